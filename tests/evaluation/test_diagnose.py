"""evaluation.diagnose: which part of a box costs the AP, with exact values on hand-made boxes."""
import json
import pickle

import numpy as np
import pytest

from pcdet_memslidar.commands.test import diagnose
from pcdet_memslidar.evaluation.diagnose import (
    PARTS,
    extent_agreement,
    format_diagnosis,
    orientation_error_deg,
    part_ablation,
)

pytestmark = pytest.mark.filterwarnings("ignore:no ground-truth 'Pedestrian' boxes in the")  # bins left empty here

PERSON = np.array([10.0, 2.0, 0.85, 0.7, 0.5, 1.7, 0.2])  # [x, y, z, dx, dy, dz, heading]


def _frames(gt_boxes, dt_boxes, scores=None):
    """One frame per ground-truth box, with the detection(s) of that frame."""
    gt = [{"name": np.array(["Pedestrian"]), "boxes_lidar": box[None]} for box in gt_boxes]
    dt = []
    for index, boxes in enumerate(dt_boxes):
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
        score = np.full(len(boxes), 0.9) if scores is None else np.asarray(scores[index], dtype=np.float64)
        dt.append({"name": np.array(["Pedestrian"] * len(boxes)), "boxes_lidar": boxes, "score": score})
    return gt, dt


def _people(count=3):
    boxes = np.repeat(PERSON[None], count, axis=0)
    boxes[:, 1] += np.arange(count)  # different places, same size
    return boxes


def _ap3d(result):
    return {part: ap["AP3D_R40"] for part, ap in result.items()}


def test_only_the_wrong_part_restores_the_ap():
    gt_boxes = _people()
    shifted = gt_boxes.copy()
    shifted[:, 0] += 0.3  # BEV IoU 0.4: paired (>= 0.1) but below IoU 0.5
    assert _ap3d(part_ablation(*_frames(gt_boxes, shifted))) == {
        "as predicted": 0.0, "centre x, y": 1.0, "z, height": 0.0, "length, width": 0.0, "heading": 0.0,
        "all but the centre": 0.0}

    grown = gt_boxes.copy()
    grown[:, 3:5] *= 1.6  # IoU 1 / 1.6^2 = 0.39
    assert _ap3d(part_ablation(*_frames(gt_boxes, grown))) == {
        "as predicted": 0.0, "centre x, y": 0.0, "z, height": 0.0, "length, width": 1.0, "heading": 0.0,
        "all but the centre": 1.0}


def test_a_quarter_turn_is_the_same_box_and_a_turned_heading_is_the_heading():
    gt_boxes = _people()
    gt_boxes[:, 3:5] = [0.9, 0.3]  # elongated, so that the heading matters
    quarter = gt_boxes[:, [0, 1, 2, 4, 3, 5, 6]].copy()
    quarter[:, 6] += np.pi / 2  # the same rectangle written the other way
    assert set(_ap3d(part_ablation(*_frames(gt_boxes, quarter))).values()) == {1.0}

    turned = gt_boxes.copy()
    turned[:, 6] += np.radians(30)
    result = _ap3d(part_ablation(*_frames(gt_boxes, turned)))
    assert result["as predicted"] == result["centre x, y"] == result["length, width"] == 0.0
    assert result["heading"] == result["all but the centre"] == 1.0


def test_a_false_positive_is_left_where_it_is():
    gt_boxes = _people(1)
    shifted = gt_boxes[0].copy()
    shifted[0] += 0.3
    far = gt_boxes[0].copy()
    far[0] += 20.0  # overlaps nothing: stays a false positive, scored above the true positive
    gt, dt = _frames(gt_boxes, [np.stack([far, shifted])], scores=[[0.9, 0.5]])
    result = _ap3d(part_ablation(gt, dt))
    assert result["as predicted"] == 0.0
    assert result["centre x, y"] == 0.5  # precision 1/2 at recall 1 on every R40 point


def test_extent_agreement_of_a_constant_shape_and_of_exact_boxes():
    gt_boxes = _people(4)
    gt_boxes[:, 3] = [0.5, 0.6, 0.8, 0.9]  # length (the larger BEV extent; width 0.5 or less below)
    gt_boxes[:, 4] = [0.3, 0.4, 0.45, 0.5]
    gt_boxes[:, 5] = [1.5, 1.6, 1.7, 1.8]
    gt_boxes[:, 6] = np.radians([0.0, 10.0, 20.0, 40.0])

    exact = extent_agreement(*_frames(gt_boxes, gt_boxes))
    assert exact["pairs"] == 4
    for name in ("length", "width", "height", "heading"):
        assert exact[name]["correlation"] == pytest.approx(1.0, abs=1e-12)
        assert exact[name]["median_abs_error"] == pytest.approx(0.0, abs=1e-12)
    assert exact["length"]["label_mean"] == pytest.approx(0.7, abs=1e-12)
    assert exact["width"]["label_mean"] == pytest.approx(0.4125, abs=1e-12)

    constant = gt_boxes.copy()
    constant[:, 3:6] = [0.6, 0.55, 1.7]
    constant[:, 6] = np.radians(-44.0)  # wraps to 6 deg from 40 deg, not 84
    result = extent_agreement(*_frames(gt_boxes, constant))
    assert result["length"]["pred_std"] == 0.0 and result["length"]["correlation"] is None
    assert result["length"]["median_abs_error"] == pytest.approx(0.15, abs=1e-12)  # |0.6 - (0.5, 0.6, 0.8, 0.9)|
    # -44 deg against 0, 10, 20, 40: errors 44, 54 -> 36, 64 -> 26, 84 -> 6 (a quarter turn wrapped): median 31
    assert result["heading"]["median_abs_error"] == pytest.approx(31.0, abs=1e-9)
    assert "length m" in format_diagnosis(part_ablation(*_frames(gt_boxes, constant)), result)


