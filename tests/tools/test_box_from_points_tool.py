"""tools/box_from_points.py: the main axis of a person's points against its labelled long side, and the depth of
its centre behind them."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

TOOL = Path(__file__).resolve().parents[2] / "tools" / "box_from_points.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("box_from_points", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_people_filled_with_points_show_their_long_side_and_centre(tool, memslidar_data, capsys):
    people = tool.person_measurements(memslidar_data / "industrial", None, 5)
    counts, spreads = people["count"], people["spread"]
    assert len(counts) == len(spreads) == len(people["error"]) == len(people["depth"]) > 0 and (counts >= 5).all()
    assert ((spreads >= 0) & (spreads <= 1)).all()
    raised = tool.person_measurements(memslidar_data / "industrial", None, 5, min_height=0.4)
    assert 0 < raised["count"].sum() < counts.sum()  # the lowest 0.4 m of every box left out
    widened = tool.person_measurements(memslidar_data / "industrial", None, 5, margin=0.1)
    assert widened["count"].sum() >= counts.sum()
    assert np.nanmedian(people["error"]) < 20.0  # uniform points in each box: their main axis is the long side
    assert abs(np.median(people["depth"])) < 0.2  # the boxes hold their own points
    assert tool.main([str(memslidar_data / "industrial"), "--min-points", "5", "--margin", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "| points per person | people | median error (deg) |" in out and "| spread (smaller / larger" in out
    assert "Centre behind the points' mean along the ray (CENTER_DEPTH): median" in out
