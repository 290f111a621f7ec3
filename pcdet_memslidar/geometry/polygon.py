"""Points in a polygon on the ground plane (walkable areas of site files)."""
from __future__ import annotations

import numpy as np


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(...,) bool: whether each of the points (..., 2) [m] lies inside `polygon` (V, 2), corners in order (even-odd
    rule: a ray towards +x crosses the boundary an odd number of times; points on an edge may fall either way)."""
    points = np.asarray(points, dtype=np.float64)
    x, y = points[..., 0, None], points[..., 1, None]
    start = np.asarray(polygon, dtype=np.float64)
    end = np.roll(start, -1, axis=0)
    straddles = (start[:, 1] > y) != (end[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing_x = start[:, 0] + (y - start[:, 1]) * (end[:, 0] - start[:, 0]) / (end[:, 1] - start[:, 1])
    return (np.count_nonzero(straddles & (x < crossing_x), axis=-1) % 2).astype(bool)
