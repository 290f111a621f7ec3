"""`memslidar simulate` under faults: its workers end with it, Ctrl-C gives one line that says how to resume."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SIMULATE = [sys.executable, "-m", "pcdet_memslidar.cli", "simulate", "--domain", "real", "--frames", "200"]


def _children(pid: int) -> list[int]:
    """Pids of the live processes whose parent is `pid` (from /proc)."""
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            children.append(int(stat.parent.name))
    return children


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _wait_for(condition, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


@pytest.mark.slow
def test_workers_end_when_simulate_is_killed(tmp_path):
    parent = subprocess.Popen(SIMULATE + ["--workers", "2", "--out", str(tmp_path / "real")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # the spawn pool starts a resource tracker and two workers: wait until the workers are busy (a frame written)
        assert _wait_for(lambda: any((tmp_path / "real" / "training" / "velodyne").glob("*.bin")), 60)
        workers = _children(parent.pid)
        assert len(workers) >= 2
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        assert _wait_for(lambda: not any(_alive(pid) for pid in workers), 10), "workers outlived their parent"
    finally:
        parent.kill()
        for pid in _children(parent.pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_ctrl_c_prints_one_line_naming_the_way_to_resume(tmp_path):
    # a shell that starts this run in the background makes it ignore SIGINT, and children inherit that: restore it
    process = subprocess.Popen(SIMULATE + ["--workers", "1", "--out", str(tmp_path / "real")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert _wait_for(lambda: any((tmp_path / "real" / "training" / "velodyne").glob("*.bin")), 60)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130
    assert stderr.strip().splitlines()[-1] == ("memslidar simulate: interrupted; what was written is whole: run "
                                               "the same command again to resume")
    assert "Traceback" not in stderr
