import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.monitor.tracker import Tracker, TrackerConfig

PERIOD = 0.4  # s: the Cube 1 at 200 scan lines


def person(x: float, y: float) -> np.ndarray:
    return np.array([x, y, 0.87, 0.6, 0.5, 1.74, 0.0])


def run(frames, config=None) -> list[list]:
    """Track frames [[box, ...], ...] (all scores 0.9); the ids per frame in detection order."""
    tracker = Tracker(config)
    ids = []
    for k, boxes in enumerate(frames):
        boxes = np.array(boxes).reshape(-1, 7)
        ids.append(tracker.update(boxes, np.full(len(boxes), 0.9), k * PERIOD).detection_ids)
    return ids


def passing_people() -> list[list[np.ndarray]]:
    frames = []
    for k in range(12):
        a, b = person(2.0 + 0.5 * k, 0.15), person(7.25 - 0.5 * k, -0.15)
        frames.append([a, b] if k % 2 == 0 else [b, a])
    return frames


def test_people_walking_past_each_other_keep_their_ids():
    # A walks +x, B walks -x, 0.3 m apart sideways, 1.25 m/s: they pass between frames 5 and 6, where matching
    # the detections to the tracks' last positions would swap them (next test): only the motion model tells.
    # The detection order alternates, so the ids cannot come from the order.
    ids = run(passing_people())
    # confirmed at frame 1, where B comes first: B is 1 and A is 2 from then on
    expected = [[None, None]] + [[2, 1] if k % 2 == 0 else [1, 2] for k in range(1, 12)]
    assert ids == expected


def test_without_a_motion_model_the_same_people_would_swap():
    # The case above is hard: assigning frame 6's detections to frame 5's positions by least total distance swaps.
    a5, b5, a6, b6 = np.array([4.5, 0.15]), np.array([4.75, -0.15]), np.array([5.0, 0.15]), np.array([4.25, -0.15])
    kept = np.linalg.norm(a6 - a5) + np.linalg.norm(b6 - b5)
    swapped = np.linalg.norm(b6 - a5) + np.linalg.norm(a6 - b5)
    assert swapped < kept
    static = run(passing_people(), TrackerConfig(initial_speed=0.0, accel_noise=0.0))  # no motion: ids break
    assert static[4] == [None, None] and static[5] == [3, 4]


def test_crossing_at_right_angles_keeps_ids():
    # A walks +x along y = 0; B walks +y along x = 5, one frame later through the crossing point.
    frames = [[person(2.0 + 0.5 * k, 0.0), person(5.0, -3.5 + 0.5 * k)] for k in range(14)]
    assert run(frames)[1:] == [[1, 2]] * 13


def test_a_flicker_gets_no_id_and_a_short_occlusion_keeps_it():
    config = TrackerConfig(max_misses=2)
    frames = [[person(3.0 + 0.5 * k, 0.0)] for k in range(10)]
    frames[2] = frames[2] + [person(8.0, 5.0)]  # a false positive in one frame
    frames[4] = frames[5] = []  # missed twice: survives (max_misses 2)
    ids = run(frames, config)
    assert ids == [[None], [1], [1, None], [1], [], [], [1], [1], [1], [1]]


def test_a_long_occlusion_ends_the_track_and_a_new_id_follows():
    config = TrackerConfig(max_misses=2)
    tracker = Tracker(config)
    lost, ids = [], []
    for k in range(9):
        boxes = np.array([person(3.0 + 0.5 * k, 0.0)]) if k < 3 or k > 5 else np.zeros((0, 7))
        result = tracker.update(boxes, np.full(len(boxes), 0.9), k * PERIOD)
        ids.append(result.detection_ids)
        lost.append([track.track_id for track in result.lost])
    assert ids == [[None], [1], [1], [], [], [], [None], [2], [2]]
    assert lost == [[], [], [], [], [], [1], [], [], []]  # the third miss in a row drops it


def test_low_scores_are_not_tracked():
    tracker = Tracker(TrackerConfig(min_score=0.5))
    result = tracker.update(np.stack([person(3, 0), person(6, 0)]), np.array([0.49, 0.5]), 0.0)
    assert result.kept.tolist() == [1] and len(tracker.tracks) == 1


def test_frames_out_of_time_order_are_refused():
    tracker = Tracker()
    tracker.update(np.zeros((0, 7)), np.zeros(0), 1.0)
    with pytest.raises(ValueError, match="time order"):
        tracker.update(np.zeros((0, 7)), np.zeros(0), 0.6)


def test_the_velocity_estimate_converges_to_the_walking_speed():
    tracker = Tracker()
    for k in range(15):
        tracker.update(np.array([person(2.0 + 0.5 * k, 1.0 - 0.2 * k)]), np.array([0.9]), k * PERIOD)
    np.testing.assert_allclose(tracker.tracks[0].x[2:], [1.25, -0.5], atol=1e-3)


@pytest.mark.parametrize("block, message", [({"MAX_DISTANCES": 1.0}, "did you mean MAX_DISTANCE"),
                                            ({"MIN_HITS": 1.5}, "non-negative int"),
                                            ({"MAX_DISTANCE": -1}, "non-negative float"),
                                            ({"MIN_SCORE": True}, "non-negative float"),
                                            ({"MIN_HITS": float("inf")}, "TRACKER.MIN_HITS is inf: give a finite"),
                                            ({"MAX_DISTANCE": float("nan")}, "TRACKER.MAX_DISTANCE is nan: give a"),
                                            ([1.0, 2], r"TRACKER is \[1.0, 2\]: give a mapping")])
def test_tracker_block_errors_name_the_key(block, message):
    with pytest.raises(ConfigError, match=message) as error:
        TrackerConfig.from_block(block, "cfgs/m3.yaml")
    assert "cfgs/m3.yaml: " in str(error.value)


def test_tracker_block_sets_the_fields():
    config = TrackerConfig.from_block({"MAX_DISTANCE": 2, "MIN_HITS": 3}, "x.yaml")
    assert (config.max_distance, config.min_hits, config.max_misses) == (2.0, 3, TrackerConfig().max_misses)
