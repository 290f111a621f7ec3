"""A person's heading from its own points: the main axis of the points in bird's-eye view (principal component
analysis). A person's footprint is longer across the shoulders than front to back, and the visible returns follow
it; a box's long side is laid along that axis. Headings are modulo a half turn (a person box is symmetric)."""
from __future__ import annotations

import numpy as np

from .boxes import check_boxes, points_in_boxes_mask

MAX_SHIFTS = 5  # a box's window follows the mean of its points at most this often
SHIFT_TOLERANCE = 0.01  # [m] a window that would move less than this has found its points


def main_axis(points_xy: np.ndarray) -> float | None:
    """Direction [rad] of the largest principal component of (N, 2) points [m]; None where the spread has no main
    axis (one point, or as wide every way: the two variances equal to 1e-9)."""
    centred = points_xy - points_xy.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred)
    if values[1] - values[0] <= 1e-9 * values[1]:
        return None
    return float(np.arctan2(vectors[1, -1], vectors[0, -1]))


def raise_bottoms(boxes: np.ndarray, min_height: float) -> np.ndarray:
    """A copy of (K, 7+) LiDAR boxes with each bottom raised by `min_height` [m] and the top kept."""
    raised = np.array(boxes, dtype=np.float64, copy=True)
    raised[:, 2] += min_height / 2
    raised[:, 5] -= min_height
    return raised


def orient_boxes_by_points(boxes, points, min_points: int, margin: float,
                           min_height: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(K, 7+) LiDAR boxes, (N, 3+) points [m] -> (a copy of the boxes, (K,) bool: the box was oriented).

    The points of a box: inside a window, the box grown by `margin` [m] on every side in x and y, and at least
    `min_height` [m] above its bottom (legs apart in a stride, and the floor, run along the walking direction, not the
    shoulders). The window then moves to the mean (x, y) of its points and takes the points there, until it would
    move less than SHIFT_TOLERANCE or has moved MAX_SHIFTS times (mean shift: a detected centre is a tenth of a metre
    or more off, and a window centred on the person holds more of it and less of its surroundings). Each box with at
    least `min_points` points in its last window and a main axis (main_axis) gets its long side (dx >= dy) along that
    axis, heading in [-pi/2, pi/2); centre, sizes and extra columns are kept. The others are returned unchanged.
    """
    if min_points < 2 or not np.isfinite(margin) or margin < 0 or not np.isfinite(min_height) or min_height < 0:
        raise ValueError(f"min_points >= 2, a margin >= 0 m and a min_height >= 0 m, got {min_points}, {margin}, "
                         f"{min_height}")
    boxes = np.array(boxes, dtype=np.float64, copy=True)
    points = np.asarray(points, dtype=np.float64)[:, :3]
    oriented = np.zeros(len(boxes), dtype=bool)
    if not len(boxes) or not len(points):
        return boxes, oriented
    windows = raise_bottoms(check_boxes(boxes[:, :7]), min_height)
    windows[:, 3:5] += 2 * margin
    order = np.argsort(points[:, 0], kind="stable")  # points sorted by x: each window reads only its x slab
    sorted_x = points[order, 0]

    def inside(window: np.ndarray) -> np.ndarray:
        """(M, 2) x, y of the points inside `window` (7,)."""
        reach = np.hypot(window[3], window[4]) / 2
        slab = points[order[np.searchsorted(sorted_x, window[0] - reach, side="left"):
                            np.searchsorted(sorted_x, window[0] + reach, side="right")]]
        return slab[points_in_boxes_mask(slab, window[None])[:, 0], :2]

    for index, window in enumerate(windows):
        if window[5] <= 0:  # a box no taller than min_height keeps its heading
            continue
        own = inside(window)
        for _ in range(MAX_SHIFTS):
            if len(own) < min_points:
                break
            centre = own.mean(axis=0)
            if np.hypot(*(centre - window[:2])) < SHIFT_TOLERANCE:
                break
            window[:2] = centre
            own = inside(window)
        axis = main_axis(own) if len(own) >= min_points else None
        if axis is None:
            continue
        boxes[index, 3:5] = max(boxes[index, 3], boxes[index, 4]), min(boxes[index, 3], boxes[index, 4])
        boxes[index, 6] = np.mod(axis + np.pi / 2, np.pi) - np.pi / 2
        oriented[index] = True
    return boxes, oriented
