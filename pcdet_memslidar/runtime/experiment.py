"""What tools/train.py and tools/test.py share: OpenPCDet's common flags, config loading, the output layout
output/<group>/<cfg>/<tag>/, process set-up (distributed, threads, device) and the AP summary line."""
from __future__ import annotations

import argparse
import math
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.grid import check_config_grid
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.runtime.common import get_device, set_torch_threads
from pcdet_memslidar.runtime.distributed import init_dist_pytorch, local_world_size

AP_KEYS = ("AP3D_R40", "APBEV_R40", "AP3D_R11", "APBEV_R11")


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags train.py and test.py share (OpenPCDet's names; --cfg is an alias of --cfg_file)."""
    parser.add_argument("--cfg_file", "--cfg", dest="cfg_file", required=True, help="experiment config (YAML)")
    parser.add_argument("--batch_size", type=int, default=None, help="frames per batch and process "
                                                                     "(default OPTIMIZATION.BATCH_SIZE_PER_GPU)")
    parser.add_argument("--workers", type=int, default=4, help="data loader worker processes")
    parser.add_argument("--extra_tag", default="default", help="output sub-folder name")
    parser.add_argument("--ckpt", default=None, help="checkpoint to start from (train) or evaluate (test)")
    parser.add_argument("--launcher", choices=["none", "pytorch", "slurm"], default="none",
                        help="pytorch: one process per device under torchrun (gloo on CPU, nccl on GPU)")
    parser.add_argument("--tcp_port", type=int, default=18888, help="rendezvous port when MASTER_PORT is unset")
    parser.add_argument("--local_rank", "--local-rank", type=int, default=None, help="set by the launcher")
    parser.add_argument("--set", dest="set_cfgs", default=None, nargs=argparse.REMAINDER,
                        help="config overrides: KEY.SUB VALUE ... (e.g. --set PROFILE smoke)")
    parser.add_argument("--max_waiting_mins", type=int, default=0, help="minutes to wait for a checkpoint")
    parser.add_argument("--start_epoch", type=int, default=0, help="first epoch to evaluate")
    parser.add_argument("--save_to_file", action="store_true", default=False, help="write KITTI label files")
    parser.add_argument("--output_dir", default=None, help="output root (default <repo>/output)")


@dataclass
class Experiment:
    """A loaded config and the process it runs in."""

    cfg: object
    output_dir: Path
    dist: bool
    rank: int
    world_size: int
    device: torch.device
    threads: int
    batch_size: int


def setup_experiment(args: argparse.Namespace) -> Experiment:
    """Load the config, join the process group (--launcher pytorch), set threads and device, and name the
    output folder <output root>/<group>/<cfg name>/<extra_tag>."""
    if args.launcher == "slurm":
        raise SystemExit("--launcher slurm is not supported: start the processes with torchrun and --launcher pytorch")
    cfg = load_config(args.cfg_file, args.set_cfgs)
    check_config_grid(cfg)  # a grid that does not fit SECOND is rejected before any data is read
    batch_size = positive_count(args.batch_size, "--batch_size", cfg, "BATCH_SIZE_PER_GPU")
    dist = args.launcher == "pytorch"
    world_size, rank = init_dist_pytorch(args.tcp_port, args.local_rank) if dist else (1, 0)
    cfg.LOCAL_RANK = int(os.environ.get("LOCAL_RANK", 0)) if dist else 0
    threads = set_torch_threads(local_world_size() if dist else 1)
    root = Path(args.output_dir) if args.output_dir else Path(cfg.ROOT_DIR) / "output"
    output_dir = root / cfg.EXP_GROUP_PATH / cfg.TAG / args.extra_tag
    return Experiment(cfg, output_dir, dist, rank, world_size, get_device(cfg.LOCAL_RANK), threads, batch_size)


def positive_count(option_value: int | None, option: str, cfg, key: str) -> int:
    """`option_value` (command-line `option`) when given, else cfg.OPTIMIZATION[key]; ConfigError naming where the
    value came from and the fix unless it is a positive integer."""
    if option_value is not None:
        if option_value < 1:
            raise ConfigError(f"{option} {option_value}: must be a positive integer; pass 1 or more, or leave it out "
                              f"to use OPTIMIZATION.{key} of the config")
        return option_value
    value = cfg.OPTIMIZATION.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{cfg.CFG_FILE}: OPTIMIZATION.{key} is {value!r}: it must be a positive integer; set it "
                          f"to 1 or more (in the config, its profile or --set OPTIMIZATION.{key} N) or pass {option} N")
    return value


def check_learning_rate(cfg) -> None:
    """ConfigError naming the config unless OPTIMIZATION.LR is a positive finite number."""
    lr = cfg.OPTIMIZATION.get("LR")
    if isinstance(lr, bool) or not isinstance(lr, (int, float)) or not math.isfinite(lr) or lr <= 0:
        raise ConfigError(f"{cfg.CFG_FILE}: OPTIMIZATION.LR is {lr!r}: the learning rate must be a positive finite "
                          f"number; set it in the config, its profile or with --set OPTIMIZATION.LR VALUE")


def test_split(cfg) -> str:
    """Name of the evaluation split (DATA_CONFIG.DATA_SPLIT.test, default 'test')."""
    return cfg.DATA_CONFIG.get("DATA_SPLIT", {}).get("test", "test")


def ap_line(result: dict) -> str:
    """'AP@IoU0.5  3D R40 0.8123  BEV R40 ...' from an evaluation result (values in [0, 1])."""
    parts = []
    for key in AP_KEYS:
        value = result.get(key)
        if isinstance(value, float):
            kind, positions = key[2:].split("_")
            parts.append(f"{kind} {positions} {'nan' if math.isnan(value) else f'{value:.4f}'}")
    return "AP@IoU0.5  " + "  ".join(parts)


def scalars(result: dict) -> dict[str, float]:
    """The float entries of an evaluation result (what tensorboard can plot)."""
    return {key: value for key, value in result.items() if isinstance(value, (int, float)) and not
            isinstance(value, bool) and not math.isnan(value)}
