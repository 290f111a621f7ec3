"""tools/orientation_from_points.py: the main axis of a person's points against its labelled long side."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

TOOL = Path(__file__).resolve().parents[2] / "tools" / "orientation_from_points.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("orientation_from_points", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_people_filled_with_points_show_their_long_side(tool, memslidar_data, capsys):
    errors, counts, spreads = tool.orientation_errors(memslidar_data / "industrial", None, 5)
    assert len(errors) == len(counts) == len(spreads) > 0 and (counts >= 5).all()
    assert ((spreads >= 0) & (spreads <= 1)).all()
    raised, raised_counts, _ = tool.orientation_errors(memslidar_data / "industrial", None, 5, min_height=0.4)
    assert 0 < raised_counts.sum() < counts.sum()  # the lowest 0.4 m of every box left out
    assert np.median(errors) < 20.0  # uniform points in each box: their main axis is the long side (or near)
    assert tool.main([str(memslidar_data / "industrial"), "--min-points", "5"]) == 0
    out = capsys.readouterr().out
    assert "| points per person | people | median error (deg) |" in out and "| spread (smaller / larger" in out
