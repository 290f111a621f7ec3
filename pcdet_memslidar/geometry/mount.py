"""Sensor mount: the rigid transform between the tilted sensor frame and the normalised ground frame.

Both frames use KITTI LiDAR axes (x forward, y left, z up). The ground frame has its origin on the ground straight
below the sensor; tilt pitches the sensor's x axis down towards the ground.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mount:
    """Mount height [m] above the ground and tilt / roll / yaw [deg]; tilt > 0 looks down."""

    height: float
    tilt_deg: float
    roll_deg: float = 0.0
    yaw_deg: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation sensor -> ground: R = Rz(yaw) @ Ry(tilt) @ Rx(roll)."""
        tilt, roll, yaw = np.deg2rad([self.tilt_deg, self.roll_deg, self.yaw_deg])
        c, s = np.cos(tilt), np.sin(tilt)
        pitch = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        c, s = np.cos(roll), np.sin(roll)
        bank = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        c, s = np.cos(yaw), np.sin(yaw)
        heading = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return heading @ pitch @ bank

    @property
    def origin(self) -> np.ndarray:
        """(3,) sensor position in the ground frame [m]."""
        return np.array([0.0, 0.0, self.height])

    def sensor_to_ground(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points in the sensor frame -> (N, 3) in the ground frame."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.origin

    def ground_to_sensor(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points in the ground frame -> (N, 3) in the sensor frame."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.rotation

    def directions_to_ground(self, directions: np.ndarray) -> np.ndarray:
        """(N, 3) direction vectors in the sensor frame -> (N, 3) in the ground frame (rotation only)."""
        return np.asarray(directions, dtype=np.float64) @ self.rotation.T
