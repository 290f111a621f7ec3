"""tools/benchmark_read.py: one small run prints the read time per frame of the KITTI layout and of both bag
storages, and of the bundled .bfpc recording and its frames as a KITTI layout, each as a ratio to its KITTI layout."""
import json
import runpy
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def test_a_small_run_compares_bags_with_the_kitti_layout(tmp_path, monkeypatch, capsys, real_bfpc):
    output = tmp_path / "read.json"
    monkeypatch.setattr(sys, "argv", ["benchmark_read.py", "--frames", "3", "--points", "200", "--repeats", "1",
                                      "--output", str(output)])
    with pytest.raises(SystemExit) as done:
        runpy.run_path(str(REPO / "tools" / "benchmark_read.py"), run_name="__main__")
    assert done.value.code == 0
    rows = json.loads(output.read_text())["rows"]
    assert [row["source"] for row in rows] == ["KITTI .bin + time_offset/", "rosbag2, mcap", "rosbag2, sqlite3",
                                               "rosbag2, mcap: read once, not listed (floor)",
                                               "rosbag2, sqlite3: read once, not listed (floor)",
                                               "its frames as KITTI .bin + time_offset/",
                                               ".bfpc (the bundled Cube 1 recording)"]
    assert all(row["ms_per_frame"] > 0 and row["peak_mb"] > 0 for row in rows)
    assert [row["points"] for row in rows[:5]] == [600] * 5 and rows[5]["points"] == rows[6]["points"] == sum(
        frame.returned.sum() for frame in real_bfpc.frames)  # strongest returns
    assert "| rosbag2, mcap |" in capsys.readouterr().out
