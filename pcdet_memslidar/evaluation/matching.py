"""Greedy score-ordered matching of detections to ground truth, all frames at once.

Every (detection, ground truth) pair of the same frame is a candidate; pairs whose circumscribed circles are apart
are dropped for free, the rest get their exact rotated BEV and 3D IoU in one vectorised call. Then, per IoU kind,
detections in descending score order (ties: input order) each take the still-free ground truth of highest IoU
above the threshold, as KITTI does (strictly greater than the threshold).
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.geometry.iou import aligned_iou, circles_overlap


def same_frame_pairs(dt_frame_counts: np.ndarray, gt_frame_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (detection, ground truth) index pairs within each frame, into the frame-concatenated arrays.

    dt_frame_counts (F,), gt_frame_counts (F,) boxes per frame -> (dt_index (P,), gt_index (P,)).
    """
    pair_counts = dt_frame_counts * gt_frame_counts
    frame = np.repeat(np.arange(len(pair_counts)), pair_counts)
    local = np.arange(pair_counts.sum()) - np.repeat(np.cumsum(pair_counts) - pair_counts, pair_counts)
    gts_in_frame = gt_frame_counts[frame]
    dt_start = np.cumsum(dt_frame_counts) - dt_frame_counts
    gt_start = np.cumsum(gt_frame_counts) - gt_frame_counts
    return dt_start[frame] + local // gts_in_frame, gt_start[frame] + local % gts_in_frame


def pair_ious(dt_boxes: np.ndarray, gt_boxes: np.ndarray, dt_frame_counts: np.ndarray,
              gt_frame_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Same-frame pairs with a chance of overlap: (dt_index (P,), gt_index (P,), BEV IoU (P,), 3D IoU (P,))."""
    dt_index, gt_index = same_frame_pairs(dt_frame_counts, gt_frame_counts)
    near = circles_overlap(dt_boxes[dt_index], gt_boxes[gt_index])
    dt_index, gt_index = dt_index[near], gt_index[near]
    iou_bev, iou_3d = aligned_iou(dt_boxes[dt_index], gt_boxes[gt_index])
    return dt_index, gt_index, iou_bev, iou_3d


def greedy_match(dt_scores: np.ndarray, num_gt: int, dt_index: np.ndarray, gt_index: np.ndarray,
                 iou: np.ndarray, iou_threshold: float) -> np.ndarray:
    """(D,) index of the ground truth each detection matched, -1 for none.

    Pairs (dt_index, gt_index, iou) must only join boxes of the same frame (see pair_ious).
    """
    candidate = iou > iou_threshold
    dt_index, gt_index, iou = dt_index[candidate], gt_index[candidate], iou[candidate]
    rank = np.empty(len(dt_scores), dtype=np.int64)
    rank[np.argsort(-np.asarray(dt_scores, dtype=np.float64), kind="stable")] = np.arange(len(dt_scores))
    order = np.lexsort((-iou, rank[dt_index]))  # by detection rank, then by IoU descending
    matched = np.full(len(dt_scores), -1, dtype=np.int64)
    taken = np.zeros(num_gt, dtype=bool)
    for dt, gt in zip(dt_index[order].tolist(), gt_index[order].tolist()):
        if matched[dt] < 0 and not taken[gt]:
            matched[dt] = gt
            taken[gt] = True
    return matched
