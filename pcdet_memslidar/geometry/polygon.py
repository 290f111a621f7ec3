"""Polygons on the ground plane: which points lie inside (zones, walkable areas), and whether a polygon crosses
itself."""
from __future__ import annotations

import numpy as np


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(...,) bool: points (..., 2) [m] inside the simple polygon (K, 2) or on its border (even-odd rule)."""
    shape = np.shape(points)[:-1]
    points = np.asarray(points, np.float64).reshape(-1, 2)
    polygon = np.asarray(polygon, np.float64)
    a, b = polygon, np.roll(polygon, -1, axis=0)  # (K, 2) edge starts and ends
    px, py = points[:, None, 0], points[:, None, 1]
    (ax, ay), (bx, by) = a.T[:, None, :], b.T[:, None, :]  # (1, K) each
    straddles = (ay > py) != (by > py)  # edges that cross the horizontal line through the point
    with np.errstate(divide="ignore", invalid="ignore"):
        cross_x = ax + (py - ay) * (bx - ax) / (by - ay)
    inside = (straddles & (px < cross_x)).sum(axis=1) % 2 == 1
    return (inside | _on_border(points, a, b)).reshape(shape)


def _on_border(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) bool: points (N, 2) on one of the segments a[k] -> b[k] (exactly, up to float rounding of 1e-12 m)."""
    p = points[:, None, :]
    edge, rel = (b - a)[None], p - a[None]
    cross = edge[..., 0] * rel[..., 1] - edge[..., 1] * rel[..., 0]
    dot = (rel * edge).sum(axis=2)
    return ((np.abs(cross) <= 1e-12 * np.maximum(1.0, (edge ** 2).sum(axis=2))) & (dot >= 0)
            & (dot <= (edge ** 2).sum(axis=2))).any(axis=1)


def _orientation(p, q, r) -> float:
    return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])


def _segments_meet(p1, p2, q1, q2) -> bool:
    """Whether the closed segments p1-p2 and q1-q2 share a point."""
    d1, d2 = _orientation(q1, q2, p1), _orientation(q1, q2, p2)
    d3, d4 = _orientation(p1, p2, q1), _orientation(p1, p2, q2)
    if ((d1 > 0 > d2) or (d1 < 0 < d2)) and ((d3 > 0 > d4) or (d3 < 0 < d4)):
        return True

    def on(p, q, r):  # r on segment p-q, given collinear
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    return ((d1 == 0 and on(q1, q2, p1)) or (d2 == 0 and on(q1, q2, p2)) or (d3 == 0 and on(p1, p2, q1))
            or (d4 == 0 and on(p1, p2, q2)))


def self_intersection(polygon: np.ndarray) -> tuple[int, int] | None:
    """(i, j): the first two non-adjacent edges (edge i runs from vertex i to i+1) that meet, or None."""
    k = len(polygon)
    for i in range(k):
        for j in range(i + 2, k):
            if i == 0 and j == k - 1:  # the closing edge touches edge 0 at vertex 0
                continue
            if _segments_meet(polygon[i], polygon[(i + 1) % k], polygon[j], polygon[(j + 1) % k]):
                return i, j
    return None
