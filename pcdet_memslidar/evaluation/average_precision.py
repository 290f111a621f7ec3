"""Precision-recall curves and interpolated Average Precision (KITTI / OpenPCDet R40 and R11)."""
from __future__ import annotations

import numpy as np

# Recall positions as integer fractions (numerator / denominator): compared exactly, with no rounding at 0.1 steps.
RECALL_POSITIONS = {
    "R40": (np.arange(1, 41), 40),  # 1/40 ... 1 (OpenPCDet's default; Simonelli et al. 2019)
    "R11": (np.arange(0, 11), 10),  # 0, 0.1, ... 1 (original KITTI / PASCAL VOC 2007)
}


def precision_recall_curve(scores: np.ndarray, is_tp: np.ndarray, num_gt: int,
                           weights: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Curve of the detections kept at each distinct score threshold, best score first.

    scores (D,), is_tp (D,) bool of the counted detections (ignored ones already removed); num_gt counted ground
    truths. weights (D,) int >= 0, default 1: a detection counts `weight` times (its frame taken that many times, as
    in a bootstrap resample), weight 0 leaves it out. Returns {'score': (T,), 'tp': (T,) int, 'fp': (T,) int,
    'recall': (T,), 'precision': (T,)}: detections with equal scores enter together, so ties never favour true
    positives.
    """
    scores, is_tp = np.asarray(scores, dtype=np.float64), np.asarray(is_tp, dtype=bool)
    weights = np.ones(len(scores), dtype=np.int64) if weights is None else np.asarray(weights, dtype=np.int64)
    kept = weights > 0
    scores, is_tp, weights = scores[kept], is_tp[kept], weights[kept]
    order = np.argsort(-scores, kind="stable")
    scores, is_tp, weights = scores[order], is_tp[order], weights[order]
    tp, fp = np.cumsum(weights * is_tp), np.cumsum(weights * ~is_tp)
    last_of_tie = np.append(scores[1:] != scores[:-1], True) if len(scores) else np.zeros(0, dtype=bool)
    tp, fp, scores = tp[last_of_tie], fp[last_of_tie], scores[last_of_tie]
    with np.errstate(invalid="ignore", divide="ignore"):
        recall = tp / num_gt if num_gt > 0 else np.full(len(tp), np.nan)
        precision = tp / np.maximum(tp + fp, 1)
    return {"score": scores, "tp": tp, "fp": fp, "recall": recall, "precision": precision}


def interpolated_ap(curve: dict[str, np.ndarray], num_gt: int, positions: str = "R40") -> float:
    """Mean over the recall positions r of the best precision reached at recall >= r (0 if never reached).

    NaN when num_gt is 0 (recall undefined).
    """
    if num_gt == 0:
        return float("nan")
    numerators, denominator = RECALL_POSITIONS[positions]
    # best precision at recall >= tp / num_gt, for every curve point (running maximum from the end)
    best_after = np.maximum.accumulate(curve["precision"][::-1])[::-1]
    # first curve point with tp / num_gt >= k / denominator, in integers: tp * denominator >= k * num_gt
    first = np.searchsorted(curve["tp"] * denominator, numerators * num_gt, side="left")
    reached = first < len(best_after)
    precision = np.where(reached, best_after[np.minimum(first, len(best_after) - 1)] if len(best_after) else 0.0, 0.0)
    return float(precision.mean())
