"""What training and testing share: the process a run executes in (distributed or not, device, threads), the
output layout output/<group>/<cfg>/<tag>/, the checks of the training settings, and the AP summary line."""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.policy import ExecutionPolicy, choose_policy
from pcdet_memslidar.runtime.common import get_device, set_torch_threads
from pcdet_memslidar.runtime.distributed import init_dist_pytorch, local_world_size
from pcdet_memslidar.utils.cores import shorten_time_slice

AP_KEYS = ("AP3D_R40", "APBEV_R40", "AP3D_R11", "APBEV_R11")


@dataclass(frozen=True)
class Process:
    """The process a run executes in: its device and torch threads, and its rank among `world_size` processes
    (dist: under torch.distributed, one process per device)."""

    device: torch.device
    threads: int
    dist: bool = False
    rank: int = 0
    world_size: int = 1

    @property
    def policy(self) -> ExecutionPolicy:
        """How detectors execute in this process (policy.choose_policy of its device and threads)."""
        return choose_policy(self.device.type, self.threads)


def local_process(threads: int | None = None) -> Process:
    """This process alone: the first CUDA device (else the CPU) with `threads` torch threads (None: the ones it
    already has)."""
    if threads is not None:
        torch.set_num_threads(threads)
    return Process(get_device(), torch.get_num_threads())


def start_process(launcher: str = "none", tcp_port: int = 18888, local_rank: int | None = None) -> Process:
    """Join the process group (launcher 'pytorch': one process per device under torchrun; 'none': this process
    alone), give this process its share of the free cores as torch threads and a short time slice (for a busy
    machine: utils.cores.shorten_time_slice), and pick its device."""
    if launcher not in ("none", "pytorch"):
        raise ConfigError(f"--launcher {launcher} is not supported: start the processes with torchrun and "
                          f"--launcher pytorch")
    dist = launcher == "pytorch"
    world_size, rank = init_dist_pytorch(tcp_port, local_rank) if dist else (1, 0)
    device = get_device(int(os.environ.get("LOCAL_RANK", 0)) if dist else 0)
    shorten_time_slice()
    return Process(device, set_torch_threads(local_world_size() if dist else 1), dist, rank, world_size)


def output_folder(cfg, output_root: str | Path | None, extra_tag: str) -> Path:
    """OpenPCDet's run folder <output root>/<group>/<cfg name>/<extra_tag> (default root: <repo>/output)."""
    root = Path(output_root) if output_root else Path(cfg.ROOT_DIR) / "output"
    return root / cfg.EXP_GROUP_PATH / cfg.TAG / extra_tag


def option_count(value: int | None, option: str, key: str, cfg) -> int:
    """`value` of the command-line `option` when given (ConfigError unless it is 1 or more), else
    cfg.OPTIMIZATION[key] (checked when the config was loaded)."""
    if value is None:
        if key not in cfg.OPTIMIZATION:
            raise ConfigError(f"{cfg.CFG_FILE}: OPTIMIZATION.{key} is missing; set it in the config or pass {option} N")
        return cfg.OPTIMIZATION[key]
    if value < 1:
        raise ConfigError(f"{option} {value}: must be a positive integer; pass 1 or more, or leave it out to use "
                          f"OPTIMIZATION.{key} of the config")
    return value


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
