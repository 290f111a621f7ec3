"""tools/research/box_from_points.py: the main axis of a person's points against its labelled long side, the depth
of its centre behind them, and how they drift over the frame."""
import numpy as np
import pytest

from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.utils.atomic import write_bytes


@pytest.fixture(scope="module")
def tool(load_tool):
    return load_tool("research/box_from_points.py")


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
    assert np.isnan(people["speed"]).all() and np.isnan(people["drift_error"]).all()  # these frames keep no times
    assert "No time offsets (training/time_offset): the drift of the points is not measured" in out


def test_a_walking_persons_points_drift_along_its_long_side(tool, tmp_path, capsys):
    layout = KittiLayout(tmp_path / "walk")
    times = np.linspace(0.0, 0.3, 20)  # the person is swept over 0.3 s of the frame
    walker = np.stack([9.85 + 1.0 * times, np.zeros(20), np.linspace(0.5, 1.7, 20), np.full(20, 0.5)], axis=1)
    box = np.array([[10.0, 0.0, 0.9, 0.8, 0.5, 1.8, 0.0]])  # long side along x, the walking direction
    write_frame(layout, "000000", walker, ["Pedestrian"], box, {"domain": "walk"})
    write_bytes(layout.time_offset("000000"), times.astype("<f4"))
    people = tool.person_measurements(layout.root, None, 5)
    assert people["speed"] == pytest.approx([1.0], abs=1e-4)  # float32 points
    assert people["drift_error"][0] < 0.1  # deg; the label keeps rotation_y to 0.01 rad
    assert people["range"] == pytest.approx([10.0], abs=1e-6)
    assert tool.main([str(layout.root)]) == 0
    assert "| 10-20m | 1 | 0.0 | 1 | 0.0 | 0.0 | 0 | - |" in capsys.readouterr().out
    write_bytes(layout.time_offset("000000"), times[:5].astype("<f4"))
    with pytest.raises(ValueError, match="000000.bin: 5 time offsets for 20 points: the frame's velodyne"):
        tool.person_measurements(layout.root, None, 5)
