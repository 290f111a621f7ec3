"""3D boxes in the LiDAR frame: corners, points in boxes, heading normalisation and folding, LiDAR <-> KITTI
camera boxes.

A LiDAR box is OpenPCDet's (7,) [x, y, z_center, dx, dy, dz, heading]: centre [m], size along its own x / y / z
[m], heading [rad] counter-clockwise from +x about +z. A KITTI camera box is (7,) [x, y, z, l, h, w, rotation_y]:
bottom-centre in the rectified camera frame [m], length (= dx), height (= dz), width (= dy) and rotation about the
camera's y axis (pointing down).
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.geometry.calibration import Calibration

# Unit-box corners, OpenPCDet order: bottom face (z = -1/2) 0-3, then the top face 4-7 above them.
_CORNER_SIGNS = np.array([
    [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1],
    [1, 1, 1], [1, -1, 1], [-1, -1, 1], [-1, 1, 1],
], dtype=np.float64) / 2.0


def check_boxes(boxes, name: str = "boxes") -> np.ndarray:
    """(N, 7) float64 copy of `boxes`; ValueError naming `name` for a wrong shape, NaN / inf or negative sizes."""
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.ndim != 2 or boxes.shape[1] < 7:
        raise ValueError(f"{name}: expected an (N, 7) array [x, y, z, dx, dy, dz, heading], got shape {boxes.shape}")
    boxes = boxes[:, :7]
    if not np.isfinite(boxes).all():
        raise ValueError(f"{name}: NaN or inf in box rows {np.flatnonzero(~np.isfinite(boxes).all(axis=1)).tolist()}")
    if (boxes[:, 3:6] < 0).any():
        rows = np.flatnonzero((boxes[:, 3:6] < 0).any(axis=1)).tolist()
        raise ValueError(f"{name}: negative size in box rows {rows}")
    return boxes


def limit_period(val, offset: float = 0.5, period: float = 2 * np.pi):
    """Wrap angles into [-offset * period, (1 - offset) * period); numpy arrays, torch tensors or floats."""
    return val - ((val / period + offset) // 1) * period


def normalize_heading(heading):
    """Heading (or any angle) [rad] wrapped into [-pi, pi): the package's one wrap (labels, KITTI alpha, boxes)."""
    return limit_period(heading, offset=0.5, period=2 * np.pi)


FOLDS = ("quarter", "half")  # fold_box_headings: headings into [-45, 45) deg, or long side first in [-90, 90) deg


def fold_box_headings(boxes, fold: str = "quarter") -> np.ndarray:
    """(M, 7+) LiDAR boxes -> a copy, each the same rectangle in a canonical form (extra columns kept).

    A box is a rectangle: (dx, dy, heading) and (dy, dx, heading + pi/2) cover the same points, as do headings a
    half turn apart. 'quarter': heading folded into [-pi/4, pi/4), dx and dy swapped for each odd quarter turn
    removed (one anchor rotation covers every box, but the form jumps at +-45 deg: heading by a quarter turn, dx
    and dy swapped). 'half': the long side first (dx >= dy) and its direction in [-pi/2, pi/2); the only jump is
    by a half turn at +-90 deg, which the anchor head's sine loss does not see. Computed in float64 (a float32
    heading of -pi/4 lands on +pi/4 after rounding: the same box).
    """
    if fold not in FOLDS:
        raise ValueError(f"fold {fold!r}: use one of {', '.join(FOLDS)}")
    boxes = np.array(boxes, copy=True)
    heading = boxes[:, 6].astype(np.float64)
    if fold == "half":
        swap = boxes[:, 3] < boxes[:, 4]
        heading = heading + np.where(swap, np.pi / 2, 0.0)
        boxes[swap, 3:5] = boxes[swap][:, [4, 3]]
        boxes[:, 6] = np.mod(heading + np.pi / 2, np.pi) - np.pi / 2
        return boxes
    turns = np.floor((heading + np.pi / 4) / (np.pi / 2))
    boxes[:, 6] = heading - turns * (np.pi / 2)
    odd = np.mod(turns, 2) == 1
    boxes[odd, 3:5] = boxes[odd][:, [4, 3]]
    return boxes


