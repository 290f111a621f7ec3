"""Whole-scene augmentations on numpy arrays: flip, rotation and scaling of points and their boxes together.

points: (N, 3+C) [x, y, z, features...] in the LiDAR frame [m]; gt_boxes: (M, 7+) [x, y, z, dx, dy, dz, heading, ...].
Each function draws from the given numpy Generator and returns new arrays.
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.geometry.boxes import rotate_points_along_z


def random_flip_along_x(gt_boxes: np.ndarray, points: np.ndarray, rng: np.random.Generator,
                        probability: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Mirror the scene across the x axis (y -> -y, heading -> -heading) with `probability`."""
    gt_boxes, points = gt_boxes.copy(), points.copy()
    if rng.random() < probability:
        gt_boxes[:, 1] = -gt_boxes[:, 1]
        gt_boxes[:, 6] = -gt_boxes[:, 6]
        points[:, 1] = -points[:, 1]
    return gt_boxes, points


def global_rotation(gt_boxes: np.ndarray, points: np.ndarray, rot_range, rng: np.random.Generator
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Rotate the scene about +z through the origin by an angle drawn uniformly from rot_range [rad]."""
    angle = rng.uniform(rot_range[0], rot_range[1])
    gt_boxes = gt_boxes.copy()
    gt_boxes[:, :3] = rotate_points_along_z(gt_boxes[:, :3], angle)
    gt_boxes[:, 6] += angle
    points = rotate_points_along_z(points, angle).astype(points.dtype)
    return gt_boxes, points


def global_scaling(gt_boxes: np.ndarray, points: np.ndarray, scale_range, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Scale positions and box sizes about the origin by a factor drawn uniformly from scale_range."""
    scale = rng.uniform(scale_range[0], scale_range[1])
    gt_boxes, points = gt_boxes.copy(), points.copy()
    gt_boxes[:, :6] *= scale
    points[:, :3] *= scale
    return gt_boxes, points
