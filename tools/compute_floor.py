"""The arithmetic floor of a model's time: the FLOPs of one forward pass over this machine's fp32 GEMM rate
(benchmark_tracking.py beside it prints it next to the measured time).

No implementation of the same layers in fp32 on these threads runs faster than floor_ms; a speed target below it
needs fewer FLOPs (another model) or other hardware, not better code.
"""
from __future__ import annotations

import time

import torch
from torch.utils.flop_counter import FlopCounterMode


def forward_flops(model: torch.nn.Module, *inputs) -> int:
    """FLOPs (a multiply-add counts 2) of model(*inputs) without gradients, in torch's own ops: convolutions and
    matrix products, including the products spconv's CPU path runs through torch.mm."""
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model(*inputs)
    return int(counter.get_total_flops())


def gemm_flops_per_s(size: int = 1024, repeats: int = 20) -> float:
    """fp32 FLOP/s of a size x size matrix product on torch's current threads: the fastest of `repeats`, since a
    floor needs the peak rate (the median moves with whatever else runs)."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    a @ b  # warm-up
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        seconds.append(time.perf_counter() - start)
    return 2 * size**3 / min(seconds)


def floor_ms(flops: int, flops_per_s: float) -> float:
    """The least ms that `flops` take at `flops_per_s`."""
    return 1000.0 * flops / flops_per_s
