"""Run OpenPCDet's own, unmodified tools/train.py and tools/test.py on our dataset and cfgs.

    cd /path/to/OpenPCDet/tools
    python -m pcdet_memslidar.openpcdet train.py --cfg_file cfgs/memslidar/m3.yaml --set PROFILE quick

OpenPCDet has no plugin hook, so this launcher registers first and then runs the script as __main__ (runpy):
- MEMSLidarDataset goes into pcdet.datasets.__all__, the registry its build_dataloader reads;
- pcdet.config.cfg_from_yaml_file loads with our semantics (`_BASE_CONFIG_` and DATA_PATH relative to the file
  that names them, at any depth), applies the config's profile, sets CFG_FILE (as our load_config) and checks the
  voxel grid (pcdet_memslidar.grid.check_config_grid, the check of our config loader and model);
- pcdet.config.cfg_from_list applies `--set PROFILE quick` (after the other --set values, which then win again) and
  checks the grid again;
- Detector3DTemplate.load_params_from_file / load_params_with_optimizer first read the checkpoint as our loader does
  (runtime.checkpoint.read_checkpoint) and refuse one trained on another grid or profile, before OpenPCDet would
  load the half of it that fits and evaluate anyway;
- the checkpoints OpenPCDet's training writes (tools/train_utils' checkpoint_state) carry our record of the grid and
  profile (runtime.checkpoint.trained_on), so that those are refused the same way;
- torch.load's weights_only mode (the default from torch 2.6) is allowed the numpy scalars that OpenPCDet's one-cycle
  optimizer state holds, so stock OpenPCDet reloads its own checkpoints too.
Our errors (ConfigError, DataFormatError) come out as one line and exit status 2. main() applies the process policy
(policy.apply_process_policy) before anything imports torch: torch loads with register().
"""
from __future__ import annotations

import functools
import runpy
import sys
from pathlib import Path

from pcdet_memslidar.config import apply_profile, cfg_from_yaml_file
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.grid import check_config_grid
from pcdet_memslidar.policy import apply_process_policy

USAGE = "usage: python -m pcdet_memslidar.openpcdet /path/to/OpenPCDet/tools/{train,test}.py [script arguments]"


def register() -> None:
    """Register MEMSLidarDataset and our config semantics with the importable `pcdet` (idempotent)."""
    try:
        import pcdet.config
        import pcdet.datasets
    except ImportError as error:
        raise ImportError(f"OpenPCDet is not importable ({error}): install it in this environment (in the OpenPCDet "
                          f"checkout: `python setup.py develop`), or use the standalone tools (tools/train.py, "
                          f"`memslidar train`)") from error

    import torch

    from pcdet_memslidar.datasets import MEMSLidarDataset
    from pcdet_memslidar.runtime.checkpoint import numpy_scalar_globals

    pcdet.datasets.__all__["MEMSLidarDataset"] = MEMSLidarDataset
    if not getattr(pcdet.config.cfg_from_list, "memslidar", False):
        pcdet.config.cfg_from_yaml_file = _cfg_from_yaml_file
        pcdet.config.cfg_from_list = _profile_aware_cfg_from_list(pcdet.config.cfg_from_list)
    torch.serialization.add_safe_globals(numpy_scalar_globals())
    from pcdet.models.detectors.detector3d_template import Detector3DTemplate

    for name in ("load_params_from_file", "load_params_with_optimizer"):
        method = getattr(Detector3DTemplate, name)
        if not getattr(method, "memslidar", False):
            setattr(Detector3DTemplate, name, _grid_checked(method))


def _cfg_from_yaml_file(cfg_file, config):
    """OpenPCDet's cfg_from_yaml_file(cfg_file, config) with our path rules, the config's profile and grid check."""
    cfg_from_yaml_file(cfg_file, merge_to=config)
    if "PROFILES" in config:
        apply_profile(config)
    config.CFG_FILE = str(Path(cfg_file).resolve())
    check_config_grid(config)
    return config


def _profile_aware_cfg_from_list(original):
    """Wrap OpenPCDet's cfg_from_list: set, apply the (possibly new) PROFILE, set again so --set values win."""

    def cfg_from_list(cfg_list, config):
        original(cfg_list, config)
        if "PROFILES" in config:
            apply_profile(config)
            original(cfg_list, config)
        check_config_grid(config, f"{config.get('CFG_FILE', 'the config')} with --set {' '.join(map(str, cfg_list))}")

    cfg_from_list.memslidar = True
    return cfg_from_list


def _grid_checked(load):
    """Wrap a Detector3DTemplate loader: read `filename` safely and refuse weights trained on another voxel grid
    (the checkpoint's record against the model's dataset) before OpenPCDet loads it."""

    from pcdet_memslidar.runtime.checkpoint import grid_mismatch, read_checkpoint

    @functools.wraps(load)
    def checked(self, filename, *args, **kwargs):
        mismatch = grid_mismatch(read_checkpoint(filename), self)
        if mismatch:
            raise DataFormatError(filename, mismatch)
        return load(self, filename, *args, **kwargs)

    checked.memslidar = True
    return checked


def record_grid_in_checkpoints(tools_dir: Path) -> None:
    """Wrap OpenPCDet's tools/train_utils/train_utils.checkpoint_state (if `tools_dir` has it) so that each checkpoint
    its training saves carries our 'memslidar' record: the grid of the model's dataset and the config's PROFILE."""
    if not (tools_dir / "train_utils" / "train_utils.py").is_file():
        return
    import pcdet.config
    from train_utils import train_utils

    from pcdet_memslidar.runtime.checkpoint import trained_on

    original = train_utils.checkpoint_state
    if getattr(original, "memslidar", False):
        return

    @functools.wraps(original)
    def checkpoint_state(model=None, *args, **kwargs):
        state = original(model, *args, **kwargs)
        if model is not None:
            state["memslidar"] = {**trained_on(model), "profile": pcdet.config.cfg.get("PROFILE")}
        return state

    checkpoint_state.memslidar = True
    train_utils.checkpoint_state = checkpoint_state


def main(argv: list[str] | None = None) -> int:
    """Register, then run an OpenPCDet script with the remaining arguments as its command line."""
    apply_process_policy()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    script = Path(argv[0]).resolve()
    if not script.is_file():
        print(f"{argv[0]}: no such script. {USAGE}", file=sys.stderr)
        return 2
    register()
    sys.argv = [str(script), *argv[1:]]
    sys.path.insert(0, str(script.parent))  # the script's own folder, as `python script.py` would (train_utils/ ...)
    record_grid_in_checkpoints(script.parent)
    try:
        runpy.run_path(str(script), run_name="__main__")
    except (ConfigError, DataFormatError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
