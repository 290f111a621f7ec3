import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.monitor.zones import Zone, ZoneMonitor, read_zones

SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def box(x: float, y: float, z_bottom: float = 0.0, height: float = 1.8) -> np.ndarray:
    return np.array([x, y, z_bottom + height / 2, 0.6, 0.5, height, 0.0])


def test_enter_and_leave_events_of_a_hand_made_track():
    zones = [Zone("press", "protective", SQUARE), Zone("aisle", "warning", SQUARE + [1.0, 0.0])]
    monitor = ZoneMonitor(zones)
    xs = [-1.0, 0.5, 1.5, 2.5, 3.5, 2.5]  # walks in through press, into both, aisle only, out, back into aisle
    frames = []
    for k, x in enumerate(xs):
        zones_of, events = monitor.update(0.4 * k, [7], np.array([box(x, 1.0)]), [])
        frames.append((zones_of[0], [(e["event"], e["zone"]) for e in events]))
    assert frames == [([], []), (["press"], [("enter", "press")]), (["press", "aisle"], [("enter", "aisle")]),
                      (["aisle"], [("leave", "press")]), ([], [("leave", "aisle")]), (["aisle"], [("enter", "aisle")])]


def test_a_missed_frame_raises_no_event_and_a_lost_track_leaves():
    monitor = ZoneMonitor([Zone("press", "protective", SQUARE)])
    _, enter = monitor.update(0.0, [3], np.array([box(1, 1)]), [])
    _, missed = monitor.update(0.4, [], np.zeros((0, 7)), [])
    _, lost = monitor.update(0.8, [], np.zeros((0, 7)), [3])
    assert enter == [{"event": "enter", "zone": "press", "level": "protective", "track_id": 3, "time_s": 0.0}]
    assert missed == []
    assert lost == [{"event": "leave", "zone": "press", "level": "protective", "track_id": 3, "time_s": 0.8,
                     "reason": "lost"}]


def test_tentative_tracks_are_in_no_zone():
    monitor = ZoneMonitor([Zone("press", "protective", SQUARE)])
    zones_of, events = monitor.update(0.0, [None], np.array([box(1, 1)]), [])
    assert zones_of == [[]] and events == []


def test_z_range_counts_boxes_that_reach_into_it():
    zone = Zone("platform", "warning", SQUARE, z_range=(2.0, 4.0))
    boxes = np.array([box(1, 1), box(1, 1, z_bottom=0.2), box(1, 1, z_bottom=2.5), box(1, 1, z_bottom=4.0)])
    assert zone.contains(boxes).tolist() == [False, True, True, True]


def test_read_zones(tmp_path):
    path = tmp_path / "zones.yaml"
    path.write_text("zones:\n  - name: press\n    level: protective\n    polygon: [[0, 0], [2, 0], [2, 2]]\n"
                    "    z_range: [0, 2.5]\n")
    (zone,) = read_zones(path)
    assert (zone.name, zone.level, zone.polygon.tolist(), zone.z_range) == \
        ("press", "protective", [[0, 0], [2, 0], [2, 2]], (0.0, 2.5))


@pytest.mark.parametrize("text, message", [
    ("zones:\n  - {name: a, level: protective, polygon: [[0, 0], [2, 2], [2, 0], [0, 2]]}",
     r"zone 1 \('a'\): the polygon intersects itself \(edge 1-2 meets edge 3-4"),
    ("zones:\n  - {name: a, level: danger, polygon: [[0, 0], [2, 0], [2, 2]]}", "level is 'danger'; use one of"),
    ("zones:\n  - {name: a, level: warning, polygon: [[0, 0], [2, 0]]}", "at least 3 finite"),
    ("zones:\n  - {name: a, level: warning, polygon: [[0, 0], [1, 0], [2, 0]]}", "the polygon encloses no area"),
    ("zone:\n  - {name: a, level: warning, polygon: [[0, 0], [1, 0], [2, 2]]}", "top-level 'zones:' list"),
    ("zones:\n  - {name: a, level: warning, polygon: [[0, 0], [1, 0], [2, 2]]}\nlevels: [warning]",
     "unknown top-level key 'levels'"),
    ("zones:\n  - {name: a, level: warning, polgon: [[0, 0], [2, 0], [2, 2]]}", "did you mean 'polygon'"),
    ("zones:\n  - {name: a, level: warning, polygon: [[0, 0], [2, 0], [2, 2]], z_range: [2, 1]}", "low < high"),
    ("zones:\n  - {name: a, level: warning, polygon: [[0, 0], [2, 0], [2, 2]]}\n"
     "  - {name: a, level: warning, polygon: [[0, 0], [2, 0], [2, 2]]}", "'a' is used twice"),
    ("zone: []", "top-level 'zones:' list"),
    ("zones: [unclosed", "not valid YAML"),
])
def test_bad_zone_files_name_the_file_the_zone_and_the_fix(tmp_path, text, message):
    path = tmp_path / "zones.yaml"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message) as error:
        read_zones(path)
    assert str(path) in str(error.value)


def test_missing_zone_file(tmp_path):
    with pytest.raises(DataFormatError, match="zone file not found"):
        read_zones(tmp_path / "none.yaml")


def test_the_example_zone_file_loads():
    from pathlib import Path
    zones = read_zones(Path(__file__).resolve().parents[2] / "examples" / "zones_industrial_entrance.yaml")
    assert [(zone.name, zone.level) for zone in zones] == [("walkway", "warning"), ("machines right", "protective"),
                                                          ("machines left", "protective")]
