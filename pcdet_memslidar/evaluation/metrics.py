"""Average Precision of the person class: 3D and BEV IoU, R40 and R11, overall and per distance bin.

Annotations are one dict per frame, as OpenPCDet's: {'name': (M,) str, 'boxes_lidar': (M, 7) [x, y, z_center,
dx, dy, dz, heading], 'score': (M,)} (ground truth needs no score). Only objects named `class_name` count.

Distance bins use the BEV range sqrt(x^2 + y^2) [m] of a box centre from the sensor origin. Detections are matched
once, against all ground truth of their frame (matching.py); a bin then counts, like KITTI's difficulty levels:
- ground truth inside the bin as positives;
- a detection matched to ground truth inside the bin as a true positive;
- a detection matched to ground truth outside the bin as neither (ignored): the person is found, just not scored here;
- an unmatched detection as a false positive when its own centre is inside the bin, else ignored.
So a person at 9.9 m detected at 10.1 m is a true positive of the 0-10 m bin and no false positive of 10-20 m.
"""
from __future__ import annotations

import warnings

import numpy as np

from pcdet_memslidar.evaluation.average_precision import interpolated_ap, precision_recall_curve
from pcdet_memslidar.evaluation.matching import greedy_match, pair_ious
from pcdet_memslidar.geometry.boxes import check_boxes
from pcdet_memslidar.io.kitti import CLASS_NAME

DISTANCE_BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, float("inf")))  # [m], lower bound included


def bin_label(low: float, high: float) -> str:
    """'0-10m', '20+m'."""
    return f"{low:g}+m" if np.isinf(high) else f"{low:g}-{high:g}m"


def stack_class(annos: list[dict], class_name: str, with_score: bool, kind: str):
    """Boxes (B, 7), scores (B,) of `class_name` over all frames and their per-frame counts (F,)."""
    boxes, scores, counts = [], [], []
    for frame, anno in enumerate(annos):
        missing = {"name", "boxes_lidar"} | ({"score"} if with_score else set())
        if missing - anno.keys():
            raise ValueError(f"{kind}_annos[{frame}]: missing keys {sorted(missing - anno.keys())}")
        names = np.asarray(anno["name"]).reshape(-1)
        keep = names == class_name
        frame_boxes = np.asarray(anno["boxes_lidar"], dtype=np.float64).reshape(-1, 7)
        if len(frame_boxes) != len(names):
            raise ValueError(f"{kind}_annos[{frame}]: {len(names)} names but {len(frame_boxes)} boxes")
        boxes.append(check_boxes(frame_boxes[keep], f"{kind}_annos[{frame}]['boxes_lidar']"))
        if with_score:
            frame_scores = np.asarray(anno["score"], dtype=np.float64).reshape(-1)
            if len(frame_scores) != len(names):
                raise ValueError(f"{kind}_annos[{frame}]: {len(names)} names but {len(frame_scores)} scores")
            scores.append(frame_scores[keep])
        counts.append(int(keep.sum()))
    boxes = np.concatenate(boxes) if boxes else np.zeros((0, 7))
    scores = np.concatenate(scores) if scores else np.zeros(0)
    return boxes, scores, np.asarray(counts, dtype=np.int64)


def match_annos(gt_annos: list[dict], dt_annos: list[dict], iou_threshold_3d: float = 0.5,
                iou_threshold_bev: float = 0.5, class_name: str = CLASS_NAME) -> dict:
    """The `class_name` boxes of frame-aligned annotations, detections matched once per IoU kind (matching.py).

    Returns {'gt_boxes': (G, 7), 'gt_counts': (F,), 'dt_boxes': (D, 7), 'dt_scores': (D,), 'dt_counts': (F,) boxes
    per frame, 'matched': {'3D' | 'BEV': (D,) index into gt_boxes of each detection's ground truth, -1 for none}}.
    """
    if len(gt_annos) != len(dt_annos):
        raise ValueError(f"{len(gt_annos)} ground-truth frames but {len(dt_annos)} detection frames: give one anno "
                         "per frame")
    gt_boxes, _, gt_counts = stack_class(gt_annos, class_name, with_score=False, kind="gt")
    dt_boxes, dt_scores, dt_counts = stack_class(dt_annos, class_name, with_score=True, kind="dt")
    dt_index, gt_index, iou_bev, iou_3d = pair_ious(dt_boxes, gt_boxes, dt_counts, gt_counts)
    matched = {kind: greedy_match(dt_scores, len(gt_boxes), dt_index, gt_index, iou, threshold)
               for kind, iou, threshold in (("3D", iou_3d, iou_threshold_3d), ("BEV", iou_bev, iou_threshold_bev))}
    return {"gt_boxes": gt_boxes, "gt_counts": gt_counts, "dt_boxes": dt_boxes, "dt_scores": dt_scores,
            "dt_counts": dt_counts, "matched": matched}


