"""torch.distributed under torchrun: gloo on CPU, nccl on GPU; merging per-rank results."""
from __future__ import annotations

import os

import torch
import torch.distributed as dist


def init_dist_pytorch(tcp_port: int | None = None, local_rank: int | None = None) -> tuple[int, int]:
    """Join the process group torchrun describes in RANK / WORLD_SIZE / MASTER_ADDR / MASTER_PORT.

    Backend nccl when CUDA is available (this rank's GPU is selected), else gloo. Without MASTER_PORT the
    `tcp_port` is used on localhost. Returns (world_size, rank).
    """
    os.environ.setdefault("MASTER_ADDR", "127.0.0.1")
    if tcp_port is not None:
        os.environ.setdefault("MASTER_PORT", str(tcp_port))
    if "RANK" not in os.environ or "WORLD_SIZE" not in os.environ:
        raise RuntimeError("--launcher pytorch needs torchrun (RANK and WORLD_SIZE are not set): run "
                           "`torchrun --nproc_per_node N tools/train.py --launcher pytorch ...`")
    local_rank = int(os.environ.get("LOCAL_RANK", local_rank or 0))
    if torch.cuda.is_available():
        torch.cuda.set_device(local_rank % torch.cuda.device_count())
        backend = "nccl"
    else:
        backend = "gloo"
    if not dist.is_initialized():
        dist.init_process_group(backend=backend)
    return dist.get_world_size(), dist.get_rank()


def get_dist_info() -> tuple[int, int]:
    """(rank, world_size); (0, 1) outside a process group."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def local_world_size() -> int:
    """Processes of this job on this machine (torchrun's LOCAL_WORLD_SIZE; 1 without torchrun)."""
    return int(os.environ.get("LOCAL_WORLD_SIZE", 1))


def merge_results_dist(results: list, size: int) -> list:
    """Gather every rank's list of per-frame results; rank r handled frames r, r + W, ... (DistributedSampler
    without shuffling), so interleave them back into dataset order and drop the padding beyond `size`."""
    rank, world_size = get_dist_info()
    gathered = [None] * world_size
    dist.all_gather_object(gathered, results)
    merged = [item for group in zip(*gathered) for item in group]
    return merged[:size]
