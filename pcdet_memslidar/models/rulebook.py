"""Sparse 3D convolutions on a CPU, on all threads, forward and backward: spconv's numbers (to float rounding), faster.

spconv's CPU path runs on one thread (its scatter-add races on more, see spconv_cpu). Here a sparse convolution is
a rulebook and three dense steps:
- the rulebook (numba, a hash table of the active cells): for each kernel offset k the pairs (input row, output
  row) with input cell = output cell x stride - padding + k (spconv's cross-correlation; a submanifold conv keeps
  the input cells as output cells and centres the kernel);
- per offset: gather the input rows, multiply by that offset's weight (a torch matrix product), add into the output
  rows. For one offset the pairs are one-to-one (an output cell takes at most one input, an input reaches at most
  one output), so the adds of one offset never collide, forward or backward, and offsets are summed in one fixed
  order. The products that feed the output and the input gradient sum over the channels (at most 64 here), which
  BLAS did not split between threads on any CPU tried; the weight gradient sums over all pairs of an offset, which
  it does split on some (MKL on an Intel Xeon), so that product runs on one thread. Hence the result does not
  depend on the thread count (tested to the bit), and a training's rulebooks and convs may run on fewer threads
  when other processes need the cores.
Without grad (inference) the eval-mode BatchNorm after each conv is folded into its weight and bias; with grad
(training) the conv is an autograd Function, the BatchNorm torch's kernels on one thread (BatchNormFunction: on more,
torch splits the rows between threads and the bits change), the ReLU torch's own.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

import numba
import numpy as np
import spconv.pytorch as spconv
import torch
from numba import prange
from torch import nn

from pcdet_memslidar.utils.compiled import kernel

_EMPTY = -1
_HASH = 0x9E3779B1  # Fibonacci hashing multiplier (32 bit)


@kernel(inline="always")
def _slot(key: int, mask: int) -> int:
    return (key * _HASH) & mask


@kernel
def _hash_table(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Open-addressing table of (V,) distinct int64 keys >= 0 -> their row: (slot keys, slot rows), 2-4x V slots."""
    size = 1
    while size < 2 * keys.shape[0]:
        size *= 2
    slot_keys = np.full(size, _EMPTY, np.int64)
    slot_rows = np.empty(size, np.int64)
    for row in range(keys.shape[0]):
        slot = _slot(keys[row], size - 1)
        while slot_keys[slot] != _EMPTY:
            slot = (slot + 1) & (size - 1)
        slot_keys[slot] = keys[row]
        slot_rows[slot] = row
    return slot_keys, slot_rows


@kernel(inline="always")
def _lookup(slot_keys: np.ndarray, slot_rows: np.ndarray, key: int) -> int:
    """The row of `key`, or -1."""
    mask = slot_keys.shape[0] - 1
    slot = _slot(key, mask)
    while slot_keys[slot] != key:
        if slot_keys[slot] == _EMPTY:
            return -1
        slot = (slot + 1) & mask
    return slot_rows[slot]


@kernel(inline="always")
def _key(b: int, z: int, y: int, x: int, shape: np.ndarray) -> int:
    return ((b * shape[0] + z) * shape[1] + y) * shape[2] + x


