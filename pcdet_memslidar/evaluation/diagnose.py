"""Which part of a box costs the AP, and whether the predicted boxes follow the labels at all.

- part_ablation: the AP again with one part of every detection (centre, z and height, length and width, heading)
  replaced by that of the ground-truth box it overlaps most in BEV. The part whose replacement gains most is what
  the detector gets wrong most.
- extent_agreement: for detections paired with a ground-truth box, the spread of predicted and labelled extents
  and headings and how they correlate. A detector that regresses every box to one mean shape has predicted spread
  near 0 and correlation near 0, whatever its AP.

Boxes are compared as rectangles: both sides are folded (geometry.boxes.fold_box_headings) before a part is
replaced, so (dx, dy, heading) of the two boxes are in the same form; the length is the larger BEV extent, the
width the smaller. A rectangle looks the same turned by half a turn, so its orientation is that of its long side,
modulo 180 deg (fold_box_headings 'half'): the heading error of a person box is the angle between the two long
sides, in [0, 90] deg; a detector that has not learned it scores a median of 45 deg on people facing every way.
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.evaluation.matching import pair_ious
from pcdet_memslidar.evaluation.metrics import DISTANCE_BINS, bin_label, evaluate, stack_class
from pcdet_memslidar.geometry.boxes import fold_box_headings
from pcdet_memslidar.io.kitti import CLASS_NAME

MIN_BEV_IOU = 0.1  # a detection overlapping no ground truth this much is a false positive: left as it is
SCORE_THRESHOLD = 0.3  # extent_agreement looks at detections at least this confident
PARTS: dict[str, tuple[int, ...]] = {  # part -> box columns [x, y, z, dx, dy, dz, heading]
    "centre x, y": (0, 1),
    "z, height": (2, 5),
    "length, width": (3, 4),
    "heading": (6,),
    "all but the centre": (2, 3, 4, 5, 6),
}


def nearest_ground_truth(gt_annos: list[dict], dt_annos: list[dict], min_bev_iou: float = MIN_BEV_IOU,
                         class_name: str = CLASS_NAME):
    """Each detection's ground-truth box of highest BEV IoU in its frame.

    Returns gt boxes (G, 7), dt boxes (D, 7), dt scores (D,), dt counts per frame (F,) and the index (D,) into the
    gt boxes, -1 where no ground truth overlaps at least min_bev_iou.
    """
    gt_boxes, _, gt_counts = stack_class(gt_annos, class_name, with_score=False, kind="gt")
    dt_boxes, dt_scores, dt_counts = stack_class(dt_annos, class_name, with_score=True, kind="dt")
    dt_index, gt_index, iou_bev, _ = pair_ious(dt_boxes, gt_boxes, dt_counts, gt_counts)
    keep = iou_bev >= min_bev_iou
    dt_index, gt_index, iou_bev = dt_index[keep], gt_index[keep], iou_bev[keep]
    order = np.lexsort((-iou_bev, dt_index))  # per detection, highest IoU first
    nearest = np.full(len(dt_boxes), -1, dtype=np.int64)
    first = np.unique(dt_index[order], return_index=True)[1]
    nearest[dt_index[order][first]] = gt_index[order][first]
    return gt_boxes, dt_boxes, dt_scores, dt_counts, nearest


def _annos(boxes: np.ndarray, scores: np.ndarray, counts: np.ndarray, class_name: str) -> list[dict]:
    """Per-frame anno dicts of frame-concatenated boxes (D, 7) and scores (D,)."""
    cuts = np.cumsum(counts)[:-1]
    return [{"name": np.full(len(b), class_name), "boxes_lidar": b, "score": s}
            for b, s in zip(np.split(boxes, cuts), np.split(scores, cuts))]


def part_ablation(gt_annos: list[dict], dt_annos: list[dict], parts: dict[str, tuple[int, ...]] = PARTS,
                  min_bev_iou: float = MIN_BEV_IOU, class_name: str = CLASS_NAME) -> dict[str, dict[str, float]]:
    """{'as predicted' | part: {'AP3D_R40', 'APBEV_R40'}}: AP with `part` of every detection that overlaps ground
    truth (BEV IoU >= min_bev_iou) replaced by its nearest ground truth's. Frames aligned as in metrics.evaluate."""
    gt_boxes, dt_boxes, dt_scores, dt_counts, nearest = nearest_ground_truth(gt_annos, dt_annos, min_bev_iou,
                                                                             class_name)
    folded_dt, folded_gt = fold_box_headings(dt_boxes), fold_box_headings(gt_boxes)
    paired = nearest >= 0
    result = {}
    for part, columns in {"as predicted": (), **parts}.items():
        boxes = folded_dt.copy()
        for column in columns:
            boxes[paired, column] = folded_gt[nearest[paired], column]
        scored = evaluate(gt_annos, _annos(boxes, dt_scores, dt_counts, class_name), class_name=class_name)
        result[part] = {"AP3D_R40": scored["AP3D_R40"], "APBEV_R40": scored["APBEV_R40"]}
    return result


ORIENTATION_TOLERANCE_DEG = 15.0  # extent_agreement's share of pairs whose long sides agree this well


def orientation_error_deg(dt_boxes: np.ndarray, gt_boxes: np.ndarray) -> np.ndarray:
    """(M,) angle [deg] in [0, 90] between the long sides of paired boxes (M, 7+)."""
    difference = fold_box_headings(dt_boxes, "half")[:, 6] - fold_box_headings(gt_boxes, "half")[:, 6]
    return np.abs(np.degrees(np.mod(difference + np.pi / 2, np.pi) - np.pi / 2))


