"""The CPU cores this process may use (without importing torch: the simulator's processes do not need it)."""
from __future__ import annotations

import ctypes
import os
import struct

from pcdet_memslidar.errors import ConfigError


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


SLICE_VARIABLE = "MEMSLIDAR_SLICE_US"
DEFAULT_SLICE_US = 300
_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}  # syscall numbers
_FAIR_POLICIES = {getattr(os, name) for name in ("SCHED_OTHER", "SCHED_BATCH", "SCHED_IDLE") if hasattr(os, name)}


def shorten_time_slice() -> int:
    """Ask Linux's scheduler for a short time slice for this process's threads, which the threads and processes
    they start inherit: $MEMSLIDAR_SLICE_US microseconds, default 300; 0 asks for the kernel's own (a few milliseconds).

    OpenMP threads wait for each other at every parallel region; on a busy machine a thread that wakes there
    otherwise waits out the slice of the process on its core. The EEVDF scheduler (Linux 6.12 and later) runs a
    thread with a shorter slice sooner, in shorter turns, for the same share of the CPU; older kernels ignore the
    request. Each thread keeps its policy and nice value; real-time threads are left alone. Returns how many
    threads took the request (0 off Linux on x86-64 or arm64)."""
    value = os.environ.get(SLICE_VARIABLE, str(DEFAULT_SLICE_US))
    if not value.isdigit():
        raise ConfigError(f"{SLICE_VARIABLE}={value!r}: give whole microseconds, e.g. {DEFAULT_SLICE_US} (0: the "
                          f"kernel's own slice)")
    number = _SCHED_SETATTR.get(os.uname().machine) if hasattr(os, "sched_getscheduler") else None
    if number is None:
        return 0
    microseconds = int(value)
    syscall = ctypes.CDLL(None, use_errno=True).syscall
    taken = 0
    for task in os.listdir("/proc/self/task"):
        tid = int(task)
        try:
            policy, nice = os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)
        except OSError:  # the thread ended meanwhile
            continue
        if policy not in _FAIR_POLICIES:
            continue
        # struct sched_attr (48 bytes): size, policy, flags, nice, priority, runtime (the slice, ns), deadline, period
        attr = struct.pack("IIQiIQQQ", 48, policy, 0, nice, 0, microseconds * 1000, 0, 0)
        taken += syscall(number, tid, ctypes.c_char_p(attr), 0) == 0
    return taken