@kernel(parallel=True)
def _keys(coords: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """(V,) int64 keys of (V, 4) cells [b, z, y, x] in a grid of `shape` (z, y, x)."""
    keys = np.empty(coords.shape[0], np.int64)
    for row in prange(coords.shape[0]):
        keys[row] = _key(coords[row, 0], coords[row, 1], coords[row, 2], coords[row, 3], shape)
    return keys


@kernel(parallel=True)
def _submanifold_sources(coords: np.ndarray, shape: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(V, K) input row at each kernel offset of each cell, the kernel centred on it (`offsets` (K, 3) (dz, dy, dx)
    relative to the centre); -1 where inactive."""
    slot_keys, slot_rows = _hash_table(_keys(coords, shape))
    sources = np.full((coords.shape[0], offsets.shape[0]), -1, np.int64)
    for row in prange(coords.shape[0]):
        b, z, y, x = coords[row, 0], coords[row, 1], coords[row, 2], coords[row, 3]
        for k in range(offsets.shape[0]):
            zz, yy, xx = z + offsets[k, 0], y + offsets[k, 1], x + offsets[k, 2]
            if 0 <= zz < shape[0] and 0 <= yy < shape[1] and 0 <= xx < shape[2]:
                sources[row, k] = _lookup(slot_keys, slot_rows, _key(b, zz, yy, xx, shape))
    return sources


@kernel
def _strided_pairs(coords: np.ndarray, out_shape: np.ndarray, kernel_size: np.ndarray, offsets: np.ndarray,
                   stride: np.ndarray, padding: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output cells (M, 4) and per kernel offset the pairs (counts (K,), inputs (K, V), outputs (K, V)) of a strided
    conv: input cell i reaches output cell o = (i + padding - k) / stride where that divides and lies in the output
    grid (`offsets` (K, 3): k as (dz, dy, dx)). Output rows are numbered in order of first appearance."""
    rows = coords.shape[0]
    reach = 1  # output cells one input cell reaches at most: ceil(kernel / stride) per axis
    for axis in range(3):
        reach *= -(-kernel_size[axis] // stride[axis])
    size = 1
    while size < 2 * rows * reach:
        size *= 2
    mask = size - 1
    slot_keys = np.full(size, _EMPTY, np.int64)
    slot_rows = np.empty(size, np.int64)
    cells = np.empty((rows * reach, 4), np.int64)
    counts = np.zeros(offsets.shape[0], np.int64)
    inputs = np.empty((offsets.shape[0], rows), np.int64)
    outputs = np.empty((offsets.shape[0], rows), np.int64)
    made = 0
    for row in range(rows):
        b, z, y, x = coords[row, 0], coords[row, 1], coords[row, 2], coords[row, 3]
        for k in range(offsets.shape[0]):
            qz, qy, qx = z + padding[0] - offsets[k, 0], y + padding[1] - offsets[k, 1], x + padding[2] - offsets[k, 2]
            if qz % stride[0] or qy % stride[1] or qx % stride[2]:
                continue
            oz, oy, ox = qz // stride[0], qy // stride[1], qx // stride[2]
            if not (0 <= oz < out_shape[0] and 0 <= oy < out_shape[1] and 0 <= ox < out_shape[2]):
                continue
            key = _key(b, oz, oy, ox, out_shape)
            slot = _slot(key, mask)
            while slot_keys[slot] != key and slot_keys[slot] != _EMPTY:
                slot = (slot + 1) & mask
            if slot_keys[slot] == _EMPTY:  # a new output cell
                slot_keys[slot] = key
                slot_rows[slot] = made
                cells[made, 0], cells[made, 1], cells[made, 2], cells[made, 3] = b, oz, oy, ox
                made += 1
            inputs[k, counts[k]] = row
            outputs[k, counts[k]] = slot_rows[slot]
            counts[k] += 1
    return cells[:made].copy(), counts, inputs, outputs


@kernel
def _submanifold_pairs(sources: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per kernel offset k the pairs of a (V, K) table of source rows (-1: none): counts (K,), inputs (K, V),
    outputs (K, V), rows [k, :counts[k]] valid, in output row order."""
    rows, offsets = sources.shape
    counts = np.zeros(offsets, np.int64)
    inputs = np.empty((offsets, rows), np.int64)
    outputs = np.empty((offsets, rows), np.int64)
    for row in range(rows):
        for k in range(offsets):
            if sources[row, k] >= 0:
                inputs[k, counts[k]] = sources[row, k]
                outputs[k, counts[k]] = row
                counts[k] += 1
    return counts, inputs, outputs


@kernel(parallel=True)
def _scatter_add(out: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """out[rows[p]] += values[p] for (P,) distinct rows, in parallel (distinct rows never collide)."""
    for p in prange(rows.shape[0]):
        for channel in range(values.shape[1]):
            out[rows[p], channel] += values[p, channel]


class Rulebook:
    """The pairs of one sparse conv: output cells `coords` (M, 4) int64 [b, z, y, x] in a grid of `shape` (z, y,
    x), and `pairs`: per kernel offset k with any, (k, input rows, output rows), torch int64: input row inputs[p]
    adds into output row outputs[p]."""

    def __init__(self, coords: np.ndarray, shape, conv: spconv.conv.SparseConvolution):
        kernel_size, stride, padding = (np.asarray(v, np.int64) for v in (conv.kernel_size, conv.stride,
                                                                            conv.padding))
        if list(conv.dilation) != [1, 1, 1] or conv.transposed or conv.inverse or conv.groups != 1:
            raise ValueError(f"{type(conv).__name__} with dilation {conv.dilation}, transposed "
                                      f"{conv.transposed}, inverse {conv.inverse}, groups {conv.groups}: the CPU "
                                      f"rulebook takes dilation 1, one group, forward convs; run it with spconv")
        self.subm = bool(conv.subm)
        if self.subm and not (kernel_size % 2).all():
            raise ValueError(f"SubMConv3d with kernel {conv.kernel_size}: the CPU rulebook centres odd "
                                      f"kernels; run it with spconv")
        shape = np.asarray(shape, np.int64)
        self.shape = shape if self.subm else (shape + 2 * padding - kernel_size) // stride + 1
        offsets = np.stack(np.unravel_index(np.arange(kernel_size.prod()), kernel_size), axis=1)  # z-major, as
        if self.subm:  # spconv's weights
            self.coords = coords
            counts, inputs, outputs = _submanifold_pairs(_submanifold_sources(coords, shape,
                                                                              offsets - kernel_size // 2))
        else:
            self.coords, counts, inputs, outputs = _strided_pairs(coords, self.shape, kernel_size, offsets, stride,
                                                                  padding)
        inputs, outputs = torch.from_numpy(inputs), torch.from_numpy(outputs)
        self.pairs = [(k, inputs[k, :n], outputs[k, :n]) for k, n in enumerate(counts.tolist()) if n]


def convolve(features: torch.Tensor, rules: Rulebook, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """(V, C_in) features of the input rows -> (M, C_out) of the output rows: sum over offsets in order k = 0..K-1
    (no grad)."""
    out = bias.expand(len(rules.coords), -1).clone()
    for k, inputs, outputs in rules.pairs:
        products = features.index_select(0, inputs) @ weight[k]
        _scatter_add(out.numpy(), outputs.numpy(), products.numpy())
    return out


@contextlib.contextmanager
def on_threads(threads: int) -> Iterator[None]:
    """torch and numba on `threads` threads in the body, then back to torch's count before it."""
    before = torch.get_num_threads()
    if threads == before:
        yield
        return
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(min(before, numba.config.NUMBA_NUM_THREADS))
        torch.set_num_threads(before)


class SparseConvFunction(torch.autograd.Function):
    """convolve() without bias, with its backward, both on `threads` threads: for each offset k, grad_features[inputs]
    += grad_out[outputs] @ weight[k]^T (collision-free, see above) and, on one thread (its sum over pairs must not be
    split), grad_weight[k] = inputs' features^T @ grad_out[outputs]."""

    @staticmethod
    def forward(ctx, features: torch.Tensor, weight: torch.Tensor, rules: Rulebook, threads: int) -> torch.Tensor:
        with on_threads(threads):  # every copy too: a parallel region on a busy machine waits for a core
            features, weight = features.contiguous(), weight.contiguous()
            ctx.save_for_backward(features, weight)
            ctx.rules, ctx.threads = rules, threads
            return convolve(features, rules, weight, weight.new_zeros(weight.shape[-1]))

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        features, weight = ctx.saved_tensors
        grad_features = grad_weight = None
        with on_threads(ctx.threads):
            grad_out = grad_out.contiguous()
            grad_rows = [grad_out.index_select(0, outputs) for _, _, outputs in ctx.rules.pairs]
            if ctx.needs_input_grad[0]:
                grad_features = torch.zeros_like(features)
                for (k, inputs, _), rows in zip(ctx.rules.pairs, grad_rows):
                    _scatter_add(grad_features.numpy(), inputs.numpy(), (rows @ weight[k].t()).numpy())
        if ctx.needs_input_grad[1]:
            with on_threads(1):
                grad_weight = torch.zeros_like(weight)
                for (k, inputs, _), rows in zip(ctx.rules.pairs, grad_rows):
                    torch.mm(features.index_select(0, inputs).t(), rows, out=grad_weight[k])
                # laid out as spconv's parameter (kernel_weight's view of it): autograd's way back copies nothing
                grad_weight = grad_weight.permute(2, 0, 1).contiguous().permute(1, 2, 0)
        return grad_features, grad_weight, None, None


class BatchNormFunction(torch.autograd.Function):
    """torch's training-mode BatchNorm of (V, C) rows (batch statistics, running statistics updated in place), forward
    and backward on one thread: on more, torch splits the rows between threads and the bits depend on the thread
    count (tools/thread_census.py)."""

    @staticmethod
    def forward(ctx, features, weight, bias, running_mean, running_var, momentum: float, eps: float):
        with on_threads(1):
            out, mean, invstd = torch.native_batch_norm(features, weight, bias, running_mean, running_var, True,
                                                        momentum, eps)
        ctx.save_for_backward(features, weight, mean, invstd)
        ctx.eps = eps
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        features, weight, mean, invstd = ctx.saved_tensors
        mask = list(ctx.needs_input_grad[:3])
        with on_threads(1):
            grads = torch.ops.aten.native_batch_norm_backward(grad_out.contiguous(), features, weight, None, None,
                                                              mean, invstd, True, ctx.eps, mask)
        return *grads, None, None, None, None


def batch_norm(norm: nn.BatchNorm1d, features: torch.Tensor) -> torch.Tensor:
    """norm(features) of (V, C) rows, in training mode (batch statistics) on one thread (BatchNormFunction)."""
    if not norm.training:
        return norm(features)
    momentum = norm.momentum
    if norm.track_running_stats:
        norm.num_batches_tracked.add_(1)
        momentum = 1.0 / float(norm.num_batches_tracked) if momentum is None else momentum  # nn.BatchNorm's rule
    return BatchNormFunction.apply(features, norm.weight, norm.bias, norm.running_mean, norm.running_var,
                                   momentum or 0.0, norm.eps)


def kernel_weight(conv: spconv.conv.SparseConvolution) -> torch.Tensor:
    """The conv's weight as (K, C_in, C_out) per kernel offset, a differentiable view of spconv's (C_out, kz, ky,
    kx, C_in) parameter."""
    weight = conv.weight
    return weight.reshape(weight.shape[0], -1, weight.shape[-1]).permute(1, 2, 0)


def folded(conv: spconv.conv.SparseConvolution, norm: nn.BatchNorm1d | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight (K, C_in, C_out) and bias (C_out,) of the conv, detached, with an eval-mode BatchNorm after the conv
    folded in."""
    weight = kernel_weight(conv).detach()
    bias = conv.bias.detach() if conv.bias is not None else weight.new_zeros(weight.shape[-1])
    if norm is None:
        return weight.contiguous(), bias
    scale = norm.weight.detach() / torch.sqrt(norm.running_var + norm.eps)
    return (weight * scale).contiguous(), (bias - norm.running_mean) * scale + norm.bias.detach()


def _layers(module: nn.Module) -> list[nn.Module]:
    """The leaf layers of nested SparseSequentials, in order."""
    if isinstance(module, spconv.SparseSequential):
        return [layer for child in module for layer in _layers(child)]
    return [module]


def run(module: nn.Module, tensor: spconv.SparseConvTensor, cache: dict,
        conv_threads: int | None = None) -> spconv.SparseConvTensor:
    """Forward of a SparseSequential of sparse convs, BatchNorm1d and ReLU on the CPU (the tensor's cells distinct,
    as spconv requires), with rulebooks shared through `cache` by indice_key as spconv shares its indices. Without
    grad an eval-mode BatchNorm is folded into the conv before it; with grad the convs are differentiable
    (SparseConvFunction) and, like the rulebooks, run on `conv_threads` (default: torch's), forward and backward. numba
    runs on as many threads as torch."""
    threads = torch.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # starts numba's OpenMP pool at the first
    torch.set_num_threads(threads)  # call, which sets OpenMP's thread count: torch's too (libgomp is shared)
    grad = torch.is_grad_enabled()
    features, coords, shape = tensor.features, tensor.indices.numpy().astype(np.int64), tensor.spatial_shape
    layers = _layers(module)
    for position, layer in enumerate(layers):
        previous = layers[position - 1] if position else None
        if isinstance(layer, spconv.conv.SparseConvolution):
            key = layer.indice_key if layer.subm and layer.indice_key else id(layer)
            rules = cache.get(key)
            if rules is None or rules.coords is not coords and not np.array_equal(rules.coords, coords):
                with on_threads(conv_threads or threads):  # integer pairs: the same on any thread count
                    rules = cache[key] = Rulebook(coords, shape, layer)
            if grad:
                features = SparseConvFunction.apply(features, kernel_weight(layer), rules, conv_threads or threads)
                features = features if layer.bias is None else features + layer.bias
            else:
                following = layers[position + 1] if position + 1 < len(layers) else None
                norm = following if isinstance(following, nn.BatchNorm1d) and not following.training else None
                features = convolve(features, rules, *folded(layer, norm))
            coords, shape = rules.coords, rules.shape.tolist()
        elif isinstance(layer, nn.BatchNorm1d) and not (grad or layer.training) and isinstance(
                previous, spconv.conv.SparseConvolution):
            continue  # folded into the conv before it
        elif isinstance(layer, nn.BatchNorm1d):
            features = batch_norm(layer, features)
        elif isinstance(layer, nn.ReLU):
            features = torch.relu(features) if grad else features.clamp_min_(0)
        else:
            raise ValueError(f"{type(layer).__name__} in a sparse block: the CPU rulebook takes sparse "
                                      f"convs, each optionally followed by BatchNorm1d, and ReLU")
    return spconv.SparseConvTensor(features, torch.from_numpy(coords).int(), list(shape), tensor.batch_size)