def evaluate(gt_annos: list[dict], dt_annos: list[dict], iou_threshold_3d: float = 0.5,
             iou_threshold_bev: float = 0.5, class_name: str = CLASS_NAME,
             distance_bins=DISTANCE_BINS) -> dict:
    """AP of `class_name` for frame-aligned ground truth and detections.

    Returns {'AP3D_R40', 'AP3D_R11', 'APBEV_R40', 'APBEV_R11': float in [0, 1] over all distances; the same keys
    with a bin suffix ('AP3D_R40_0-10m', ...); 'num_gt' and 'num_dt': {'all' | bin: count}; 'pr_curves':
    {'3D' | 'BEV': {'all' | bin: precision_recall_curve dict}}}. A bin (or data set) without ground truth has AP
    NaN, with a warning. Ground truth scored against itself gives exactly 1.0.
    """
    matches = match_annos(gt_annos, dt_annos, iou_threshold_3d, iou_threshold_bev, class_name)
    gt_boxes, dt_boxes, dt_scores = matches["gt_boxes"], matches["dt_boxes"], matches["dt_scores"]
    gt_range = np.hypot(gt_boxes[:, 0], gt_boxes[:, 1])
    dt_range = np.hypot(dt_boxes[:, 0], dt_boxes[:, 1])
    bins = {"all": (0.0, float("inf"))} | {bin_label(*limits): limits for limits in distance_bins}

    result: dict = {"num_gt": {}, "num_dt": {}, "pr_curves": {"3D": {}, "BEV": {}}}
    for kind, matched in matches["matched"].items():
        matched_range = gt_range[np.maximum(matched, 0)] if len(gt_boxes) else np.zeros(len(matched))
        for label, (low, high) in bins.items():
            gt_in_bin = (gt_range >= low) & (gt_range < high)
            tp = (matched >= 0) & (matched_range >= low) & (matched_range < high)
            fp = (matched < 0) & (dt_range >= low) & (dt_range < high)
            num_gt = int(gt_in_bin.sum())
            counted = tp | fp
            curve = precision_recall_curve(dt_scores[counted], tp[counted], num_gt)
            suffix = "" if label == "all" else f"_{label}"
            result["pr_curves"][kind][label] = curve
            result[f"AP{kind}_R40{suffix}"] = interpolated_ap(curve, num_gt, "R40")
            result[f"AP{kind}_R11{suffix}"] = interpolated_ap(curve, num_gt, "R11")
            result["num_gt"][label] = num_gt
            result["num_dt"][label] = int(((dt_range >= low) & (dt_range < high)).sum())
    for label, count in result["num_gt"].items():
        if count == 0:
            where = "in any frame" if label == "all" else f"in the {label} bin"
            warnings.warn(f"no ground-truth '{class_name}' boxes {where}: its AP is NaN", stacklevel=2)
    return result


def ap_summary(result: dict) -> dict[str, float | None]:
    """The AP values of `result` (overall and per bin) as a flat JSON-ready dict; NaN becomes None."""
    return {key: (None if np.isnan(value) else value) for key, value in result.items() if key.startswith("AP")}


def format_results(result: dict) -> str:
    """Table of AP (fractions in [0, 1]) per distance bin, with ground-truth and detection counts."""
    labels = list(result["num_gt"])
    columns = ["AP3D_R40", "AP3D_R11", "APBEV_R40", "APBEV_R11"]
    lines = [f"{'range':>8} {'#gt':>6} {'#det':>6} " + " ".join(f"{name:>9}" for name in columns)]
    for label in labels:
        suffix = "" if label == "all" else f"_{label}"
        values = " ".join(f"{result[name + suffix]:>9.4f}" for name in columns)
        lines.append(f"{label:>8} {result['num_gt'][label]:>6} {result['num_dt'][label]:>6} {values}")
    return "\n".join(lines)
