"""How the package compiles its per-element loops: numba, with one set of options."""
from __future__ import annotations

import numba


def kernel(function=None, *, inline: str = "never", parallel: bool = False):
    """numba.njit, cached on disk (compiled once per installation), releasing the GIL (frames are made in threads),
    with numpy's error model (float division by zero gives inf or nan instead of an exception check in every
    loop; the kernels guard their divisions themselves). Use as @kernel, @kernel(inline="always"), or
    @kernel(parallel=True) for a kernel whose `numba.prange` loops run on numba's threads."""
    compile = numba.njit(cache=True, nogil=True, error_model="numpy", inline=inline, parallel=parallel)
    return compile if function is None else compile(function)
