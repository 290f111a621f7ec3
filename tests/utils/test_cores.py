"""Cores on a shared machine: the count of other processes' runnable threads, inference threads that give way to
them and come back, and a short scheduler time slice."""
import io
import json
import os
import subprocess
import sys

import pytest
import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.runtime import common
from pcdet_memslidar.utils import cores


def test_running_threads_reads_the_state_after_the_name_even_with_parentheses_in_it(tmp_path):
    files = []
    for index, line in enumerate(["12 (python) R 1 12", "13 (a) S (b) S 1 13", "14 (pt_main_thread) S 1",
                                  "15 (x) R) R 1 15"]):
        files.append(tmp_path / f"{index}.stat")
        files[-1].write_text(line)
    assert cores._running_threads(files + [tmp_path / "gone.stat"]) == 2  # 12 and 15 run; a thread that ended


def fake_proc(monkeypatch, runnable: list[int], states: dict[str, str]) -> None:
    """/proc as cores reads it: /proc/loadavg gives the runnable counts in turn, /proc/self/task the threads of
    `states` {tid: state letter}."""
    loadavg = iter(f"0.52 0.58 0.59 {count}/913 4242\n" for count in runnable)

    def fake_open(path):
        if path == "/proc/loadavg":
            return io.StringIO(next(loadavg))
        tid = path.split("/")[-2]
        return io.StringIO(f"{tid} (pt_main_thread) {states[tid]} 1 {tid}")

    monkeypatch.setattr(cores, "open", fake_open, raising=False)
    monkeypatch.setattr(cores.os, "listdir", lambda path: list(states) if path == "/proc/self/task" else [])


@pytest.mark.parametrize("runnable, expected", [([9, 3, 7, 12, 5], 5),  # less 2 own: 7 1 5 10 3, median 5
                                                ([1, 1, 3, 2, 1], 0)])  # median -1: never below 0
def test_runnable_elsewhere_is_the_median_runnable_count_less_this_processs_running_threads(monkeypatch, runnable,
                                                                                             expected):
    fake_proc(monkeypatch, runnable, {"100": "R", "101": "S", "102": "R"})
    assert cores.runnable_elsewhere() == expected


def test_runnable_elsewhere_is_zero_without_proc(monkeypatch):
    monkeypatch.setattr(cores.os, "listdir", lambda path: (_ for _ in ()).throw(FileNotFoundError(path)))
    assert cores.runnable_elsewhere() == 0


def test_one_thread_has_nothing_to_give_and_reads_no_load(monkeypatch):
    monkeypatch.setattr(cores, "runnable_elsewhere", lambda: pytest.fail("read the load for a one-thread run"))
    assert cores.free_threads(1) == 1


@pytest.mark.parametrize("elsewhere, expected", [(0, 2), (1, 1), (3, 1)])
def test_inference_threads_give_way_to_other_processes_and_come_back(monkeypatch, elsewhere, expected):
    monkeypatch.setattr(cores, "available_cores", lambda: 2)
    monkeypatch.setattr(cores, "runnable_elsewhere", lambda: elsewhere)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with common.threads_giving_way() as give_way:
            assert give_way() == expected == torch.get_num_threads()
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


_SLICE_PROBE = """
import json, os, threading
from pcdet_memslidar.utils.cores import shorten_time_slice

def slice_ns(tid):
    for line in open(f"/proc/self/task/{tid}/sched"):
        if line.startswith("se.slice"):
            return int(line.split()[-1])
    return None

main = threading.get_native_id()
before = slice_ns(main)
os.nice(3)
taken = shorten_time_slice()
started = []
thread = threading.Thread(target=lambda: started.append(slice_ns(threading.get_native_id())))
thread.start()
thread.join()
after = slice_ns(main)
os.environ["MEMSLIDAR_SLICE_US"] = "0"
shorten_time_slice()
print(json.dumps({"taken": taken, "nice": os.getpriority(os.PRIO_PROCESS, 0), "before": before, "after": after,
                  "thread": started[0], "reset": slice_ns(main)}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux scheduler request")
def test_a_short_time_slice_keeps_the_nice_value_reaches_new_threads_and_zero_gives_the_kernels_back():
    """In a fresh process (the request outlives the call): 300 us by default, inherited by a thread started after
    it, the process's nice value 3 kept, MEMSLIDAR_SLICE_US=0 back to the kernel's slice."""
    env = {key: value for key, value in os.environ.items() if key != cores.SLICE_VARIABLE}
    done = subprocess.run([sys.executable, "-c", _SLICE_PROBE], env=env, capture_output=True, text=True, timeout=60,
                          check=True)
    probe = json.loads(done.stdout.strip().splitlines()[-1])
    assert probe["taken"] >= 1 and probe["nice"] == 3
    if probe["before"] is None:
        pytest.skip("this kernel does not show se.slice in /proc/<pid>/sched; the request was made, not checked")
    assert probe["after"] == probe["thread"] == 300_000
    assert probe["reset"] == probe["before"] != 300_000


@pytest.mark.parametrize("value", ["abc", "-5", "", "0.3"])
def test_a_malformed_slice_variable_is_refused_with_the_fix(monkeypatch, value):
    monkeypatch.setenv(cores.SLICE_VARIABLE, value)
    with pytest.raises(ConfigError, match=f"MEMSLIDAR_SLICE_US={value!r}: give whole microseconds"):
        cores.shorten_time_slice()
