"""Bootstrap confidence intervals of AP over the test frames: percentile intervals, deterministic for a seed.

A resample draws F of the F test frames with replacement: a count vector (F,) (multinomial), frame f taken counts[f]
times. Matching is per frame and does not depend on the other frames, so detections are matched once
(metrics.match_annos) and a resample only weights each detection by its frame's count: its AP is exactly evaluate()'s
on the frames repeated that many times. AP over all distances, counted as evaluate()'s 'all' range: every ground truth
is a positive, every matched detection a true positive, every other detection a false positive.

Several seeds of one model: each resample also draws K of the model's K seeds with replacement (seed_counts (K,),
drawn for each model on its own) and averages their AP, weighted by those counts, on the same frame counts: the
interval then covers the spread over seeds as well as the draw of test frames (with one seed, the frames only). Two
models: the same frame counts for both (they are scored on the same frames), so their difference is paired. An
interval is the pair of (1 - level) / 2 and (1 + level) / 2 quantiles of the resampled values. AP values are
fractions in [0, 1].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.evaluation.average_precision import RECALL_POSITIONS, interpolated_ap, precision_recall_curve
from pcdet_memslidar.evaluation.metrics import match_annos
from pcdet_memslidar.io.kitti import CLASS_NAME

RESAMPLES = 1000
LEVEL = 0.95
SEED = 0


@dataclass(frozen=True)
class FrameMatches:
    """One run's detections on F test frames, matched for one IoU kind, best score first: score (D,), is_tp (D,)
    bool, frame (D,) int index of the detection's frame; num_gt (F,) int ground truths per frame."""
    score: np.ndarray
    is_tp: np.ndarray
    frame: np.ndarray
    num_gt: np.ndarray


def frame_matches(gt_annos: list[dict], dt_annos: list[dict], iou_threshold_3d: float = 0.5,
                  iou_threshold_bev: float = 0.5, class_name: str = CLASS_NAME) -> dict[str, FrameMatches]:
    """{'3D' | 'BEV': FrameMatches} of frame-aligned annotations (as metrics.evaluate takes them)."""
    matches = match_annos(gt_annos, dt_annos, iou_threshold_3d, iou_threshold_bev, class_name)
    order = np.argsort(-matches["dt_scores"], kind="stable")
    frame = np.repeat(np.arange(len(gt_annos)), matches["dt_counts"])[order]
    return {kind: FrameMatches(matches["dt_scores"][order], matched[order] >= 0, frame, matches["gt_counts"])
            for kind, matched in matches["matched"].items()}


def resample_counts(num_frames: int, resamples: int = RESAMPLES, seed: int = SEED) -> np.ndarray:
    """(resamples, num_frames) int: how often each frame (or each of a model's seeds) is drawn in each resample
    (every row sums to num_frames; all ones for one)."""
    if resamples < 1:
        raise ValueError(f"bootstrap: resamples must be at least 1, got {resamples}")
    if num_frames < 1:
        raise ValueError("bootstrap: no test frames to resample")
    rng = np.random.default_rng(seed)
    return rng.multinomial(num_frames, np.full(num_frames, 1.0 / num_frames), size=resamples)


def weighted_ap(matches: FrameMatches, counts: np.ndarray) -> dict[str, float]:
    """{'R40' | 'R11': AP} of the frames taken counts (F,) int times each; NaN when they hold no ground truth."""
    counts = np.asarray(counts, dtype=np.int64)
    if counts.shape != matches.num_gt.shape:
        raise ValueError(f"bootstrap: {counts.shape[-1]} frame counts for {len(matches.num_gt)} frames")
    num_gt = int(counts @ matches.num_gt)
    curve = precision_recall_curve(matches.score, matches.is_tp, num_gt, counts[matches.frame])
    return {positions: interpolated_ap(curve, num_gt, positions) for positions in RECALL_POSITIONS}


def bootstrap_ap(runs: list[FrameMatches], counts: np.ndarray,
                 seed_counts: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """{'R40' | 'R11': (B,) AP averaged over `runs` (the seeds of one model, one IoU kind)} for each resample row of
    counts (B, F), each seed weighted by its row of seed_counts (B, K) (None: every seed once)."""
    num_frames(runs)
    seed_counts = np.ones((len(counts), len(runs))) if seed_counts is None else np.asarray(seed_counts, float)
    if seed_counts.shape != (len(counts), len(runs)):
        raise ValueError(f"bootstrap: seed counts of shape {seed_counts.shape} for {len(counts)} resamples of "
                         f"{len(runs)} seeds")
    aps = {positions: np.empty((len(counts), len(runs))) for positions in RECALL_POSITIONS}
    for resample, row in enumerate(counts):
        for index, run in enumerate(runs):
            for positions, value in weighted_ap(run, row).items():
                aps[positions][resample, index] = value
    return {positions: (values * seed_counts).sum(axis=1) / seed_counts.sum(axis=1)
            for positions, values in aps.items()}


def num_frames(runs: list[FrameMatches]) -> int:
    """F, the test frames every run is scored on; ValueError when the runs differ in frames or ground truth."""
    if not runs:
        raise ValueError("bootstrap: no runs given")
    lengths = sorted({len(run.num_gt) for run in runs})
    if len(lengths) > 1:
        raise ValueError(f"bootstrap: the runs cover {lengths} frames; score every run on the same test frames")
    if any(not np.array_equal(run.num_gt, runs[0].num_gt) for run in runs):
        raise ValueError("bootstrap: the runs have different ground truth per frame; score them on the same frames")
    return lengths[0]


def check_level(level: float) -> None:
    """ValueError unless 0 < level < 1."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"bootstrap: the confidence level must be inside (0, 1), got {level}")


def percentile_interval(values: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    """(low, high): the (1 - level) / 2 and (1 + level) / 2 quantiles of resampled values (B,); NaN if any is NaN."""
    check_level(level)
    low, high = np.quantile(np.asarray(values, dtype=np.float64), [(1.0 - level) / 2, (1.0 + level) / 2])
    return float(low), float(high)


def ap_interval(runs: list[FrameMatches], positions: str = "R40", resamples: int = RESAMPLES, level: float = LEVEL,
                seed: int = SEED) -> tuple[float, float]:
    """Interval (low, high) of the seed-mean AP of one model's runs (FrameMatches of one IoU kind per seed)."""
    check_level(level)
    counts = resample_counts(num_frames(runs), resamples, seed)
    return percentile_interval(bootstrap_ap(runs, counts)[positions], level)


def difference_interval(runs_a: list[FrameMatches], runs_b: list[FrameMatches], positions: str = "R40",
                        resamples: int = RESAMPLES, level: float = LEVEL, seed: int = SEED) -> tuple[float, float]:
    """Paired interval (low, high) of model a's seed-mean AP minus model b's: the same resampled frames for both."""
    check_level(level)
    counts = resample_counts(num_frames([*runs_a, *runs_b]), resamples, seed)
    return percentile_interval(bootstrap_ap(runs_a, counts)[positions] - bootstrap_ap(runs_b, counts)[positions],
                               level)
