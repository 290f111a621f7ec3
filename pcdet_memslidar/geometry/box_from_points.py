"""A person box from its own points in bird's-eye view.

- Orientation: the main axis of the points (principal component analysis). A person's footprint is longer across
  the shoulders than front to back, and the visible returns follow it; a box's long side is laid along that axis.
  Headings are modulo a half turn (a person box is symmetric).
- Drift: a MEMS scanner sweeps its field of view over a whole frame period (0.4 s for the Cube 1 patterns here),
  and a person's points are taken over much of it: a walking person's points drift along its path. Where the points'
  time offsets are known and they drift at least MIN_DRIFT_SPEED, the long side is laid along the drift instead
  (a walking person's box is longest along its stride).
- Centre: a LiDAR sees a person's near side, so the mean of the returns lies in front of the body's centre, along
  the ray from the sensor; the centre is that mean moved a fixed depth further along the ray. The sensor is above
  (0, 0) of the ground frame (docs/design.md, "Coordinates").
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.geometry.boxes import check_boxes, points_in_boxes_mask

MAX_SHIFTS = 5  # a box's window follows the mean of its points at most this often
SHIFT_TOLERANCE = 0.01  # [m] a window that would move less than this has found its points
MIN_RANGE = 1e-6  # [m] points whose mean is this close to the sensor's axis have no ray: the centre stays
MIN_TIME_SPAN = 1e-3  # [s] points taken closer together than this in time show no drift


def main_axis(points_xy: np.ndarray) -> float | None:
    """Direction [rad] of the largest principal component of (N, 2) points [m]; None where the spread has no main
    axis (one point, or as wide every way: the two variances equal to 1e-9)."""
    centred = points_xy - points_xy.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred)
    if values[1] - values[0] <= 1e-9 * values[1]:
        return None
    return float(np.arctan2(vectors[1, -1], vectors[0, -1]))


def drift_velocity(points_xy: np.ndarray, times: np.ndarray) -> np.ndarray | None:
    """(2,) velocity [m/s] of the least-squares line through (N, 2) positions [m] against their (N,) times [s];
    None where the times span less than MIN_TIME_SPAN."""
    if len(times) < 2 or np.ptp(times) < MIN_TIME_SPAN:
        return None
    centred = times - times.mean()
    return centred @ (points_xy - points_xy.mean(axis=0)) / (centred @ centred)


def centre_behind(points_xy: np.ndarray, depth: float) -> np.ndarray:
    """(2,) the mean of (N, 2) points [m] moved `depth` [m] further from the sensor along the ray through it; the
    mean itself where it lies on the sensor's axis."""
    mean = points_xy.mean(axis=0)
    reach = float(np.hypot(*mean))
    return mean if reach < MIN_RANGE else mean * (1.0 + depth / reach)


def raise_bottoms(boxes: np.ndarray, min_height: float) -> np.ndarray:
    """A copy of (K, 7+) LiDAR boxes with each bottom raised by `min_height` [m] and the top kept."""
    raised = np.array(boxes, dtype=np.float64, copy=True)
    raised[:, 2] += min_height / 2
    raised[:, 5] -= min_height
    return raised


def point_windows(boxes: np.ndarray, margin: float, min_height: float) -> np.ndarray:
    """(K, 7) windows of (K, 7+) LiDAR boxes: each grown by `margin` [m] on every side in x and y, its bottom raised
    by `min_height` [m] (raise_bottoms)."""
    windows = raise_bottoms(np.asarray(boxes)[:, :7], min_height)
    windows[:, 3:5] += 2 * margin
    return windows


def fit_boxes_to_points(boxes, points, min_points: int, margin: float, min_height: float = 0.0,
                        center_depth: float | None = None, times=None,
                        min_drift_speed: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(K, 7+) LiDAR boxes, (N, 3+) points [m] -> (a copy of the boxes, (K,) bool: the box had at least
    `min_points` points in its last window and was fitted to them).

    The points of a box: inside a window, the box grown by `margin` [m] on every side in x and y, and at least
    `min_height` [m] above its bottom (legs apart in a stride, and the floor, run along the walking direction, not the
    shoulders). The window then moves to the mean (x, y) of its points and takes the points there, until it would
    move less than SHIFT_TOLERANCE or has moved MAX_SHIFTS times (mean shift: a detected centre is a tenth of a metre
    or more off, and a window centred on the person holds more of it and less of its surroundings). A box with at
    least `min_points` points in its last window is fitted: with `center_depth` [m], its centre (x, y) moves to
    centre_behind(points, center_depth) (None keeps it); where the points have a main axis (main_axis), its long
    side (dx >= dy) is laid along that axis, heading in [-pi/2, pi/2); with the points' (N,) `times` [s] and
    `min_drift_speed` [m/s], along their drift_velocity instead where it is at least that fast. z, sizes and extra
    columns are kept; the other boxes are returned unchanged.
    """
    settings = (margin, min_height, 0.0 if center_depth is None else center_depth,
                0.0 if min_drift_speed is None else min_drift_speed)
    if min_points < 2 or not all(np.isfinite(value) and value >= 0 for value in settings):
        raise ValueError(f"min_points >= 2 and a margin, min_height, center_depth >= 0 m and min_drift_speed >= 0 "
                         f"m/s, got {min_points}, {margin}, {min_height}, {center_depth}, {min_drift_speed}")
    boxes = np.array(boxes, dtype=np.float64, copy=True)
    points = np.asarray(points, dtype=np.float64)[:, :3]
    times = None if times is None else np.asarray(times, dtype=np.float64)
    if times is not None and len(times) != len(points):
        raise ValueError(f"{len(times)} time offsets for {len(points)} points")
    drift = times is not None and min_drift_speed is not None
    fitted = np.zeros(len(boxes), dtype=bool)
    if not len(boxes) or not len(points):
        return boxes, fitted
    windows = point_windows(check_boxes(boxes[:, :7]), margin, min_height)
    order = np.argsort(points[:, 0], kind="stable")  # points sorted by x: each window reads only its x slab
    sorted_x = points[order, 0]

    def inside(window: np.ndarray) -> np.ndarray:
        """(M,) indices of the points inside `window` (7,)."""
        reach = np.hypot(window[3], window[4]) / 2
        slab = order[np.searchsorted(sorted_x, window[0] - reach, side="left"):
                     np.searchsorted(sorted_x, window[0] + reach, side="right")]
        return slab[points_in_boxes_mask(points[slab], window[None])[:, 0]]

    for index, window in enumerate(windows):
        if window[5] <= 0:  # a box no taller than min_height stays as it is
            continue
        taken = inside(window)
        for _ in range(MAX_SHIFTS):
            if len(taken) < min_points:
                break
            centre = points[taken, :2].mean(axis=0)
            if np.hypot(*(centre - window[:2])) < SHIFT_TOLERANCE:
                break
            window[:2] = centre
            taken = inside(window)
        if len(taken) < min_points:
            continue
        own = points[taken, :2]
        fitted[index] = True
        if center_depth is not None:
            boxes[index, :2] = centre_behind(own, center_depth)
        velocity = drift_velocity(own, times[taken]) if drift else None
        if velocity is not None and np.hypot(*velocity) >= min_drift_speed:
            axis = float(np.arctan2(velocity[1], velocity[0]))
        else:
            axis = main_axis(own)
        if axis is not None:
            boxes[index, 3:5] = max(boxes[index, 3], boxes[index, 4]), min(boxes[index, 3], boxes[index, 4])
            boxes[index, 6] = np.mod(axis + np.pi / 2, np.pi) - np.pi / 2
    return boxes, fitted
