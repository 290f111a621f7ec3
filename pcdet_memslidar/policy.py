"""Execution policy: the threads and the sparse-convolution back end a detector runs with, and the process-wide
OpenMP wait hint. No torch here: the entry points apply the process policy before torch loads.

choose_policy picks the policy once per process, from its device and torch threads (runtime.experiment.Process
.policy); the runtime hands it to the detector (set_policy), whose sparse backbone runs it:

    situation                          sparse convs        their threads
    GPU                                spconv             torch's
    CPU, inference (no grad)           models.rulebook    torch's (inference loops lower them to the free cores
                                                          before each batch: runtime.common.threads_giving_way)
    CPU, training on more than 1       models.rulebook    the cores other processes leave free at each step, at
    thread                                                most `threads` (the results do not depend on the count)
    CPU, training on 1 thread          spconv             1 (faster there: docs/benchmarks.md#training-speed)

spconv's CPU scatter-add races on more than one thread, so on a CPU it always runs on one (models.spconv_cpu).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from pcdet_memslidar.utils.cores import available_cores, free_threads

SPIN_VARIABLE, WAIT_POLICY_VARIABLE = "GOMP_SPINCOUNT", "OMP_WAIT_POLICY"
SPIN_COUNT = "10000"  # spins of a waiting OpenMP thread before it sleeps (libgomp's default: 300,000)
# MKL's GEMM (torch's CPU matmul) on its AVX2 code path splits its sums by the thread count unless told to be strict,
# and one and two threads then give different bits (tests/models/test_rulebook.py with MKL_ENABLE_INSTRUCTIONS=AVX2).
MKL_REPRODUCIBILITY_VARIABLE, MKL_REPRODUCIBILITY = "MKL_CBWR", "AUTO,STRICT"


@dataclass(frozen=True)
class ExecutionPolicy:
    """How a detector executes in this process (choose_policy)."""

    device: str  # 'cpu' or 'cuda'
    threads: int  # torch's intra-op threads in this process, and numba's (they share libgomp's pool)
    train_backend: str  # the sparse convs' back end with grad (training): 'rulebook' (models.rulebook) or 'spconv'
    infer_backend: str  # without grad (inference, validation)

    def sparse_backend(self, grad: bool) -> str:
        """The back end of the sparse convs with grad enabled (training) or not (inference)."""
        return self.train_backend if grad else self.infer_backend

    def rulebook_threads(self, grad: bool) -> int | None:
        """Threads for models.rulebook's convs: with grad the cores other processes leave free now (1 to `threads`,
        read at each training step); without, None (torch's, as the inference loop set them)."""
        return free_threads(self.threads) if grad else None


def choose_policy(device: str, threads: int) -> ExecutionPolicy:
    """The policy of a process on `device` ('cpu' or 'cuda') with `threads` torch threads (module docstring)."""
    if threads < 1:
        raise ValueError(f"threads {threads}: a process runs on at least 1 torch thread")
    if device != "cpu":
        return ExecutionPolicy(device, threads, train_backend="spconv", infer_backend="spconv")
    return ExecutionPolicy(device, threads, train_backend="rulebook" if threads > 1 else "spconv",
                           infer_backend="rulebook")


def thread_share(processes: int = 1) -> int:
    """Torch threads for each of `processes` processes sharing the cores this process may run on: an equal share,
    at least 1 (over-subscribed threads are many times slower than one thread per core)."""
    return max(1, available_cores() // max(1, processes))


def apply_process_policy() -> None:
    """Set the OpenMP wait hint in this process's environment, and so in the processes it starts: GOMP_SPINCOUNT
    10000, unless the user set GOMP_SPINCOUNT or OMP_WAIT_POLICY (which a GOMP_SPINCOUNT would override); and MKL's
    strict reproducibility (MKL_CBWR AUTO,STRICT: the same bits on any thread count), unless the user set MKL_CBWR.
    Idempotent.

    libgomp, the OpenMP runtime torch and numba share, reads it when it loads (at `import torch`), so the entry
    points call this first (cli.main, the OpenPCDet launcher, tools), and experiments.runs.run_jobs before it spawns
    its training workers. libgomp lets a waiting thread spin 300,000 times before it sleeps; on a
    machine shared with other processes the spinning takes the core from the very thread it waits for, and a
    training step ran 5-6x slower beside three busy processes instead of 2-3x (tools/benchmark_load.py)."""
    if SPIN_VARIABLE not in os.environ and WAIT_POLICY_VARIABLE not in os.environ:
        os.environ[SPIN_VARIABLE] = SPIN_COUNT
    os.environ.setdefault(MKL_REPRODUCIBILITY_VARIABLE, MKL_REPRODUCIBILITY)
