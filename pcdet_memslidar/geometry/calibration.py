"""KITTI camera calibration: LiDAR <-> rectified camera frame, and the virtual camera of our datasets."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# LiDAR (x forward, y left, z up) -> camera (x right, y down, z forward).
_LIDAR_TO_CAMERA_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass
class Calibration:
    """KITTI calib: P2 (3, 4) projection, R0 (3, 3) rectification, V2C (3, 4) LiDAR -> camera."""

    P2: np.ndarray = field(default_factory=lambda: np.array(
        [[721.5377, 0.0, 609.5593, 0.0], [0.0, 721.5377, 172.854, 0.0], [0.0, 0.0, 1.0, 0.0]]))
    R0: np.ndarray = field(default_factory=lambda: np.eye(3))
    V2C: np.ndarray = field(default_factory=lambda: np.hstack([_LIDAR_TO_CAMERA_AXES, np.zeros((3, 1))]))

    @classmethod
    def virtual(cls) -> "Calibration":
        """The virtual camera of every generated or imported frame: at the LiDAR origin, looking along +x."""
        return cls()

    def lidar_to_rect(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) LiDAR points [m] -> (N, 3) rectified camera points [m]."""
        points = np.asarray(points, dtype=np.float64)
        return (points @ self.V2C[:, :3].T + self.V2C[:, 3]) @ self.R0.T

    def rect_to_lidar(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) rectified camera points [m] -> (N, 3) LiDAR points [m]."""
        camera = np.asarray(points, dtype=np.float64) @ np.linalg.inv(self.R0).T
        rotation, translation = self.V2C[:, :3], self.V2C[:, 3]
        return (camera - translation) @ np.linalg.inv(rotation).T
