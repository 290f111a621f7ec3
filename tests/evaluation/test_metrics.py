"""AP: exact small cases, ground truth against itself, distance bins, and a cross-check against an independent
per-frame reference (shapely IoU, per-threshold counting)."""
import warnings

import numpy as np
import pytest
from shapely.geometry import Polygon

from pcdet_memslidar.evaluation import evaluate, format_results
from pcdet_memslidar.geometry.boxes import boxes_to_corners_3d

AP_KEYS = ["AP3D_R40", "AP3D_R11", "APBEV_R40", "APBEV_R11"]
BINS = ["0-10m", "10-20m", "20+m"]
pytestmark = pytest.mark.filterwarnings("ignore:no ground-truth 'Pedestrian' boxes in the")  # empty bins: expected


def person(x, y, yaw=0.0, z=0.9):
    return [x, y, z, 0.6, 0.5, 1.8, yaw]


def gt_anno(boxes, names=None):
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    return {"name": np.array(names or ["Pedestrian"] * len(boxes)), "boxes_lidar": boxes}


def dt_anno(boxes, scores, names=None):
    return gt_anno(boxes, names) | {"score": np.array(scores, dtype=np.float64)}


def test_ground_truth_against_itself_is_exactly_one():
    rng = np.random.default_rng(0)
    gt = [gt_anno([person(*rng.uniform(-30, 30, 2), rng.uniform(-3, 3)) for _ in range(count)])
          for count in (3, 0, 5, 1, 0, 4)]
    result = evaluate(gt, [anno | {"score": np.ones(len(anno["name"]))} for anno in gt])
    for key in AP_KEYS + [f"{key}_{label}" for key in AP_KEYS for label in BINS]:
        assert result[key] == 1.0, key


def test_hand_computed_curve():
    # 2 people; detections: 0.9 hits, 0.8 misses, 0.7 hits -> (recall, precision) = (1/2, 1), (1/2, 1/2), (1, 2/3)
    gt = [gt_anno([person(5, 0), person(5, 3)])]
    dt = [dt_anno([person(5, 0), person(7, -3), person(5, 3)], [0.9, 0.8, 0.7])]
    result = evaluate(gt, dt)
    assert result["AP3D_R40"] == pytest.approx((20 * 1 + 20 * 2 / 3) / 40, abs=1e-15)
    assert result["AP3D_R11"] == pytest.approx((6 * 1 + 5 * 2 / 3) / 11, abs=1e-15)
    curve = result["pr_curves"]["3D"]["all"]
    np.testing.assert_allclose(curve["recall"], [0.5, 0.5, 1.0])
    np.testing.assert_allclose(curve["precision"], [1.0, 0.5, 2 / 3])
    np.testing.assert_allclose(curve["score"], [0.9, 0.8, 0.7])


def test_one_correct_detection_among_many_people():
    gt = [gt_anno([person(3 + i, 0) for i in range(20)])]  # 1 m apart: no box overlaps another
    result = evaluate(gt, [dt_anno([person(3, 0)], [0.5])])
    assert result["AP3D_R11"] == pytest.approx(1 / 11, abs=1e-15)  # only recall position 0 is reached
    assert result["AP3D_R40"] == pytest.approx(2 / 40, abs=1e-15)  # recall 1/20 reaches positions 1/40 and 2/40


def test_tied_scores_enter_together():
    gt = [gt_anno([person(5, 0)])]
    result = evaluate(gt, [dt_anno([person(5, 0), person(9, 0)], [0.5, 0.5])])
    assert result["AP3D_R40"] == 0.5  # without tie handling the hit would come first and give 1.0


def test_duplicate_detection_is_a_false_positive_and_the_best_overlap_wins():
    gt = [gt_anno([person(5, 0), person(5, 0.45)])]
    # the best detection overlaps both people; it takes the one it overlaps most, the second person stays free
    dt = [dt_anno([person(5, 0.05), person(5, 0.0), person(5, 0.4)], [0.9, 0.8, 0.7])]
    result = evaluate(gt, dt)
    curve = result["pr_curves"]["BEV"]["all"]
    np.testing.assert_array_equal(curve["tp"], [1, 1, 2])
    np.testing.assert_array_equal(curve["fp"], [0, 1, 1])