def _agreement(predicted: np.ndarray, labelled: np.ndarray) -> dict[str, float | None]:
    """Means, standard deviations, Pearson correlation (None if either side is constant) and the median absolute
    error of paired values (n,)."""
    spread = predicted.std() > 0 and labelled.std() > 0
    return {"label_mean": float(labelled.mean()), "label_std": float(labelled.std()),
            "pred_mean": float(predicted.mean()), "pred_std": float(predicted.std()),
            "correlation": float(np.corrcoef(predicted, labelled)[0, 1]) if spread else None,
            "median_abs_error": float(np.median(np.abs(predicted - labelled)))}


def extent_agreement(gt_annos: list[dict], dt_annos: list[dict], score_threshold: float = SCORE_THRESHOLD,
                     min_bev_iou: float = MIN_BEV_IOU, class_name: str = CLASS_NAME) -> dict:
    """How the boxes of detections scoring >= score_threshold follow those of their nearest ground truth.

    Returns {'pairs': n, 'length' | 'width' | 'height' [m] | 'heading' [deg]: _agreement, 'orientation':
    {'median_abs_error' [deg], 'within_tolerance' (share of pairs within ORIENTATION_TOLERANCE_DEG), 'by_distance':
    {bin label: {'pairs', 'median_abs_error' (None without a pair)}} over metrics.DISTANCE_BINS of the labelled
    box's BEV range}}; length and width are the larger and smaller BEV extents, heading the folded heading in
    [-45, 45) deg (its error wraps a quarter turn), orientation the long side's (orientation_error_deg). With no pair
    every entry but 'pairs' is None.
    """
    gt_boxes, dt_boxes, dt_scores, _, nearest = nearest_ground_truth(gt_annos, dt_annos, min_bev_iou, class_name)
    paired = (nearest >= 0) & (dt_scores >= score_threshold)
    dt, gt = fold_box_headings(dt_boxes[paired]), fold_box_headings(gt_boxes[nearest[paired]])
    names = ("length", "width", "height", "heading", "orientation")
    if not len(dt):
        return {"pairs": 0} | dict.fromkeys(names)
    result = {"pairs": int(len(dt))}
    for name, pick in (("length", np.max), ("width", np.min)):
        result[name] = _agreement(pick(dt[:, 3:5], axis=1), pick(gt[:, 3:5], axis=1))
    result["height"] = _agreement(dt[:, 5], gt[:, 5])
    heading_dt, heading_gt = np.degrees(dt[:, 6]), np.degrees(gt[:, 6])
    result["heading"] = _agreement(heading_dt, heading_gt)
    result["heading"]["median_abs_error"] = float(np.median(np.abs((heading_dt - heading_gt + 45.0) % 90.0 - 45.0)))
    errors = orientation_error_deg(dt, gt)
    distance = np.hypot(gt[:, 0], gt[:, 1])
    by_distance = {}
    for low, high in DISTANCE_BINS:
        inside = errors[(distance >= low) & (distance < high)]
        by_distance[bin_label(low, high)] = {"pairs": int(len(inside)),
                                             "median_abs_error": float(np.median(inside)) if len(inside) else None}
    result["orientation"] = {"median_abs_error": float(np.median(errors)),
                             "within_tolerance": float(np.mean(errors <= ORIENTATION_TOLERANCE_DEG)),
                             "by_distance": by_distance}
    return result


def format_diagnosis(ablation: dict, agreement: dict) -> str:
    """Two small tables: AP per replaced part, and predicted against labelled extents."""
    lines = ["AP with one part of each detection replaced by its nearest ground truth's (BEV IoU >= "
             f"{MIN_BEV_IOU}):", f"{'part replaced':>20} {'AP3D_R40':>9} {'APBEV_R40':>9}"]
    lines += [f"{part:>20} {ap['AP3D_R40']:>9.4f} {ap['APBEV_R40']:>9.4f}" for part, ap in ablation.items()]
    lines.append(f"Predicted against labelled boxes, {agreement['pairs']} detections (score >= {SCORE_THRESHOLD}) "
                 "paired with ground truth:")
    lines.append(f"{'':>8} {'label mean':>10} {'label std':>9} {'pred mean':>9} {'pred std':>8} {'corr':>6} "
                 f"{'median |err|':>12}")
    for name, unit in (("length", "m"), ("width", "m"), ("height", "m"), ("heading", "deg")):
        entry = agreement[name]
        if entry is None:
            continue
        corr = "-" if entry["correlation"] is None else f"{entry['correlation']:.2f}"
        lines.append(f"{name + ' ' + unit:>8} {entry['label_mean']:>10.3f} {entry['label_std']:>9.3f} "
                     f"{entry['pred_mean']:>9.3f} {entry['pred_std']:>8.3f} {corr:>6} "
                     f"{entry['median_abs_error']:>12.3f}")
    if agreement["orientation"] is not None:
        orientation = agreement["orientation"]
        lines.append(f"Long side's orientation (mod 180 deg): median error {orientation['median_abs_error']:.1f} deg, "
                     f"{100 * orientation['within_tolerance']:.0f} % within {ORIENTATION_TOLERANCE_DEG:g} deg")
        lines.append("  by the person's range: " + ", ".join(
            f"{label} {'-' if entry['median_abs_error'] is None else format(entry['median_abs_error'], '.1f')} deg "
            f"({entry['pairs']} pairs)" for label, entry in orientation["by_distance"].items()))
    return "\n".join(lines)
