"""Process set-up shared by training and testing: seeds, torch threads, data-loader workers, device, logger."""
from __future__ import annotations

import contextlib
import logging
import random
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

from pcdet_memslidar.policy import thread_share
from pcdet_memslidar.utils.cores import available_cores, free_threads


def set_random_seed(seed: int) -> None:
    """Seed Python, numpy and torch (all devices); deterministic cuDNN."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    torch.backends.cudnn.deterministic = True
    torch.backends.cudnn.benchmark = False


def set_torch_threads(local_world_size: int = 1) -> int:
    """Give each of the `local_world_size` processes on this machine an equal share of the free cores
    (policy.thread_share) as torch threads. Returns the thread count."""
    threads = thread_share(local_world_size)
    torch.set_num_threads(threads)
    return threads


def default_workers() -> int:
    """Data-loader worker processes when none are asked for: 0 without CUDA (loading in the training process leaves
    the cores to the model, and a 2-core machine gets no over-subscription warning), else OpenPCDet's 4, at most
    the free cores."""
    return min(4, available_cores()) if torch.cuda.is_available() else 0


def cpu_has_bf16() -> bool:
    """Whether this CPU computes bfloat16 in hardware (AVX512-BF16 or AMX), as oneDNN reports it."""
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def get_device(local_rank: int = 0) -> torch.device:
    """cuda:<local_rank> when CUDA is available, else the CPU."""
    return torch.device("cuda", local_rank) if torch.cuda.is_available() else torch.device("cpu")


def create_logger(log_file: str | Path | None = None, rank: int = 0, name: str = "pcdet_memslidar",
                  console: bool = True) -> logging.Logger:
    """Logger printing to the console (unless `console` is False) and to `log_file` on rank 0; quiet (errors
    only) on other ranks."""
    logger = logging.getLogger(name)
    logger.setLevel(logging.INFO if rank == 0 else logging.ERROR)
    logger.propagate = False
    for handler in list(logger.handlers):
        logger.removeHandler(handler)
        handler.close()
    formatter = logging.Formatter("%(asctime)s  %(levelname)5s  %(message)s")
    handlers: list[logging.Handler] = [logging.StreamHandler()] if console else []
    if log_file is not None and rank == 0:
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(log_file))
    for handler in handlers:
        handler.setFormatter(formatter)
        logger.addHandler(handler)
    return logger


@contextlib.contextmanager
def threads_giving_way() -> Iterator[Callable[[], int]]:
    """For inference loops on a shared machine: yields adapt(), which before a batch sets torch's threads (and
    through models.rulebook numba's) to the cores no other process is using, between 1 and the count at entry, and
    returns it; leaving the block restores that count. OpenMP threads wait for each other at every parallel region,
    so on a busy machine fewer threads than cores are faster (tools/benchmark_load.py). Inference outputs differ
    between thread counts only by float rounding (2e-10 on the quick model's head outputs)."""
    limit = torch.get_num_threads()

    def adapt() -> int:
        threads = free_threads(limit)
        if threads != torch.get_num_threads():
            torch.set_num_threads(threads)
        return threads

    try:
        yield adapt
    finally:
        torch.set_num_threads(limit)
