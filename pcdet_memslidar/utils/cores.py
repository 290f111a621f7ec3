"""The CPU cores this process may use (without importing torch: the simulator's processes do not need it)."""
from __future__ import annotations

import os


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask, not the machine's count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _running_threads(stat_files) -> int:
    """How many of the /proc .../stat files name a thread in state R (running or waiting for a core)."""
    running = 0
    for path in stat_files:
        try:
            text = open(path).read()
        except OSError:  # the thread ended meanwhile
            continue
        running += text[text.rfind(")") + 2:].startswith("R")
    return running


def runnable_elsewhere(samples: int = 5) -> int:
    """Threads of other processes that run or wait for a core now: the median over `samples` reads of the kernel's
    runnable count (/proc/loadavg) less this process's own running threads; 0 where /proc is missing."""
    try:
        own = [f"/proc/self/task/{task}/stat" for task in os.listdir("/proc/self/task")]
        counts = []
        for _ in range(samples):
            with open("/proc/loadavg") as file:
                total = int(file.read().split()[3].split("/")[0])
            counts.append(total - _running_threads(own))
    except (OSError, ValueError, IndexError):
        return 0
    return max(0, sorted(counts)[len(counts) // 2])


def free_threads(limit: int) -> int:
    """Threads that leave the other processes' runnable threads a core each: between 1 and `limit`."""
    if limit <= 1:  # nothing to give: one-thread runs (each training of `memslidar reproduce`) skip reading /proc
        return 1
    return max(1, min(limit, available_cores() - runnable_elsewhere()))