def test_bev_and_3d_thresholds_differ_for_a_floating_box():
    gt = [gt_anno([person(5, 0)])]
    floating = [dt_anno([person(5, 0, z=1.6)], [0.9])]  # same footprint, 0.7 m too high: 3D IoU 1.1 / 2.5 = 0.44
    result = evaluate(gt, floating)
    assert result["APBEV_R40"] == 1.0
    assert result["AP3D_R40"] == 0.0
    assert evaluate(gt, floating, iou_threshold_3d=0.43)["AP3D_R40"] == 1.0


def test_matches_across_a_bin_border_are_ignored_not_false():
    gt = [gt_anno([person(9.9, 0), person(15, 0)])]
    dt = [dt_anno([person(10.1, 0), person(15, 0), person(18, 0)], [0.9, 0.8, 0.7])]
    result = evaluate(gt, dt, iou_threshold_3d=0.3, iou_threshold_bev=0.3)
    assert result["AP3D_R40_0-10m"] == 1.0  # the person at 9.9 m is found (by a detection at 10.1 m)
    # 10-20 m: the detection at 10.1 m is ignored, the one at 15 m hits, the one at 18 m is a false positive
    curve = result["pr_curves"]["3D"]["10-20m"]
    np.testing.assert_array_equal(curve["tp"], [1, 1])
    np.testing.assert_array_equal(curve["fp"], [0, 1])
    assert result["num_gt"] == {"all": 2, "0-10m": 1, "10-20m": 1, "20+m": 0}
    assert result["num_dt"] == {"all": 3, "0-10m": 0, "10-20m": 3, "20+m": 0}
    assert np.isnan(result["AP3D_R40_20+m"])


def test_empty_ground_truth_gives_nan_with_a_warning_and_other_classes_are_ignored():
    gt = [gt_anno([person(5, 0)], ["Car"]), gt_anno([])]
    dt = [dt_anno([person(5, 0)], [0.9]), dt_anno([], [])]
    with pytest.warns(UserWarning, match="no ground-truth 'Pedestrian' boxes in any frame"):
        result = evaluate(gt, dt)
    assert all(np.isnan(result[key]) for key in AP_KEYS)
    assert "nan" in format_results(result)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        empty = evaluate([], [])
    assert np.isnan(empty["AP3D_R40"]) and empty["num_gt"]["all"] == 0


def test_no_detections_gives_zero():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # empty distance bins
        result = evaluate([gt_anno([person(5, 0)])], [dt_anno([], [])])
    assert all(result[key] == 0.0 for key in AP_KEYS)


def test_bad_annotations_raise():
    with pytest.raises(ValueError, match="1 ground-truth frames but 0 detection frames"):
        evaluate([gt_anno([])], [])
    with pytest.raises(ValueError, match=r"dt_annos\[0\]: missing keys \['score'\]"):
        evaluate([gt_anno([])], [gt_anno([])])
    with pytest.raises(ValueError, match=r"dt_annos\[0\]: 1 names but 2 scores"):
        evaluate([gt_anno([])], [dt_anno([person(1, 1)], [0.1, 0.2])])


# ------------------------------------------------------------------------------------- independent reference
def reference_iou(dt_box, gt_box, kind):
    footprint_dt = Polygon(boxes_to_corners_3d(dt_box[None])[0, :4, :2])
    footprint_gt = Polygon(boxes_to_corners_3d(gt_box[None])[0, :4, :2])
    area = footprint_dt.intersection(footprint_gt).area
    if kind == "BEV":
        return area / (footprint_dt.area + footprint_gt.area - area)
    low = max(dt_box[2] - dt_box[5] / 2, gt_box[2] - gt_box[5] / 2)
    high = min(dt_box[2] + dt_box[5] / 2, gt_box[2] + gt_box[5] / 2)
    volume = area * max(0.0, high - low)
    return volume / (np.prod(dt_box[3:6]) + np.prod(gt_box[3:6]) - volume)