def _box(dx, dy, heading_deg):
    return [10.0, 0.0, 0.9, dx, dy, 1.8, np.radians(heading_deg)]


@pytest.mark.parametrize("predicted, labelled, error", [
    (_box(0.8, 0.5, 0.0), _box(0.5, 0.8, 90.0), 0.0),  # the same rectangle, sides named the other way
    (_box(0.8, 0.5, 0.0), _box(0.8, 0.5, 180.0), 0.0),  # half a turn: the same rectangle
    (_box(0.8, 0.5, 10.0), _box(0.8, 0.5, 170.0), 20.0),
    (_box(0.8, 0.5, -89.0), _box(0.8, 0.5, 89.0), 2.0),
    (_box(0.8, 0.5, 0.0), _box(0.5, 0.8, 0.0), 90.0),  # long sides at right angles: the largest error
    (_box(0.8, 0.5, 30.0), _box(0.5, 0.8, -45.0), 15.0),  # long sides at 30 and 45 deg
])
def test_orientation_error_respects_the_rectangles_symmetry(predicted, labelled, error):
    assert orientation_error_deg(np.array([predicted]), np.array([labelled]))[0] == pytest.approx(error, abs=1e-9)


def test_orientation_in_the_agreement_of_exact_and_of_constant_boxes():
    gt_boxes = _people(4)
    gt_boxes[:, :2] = [[5.0, 0.0], [15.0, 0.0], [20.0, 2.0], [12.0, -1.0]]  # ranges 5, 15, 20.1, 12.04 m
    gt_boxes[:, 3:5] = [0.8, 0.5]
    gt_boxes[:, 6] = np.radians([0.0, 10.0, 60.0, 100.0])  # long sides at 0, 10, 60, -80 deg
    exact = extent_agreement(*_frames(gt_boxes, gt_boxes))["orientation"]
    assert exact == {"median_abs_error": 0.0, "within_tolerance": 1.0, "by_distance": {
        "0-10m": {"pairs": 1, "median_abs_error": 0.0}, "10-20m": {"pairs": 2, "median_abs_error": 0.0},
        "20+m": {"pairs": 1, "median_abs_error": 0.0}}}
    constant = gt_boxes.copy()
    constant[:, 6] = 0.0  # errors 0, 10, 60, 80
    result = extent_agreement(*_frames(gt_boxes, constant))["orientation"]
    assert result["median_abs_error"] == pytest.approx(35.0, abs=1e-9) and result["within_tolerance"] == 0.5
    by_distance = {label: (entry["pairs"], entry["median_abs_error"]) for label, entry in result["by_distance"].items()}
    assert by_distance == {"0-10m": (1, 0.0), "10-20m": (2, pytest.approx(45.0, abs=1e-9)),
                           "20+m": (1, pytest.approx(60.0, abs=1e-9))}
    near = extent_agreement(*_frames(gt_boxes[:2], constant[:2]))["orientation"]["by_distance"]
    assert near["20+m"] == {"pairs": 0, "median_abs_error": None}  # a bin without a pair has no median


def test_low_scores_and_no_overlap_give_no_pairs():
    gt_boxes = _people(2)
    result = extent_agreement(*_frames(gt_boxes, gt_boxes, scores=[[0.1], [0.2]]))
    assert result == {"pairs": 0, "length": None, "width": None, "height": None, "heading": None, "orientation": None}
    assert list(PARTS) == ["centre x, y", "z, height", "length, width", "heading", "all but the centre"]


def test_a_split_without_labels_writes_strict_json(tmp_path):
    _, dt = _frames([PERSON], [[PERSON]])
    no_labels = [{"name": np.array([], dtype="<U10"), "boxes_lidar": np.zeros((0, 7))}]

    class Unlabelled:
        def aligned_annos(self, det_annos):
            return no_labels, det_annos

    (tmp_path / "result.pkl").write_bytes(pickle.dumps(dt))
    diagnose(Unlabelled(), tmp_path)
    text = (tmp_path / "diagnosis.json").read_text()
    assert "NaN" not in text
    assert json.loads(text)["part_ablation"]["as predicted"]["AP3D_R40"] is None
