"""Make spconv 2.x correct on CPU: a backward pass without CUDA, and sparse convs on one thread.

spconv's CPU wheel asks CUDA for its current stream in the backward pass even for CPU tensors; with CUDA absent
that raises "Torch not compiled with CUDA enabled". Its CPU scatter-add also races with more than one torch
thread (forward and backward outputs off by up to about 30 %). So the forward of the sparse backbone runs inside
`single_thread()`, and `patch_spconv()` makes every spconv autograd backward run on one thread as well; building a
VoxelBackBone8x applies it (importing changes nothing).
Every SparseConvTensor asks torch.fx whether it is being traced, and torch logs a notice about that question (once
per process, so once per training process of `memslidar reproduce`): `patch_spconv()` keeps it out of the log.
"""
from __future__ import annotations

import contextlib
import functools
import importlib
import inspect
import logging
from typing import Callable, Iterator

import torch

_STREAM_MODULES = ("spconv.pytorch.cppcore", "spconv.pytorch.ops", "spconv.pytorch.hash")
_MARK = "_memslidar_single_thread"


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """Run the body with one torch intra-op thread, then restore the previous count."""
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _cpu_stream() -> int:
    """The null stream: what spconv's kernels take for CPU tensors."""
    return 0


def _single_thread_backward(backward: Callable) -> Callable:
    @functools.wraps(backward)
    def wrapped(ctx, *grad_outputs):
        if any(isinstance(g, torch.Tensor) and g.is_cuda for g in grad_outputs):
            return backward(ctx, *grad_outputs)
        with single_thread():
            return backward(ctx, *grad_outputs)

    setattr(wrapped, _MARK, True)
    return staticmethod(wrapped)


def _not_fx_tracing_notice(record: logging.LogRecord) -> bool:
    return not record.getMessage().startswith("is_fx_tracing will return true")


def patch_spconv() -> bool:
    """Patch spconv in place; idempotent. Returns True if the CUDA-free stream patch was applied.

    - Without CUDA, `get_current_stream` in spconv's cppcore, ops and hash modules returns the null stream.
    - Always: the backward of each spconv autograd Function runs with one thread for CPU tensors, and torch.fx's
      notice about is_fx_tracing (which SparseConvTensor calls) is filtered from its logger.
    """
    logging.getLogger("torch.fx._symbolic_trace").addFilter(_not_fx_tracing_notice)
    functional = importlib.import_module("spconv.pytorch.functional")
    for _, cls in inspect.getmembers(functional, inspect.isclass):
        if issubclass(cls, torch.autograd.Function) and cls.__module__ == functional.__name__:
            if not getattr(cls.backward, _MARK, False):
                cls.backward = _single_thread_backward(cls.backward)
    if torch.cuda.is_available():
        return False
    for name in _STREAM_MODULES:
        importlib.import_module(name).get_current_stream = _cpu_stream
    return True