def reference_ap(gt_annos, dt_annos, kind, low, high, positions):
    """Per frame: greedy matching by a plain loop; then precision / recall counted anew at every threshold."""
    rows, num_gt = [], 0  # rows: (score, is_tp) of counted detections
    for gt, dt in zip(gt_annos, dt_annos):
        gt_boxes = [b for b, n in zip(gt["boxes_lidar"], gt["name"]) if n == "Pedestrian"]
        dets = sorted([(s, i, b) for i, (b, n, s) in enumerate(zip(dt["boxes_lidar"], dt["name"], dt["score"]))
                       if n == "Pedestrian"], key=lambda d: (-d[0], d[1]))
        taken = set()
        num_gt += sum(low <= np.hypot(b[0], b[1]) < high for b in gt_boxes)
        for score, _, box in dets:
            best, best_iou = None, 0.5
            for j, gt_box in enumerate(gt_boxes):
                iou = reference_iou(box, gt_box, kind)
                if j not in taken and iou > best_iou:
                    best, best_iou = j, iou
            if best is not None:
                taken.add(best)
                if low <= np.hypot(*gt_boxes[best][:2]) < high:
                    rows.append((score, True))
            elif low <= np.hypot(box[0], box[1]) < high:
                rows.append((score, False))
    points = []
    for threshold in sorted({s for s, _ in rows}, reverse=True):
        tp = sum(hit for s, hit in rows if s >= threshold)
        fp = sum(not hit for s, hit in rows if s >= threshold)
        points.append((tp / num_gt, tp / (tp + fp)))
    recalls = [k / 40 for k in range(1, 41)] if positions == "R40" else [k / 10 for k in range(11)]
    return sum(max([p for r, p in points if r >= recall - 1e-12], default=0.0) for recall in recalls) / len(recalls)


def random_scene(rng, frames=25):
    gt_annos, dt_annos = [], []
    for _ in range(frames):
        count = rng.integers(0, 6)
        centres = rng.uniform(-25, 25, (count, 2))
        boxes = np.column_stack([centres, rng.uniform(0.8, 1.0, count), rng.uniform(0.4, 0.8, (count, 2)),
                                 rng.uniform(1.5, 1.9, count), rng.uniform(-np.pi, np.pi, count)])
        names = ["Pedestrian"] * count
        if count:
            names[0] = "Cyclist" if rng.uniform() < 0.2 else "Pedestrian"
        gt_annos.append(gt_anno(boxes, names))
        hits = boxes[rng.uniform(size=count) < 0.8] + np.concatenate(
            [rng.normal(0, 0.12, (1, 3)), rng.normal(0, 0.05, (1, 3)), rng.normal(0, 0.2, (1, 1))], axis=1)
        duplicates = hits[: rng.integers(0, len(hits) + 1)] + rng.normal(0, 0.1, (1, 7)) * [1, 1, 0, 0, 0, 0, 1]
        clutter_count = rng.integers(0, 4)
        clutter = np.column_stack([rng.uniform(-25, 25, (clutter_count, 2)), np.full(clutter_count, 0.9),
                                   np.full((clutter_count, 2), 0.6), np.full(clutter_count, 1.7),
                                   np.zeros(clutter_count)])
        detections = np.concatenate([hits, duplicates, clutter]).reshape(-1, 7)
        detections[:, 3:6] = np.abs(detections[:, 3:6])
        scores = np.round(rng.uniform(size=len(detections)), 1)  # rounded: many tied scores
        dt_annos.append(dt_anno(detections, scores))
    return gt_annos, dt_annos


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_random_scenes_match_independent_reference(seed):
    gt_annos, dt_annos = random_scene(np.random.default_rng(seed))
    result = evaluate(gt_annos, dt_annos)
    checked = 0
    for kind in ("3D", "BEV"):
        for positions in ("R40", "R11"):
            for label, (low, high) in {"all": (0, np.inf), "0-10m": (0, 10), "10-20m": (10, 20),
                                       "20+m": (20, np.inf)}.items():
                key = f"AP{kind}_{positions}" + ("" if label == "all" else f"_{label}")
                expected = reference_ap(gt_annos, dt_annos, kind, low, high, positions)
                assert result[key] == pytest.approx(expected, abs=1e-12), key
                checked += 0.0 < expected < 1.0
    assert checked >= 8  # the scenes are hard enough that most APs are neither 0 nor 1
