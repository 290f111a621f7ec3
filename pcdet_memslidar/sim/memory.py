"""Keep freed memory in the process: the simulator's numpy work allocates and frees tens of MB of temporaries
per frame. With glibc's defaults, large blocks are unmapped or trimmed when freed and page-faulted in again (and
zeroed by the kernel) on the next use; keeping them skips that work (the simulator's timings:
docs/benchmarks.md#simulator-speed)."""
from __future__ import annotations

import ctypes
import ctypes.util
import functools

_M_TRIM_THRESHOLD = -1  # mallopt parameters (glibc malloc.h)
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 32 * 1024 * 1024  # glibc's upper limit on 64-bit systems
_TRIM_THRESHOLD = 1024 * 1024 * 1024


@functools.lru_cache(maxsize=None)
def keep_freed_memory() -> bool:
    """Ask glibc to serve blocks up to 32 MB from the heap and to return free heap memory to the system only
    beyond 1 GB, once per process. Returns False where glibc's mallopt is not available (nothing changes)."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)) and bool(mallopt(_M_TRIM_THRESHOLD,
                                                                                     _TRIM_THRESHOLD))