def rotate_points_along_z(points: np.ndarray, angle) -> np.ndarray:
    """Rotate (N, 3+) points [m] (extra columns kept) counter-clockwise about +z by `angle` [rad]: scalar or (N,)."""
    points = np.asarray(points, dtype=np.float64)
    cos, sin = np.cos(angle), np.sin(angle)
    rotated = points.copy()
    rotated[..., 0] = cos * points[..., 0] - sin * points[..., 1]
    rotated[..., 1] = sin * points[..., 0] + cos * points[..., 1]
    return rotated


def boxes_to_corners_3d(boxes) -> np.ndarray:
    """(N, 7) LiDAR boxes -> (N, 8, 3) corners [m]: 0-3 the bottom face, 4-7 the top face above 0-3."""
    boxes = check_boxes(boxes)
    local = _CORNER_SIGNS[None] * boxes[:, None, 3:6]
    cos, sin = np.cos(boxes[:, 6:7]), np.sin(boxes[:, 6:7])
    corners = np.empty_like(local)
    corners[..., 0] = cos * local[..., 0] - sin * local[..., 1] + boxes[:, 0:1]
    corners[..., 1] = sin * local[..., 0] + cos * local[..., 1] + boxes[:, 1:2]
    corners[..., 2] = local[..., 2] + boxes[:, 2:3]
    return corners


def points_in_boxes_mask(points, boxes) -> np.ndarray:
    """(N, 3+) points, (M, 7) boxes -> (N, M) bool: point n lies inside box m (boundary included).

    Each point is moved into every box's own frame (translate, rotate by -heading) and compared with half the size.
    """
    points = np.asarray(points, dtype=np.float64)[:, :3]
    boxes = check_boxes(boxes)
    offset = points[:, None, :] - boxes[None, :, :3]
    cos, sin = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    local_x = cos * offset[..., 0] + sin * offset[..., 1]
    local_y = -sin * offset[..., 0] + cos * offset[..., 1]
    half = boxes[:, 3:6] / 2.0
    return ((np.abs(local_x) <= half[:, 0]) & (np.abs(local_y) <= half[:, 1])
            & (np.abs(offset[..., 2]) <= half[:, 2]))


def enlarge_box3d(boxes, extra_width=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(N, 7) boxes grown by `extra_width` (dx, dy, dz) [m] in total along each axis, centre kept."""
    boxes = check_boxes(boxes).copy()
    boxes[:, 3:6] += np.asarray(extra_width, dtype=np.float64)
    return boxes


def boxes_lidar_to_camera(boxes, calib: Calibration) -> np.ndarray:
    """(N, 7) LiDAR boxes -> (N, 7) KITTI camera boxes [x, y, z, l, h, w, rotation_y], rotation_y in [-pi, pi)."""
    boxes = check_boxes(boxes)
    bottom = boxes[:, :3].copy()
    bottom[:, 2] -= boxes[:, 5] / 2.0
    location = calib.lidar_to_rect(bottom)
    rotation_y = normalize_heading(-boxes[:, 6] - np.pi / 2.0)
    return np.column_stack([location, boxes[:, 3], boxes[:, 5], boxes[:, 4], rotation_y])


def boxes_camera_to_lidar(boxes_camera, calib: Calibration) -> np.ndarray:
    """(N, 7) KITTI camera boxes [x, y, z, l, h, w, rotation_y] -> (N, 7) LiDAR boxes, heading in [-pi, pi)."""
    boxes_camera = np.asarray(boxes_camera, dtype=np.float64).reshape(-1, 7)
    centre = calib.rect_to_lidar(boxes_camera[:, :3])
    centre[:, 2] += boxes_camera[:, 4] / 2.0
    heading = normalize_heading(-boxes_camera[:, 6] - np.pi / 2.0)
    length, height, width = boxes_camera[:, 3], boxes_camera[:, 4], boxes_camera[:, 5]
    return np.column_stack([centre, length, width, height, heading])
