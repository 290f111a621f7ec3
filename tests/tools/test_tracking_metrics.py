"""tools/tracking_metrics.py: CLEAR MOT and IDF1 of hand-made tracks, person ids read from frame metadata."""
import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError, DataFormatError


@pytest.fixture(scope="module")
def tracking(load_tool):
    return load_tool("tracking_metrics.py")


A, B = np.array([0.0, 0.0]), np.array([5.0, 0.0])


def record(frame: str, detections) -> dict:
    return {"frame": frame, "detections": [{"box": [x, y, 0.9, 0.6, 0.5, 1.7, 0.0], "score": 0.9, "track_id": i}
                                           for i, (x, y) in detections], "events": []}


def test_a_swap_a_false_positive_and_a_miss_give_exact_mota(tracking):
    truth = [(f"{k:06d}", [0, 1], np.stack([A, B])) for k in range(4)]
    records = [record("000000", [(1, A), (2, B)]),
               record("000001", [(1, A + [0.3, 0.3]), (2, B), (3, (20.0, 0.0))]),  # 0.42 m off: still a match
               record("000002", [(2, A), (1, B)]),  # the ids swap: two switches
               record("000003", [(2, A), (None, B)])]  # B only tentative: missed
    metrics = tracking.mot_metrics([(truth, records)])
    assert metrics["num_switches"] == 2 and metrics["num_false_positives"] == 1 and metrics["num_misses"] == 1
    assert metrics["mota"] == pytest.approx(1 - (1 + 1 + 2) / 8)
    assert metrics["recall"] == pytest.approx(7 / 8) and metrics["precision"] == pytest.approx(7 / 8)


def test_a_box_beyond_the_match_distance_is_a_false_positive_and_a_miss(tracking):
    truth = [("000000", [0], A[None])]
    metrics = tracking.mot_metrics([(truth, [record("000000", [(1, A + [0.5, 0.01])])])])
    assert (metrics["num_false_positives"], metrics["num_misses"], metrics["mota"]) == (1, 1, -1.0)


def test_sequences_are_pooled_with_their_own_ids(tracking):
    truth = [("000000", [0], A[None]), ("000001", [0], A[None])]
    same_ids = [record("000000", [(1, A)]), record("000001", [(1, A)])]
    metrics = tracking.mot_metrics([(truth, same_ids), (truth, same_ids)])
    assert (metrics["num_unique_objects"], metrics["num_switches"], metrics["mota"]) == (2, 0, 1.0)


def test_detections_of_other_frames_are_refused(tracking):
    with pytest.raises(ConfigError, match="do not cover its frames"):
        tracking.mot_metrics([([("000000", [0], A[None])], [record("000001", [])])])


def test_sequence_truth_reads_person_ids(tracking, tmp_path):
    from pcdet_memslidar.io.layout import KittiLayout, write_frame
    layout = KittiLayout(tmp_path)
    people = [{"box": [3.0, 1.0, 0.9, 0.6, 0.5, 1.7, 0.0]}, {"box": [9.0, -2.0, 0.9, 0.6, 0.5, 1.7, 0.0]}]
    write_frame(layout, "000000", np.zeros((1, 4), np.float32), ["Pedestrian"], np.array([people[1]["box"]]),
                {"people": people, "person_ids": [1]})
    ((frame, ids, centres),) = tracking.sequence_truth(tmp_path)
    assert (frame, ids, centres.tolist()) == ("000000", [1], [[9.0, -2.0]])
    write_frame(layout, "000001", np.zeros((1, 4), np.float32), [], np.zeros((0, 7)), {"people": []})
    with pytest.raises(DataFormatError, match="000001.json: has no person_ids: not a sequence"):
        tracking.sequence_truth(tmp_path)
