"""Normalisation to the ground frame ("recalculated to the origin, tilt and height removed").

The mount comes from the user (height, tilt) or from the ground plane: RANSAC (Open3D's segment_plane) finds
planes, the first one that faces the sensor from below is refined by least squares on its inliers, and its normal
and distance give height, tilt and roll (yaw is not observable from the ground and stays 0).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.utils.open3d import import_open3d


@dataclass(frozen=True)
class GroundEstimate:
    """A mount estimated from the ground plane, with the evidence for it."""

    mount: Mount
    plane: tuple[float, float, float, float]  # a, b, c, d of a x + b y + c z + d = 0, sensor frame, unit normal up
    inliers: int  # points within the RANSAC distance of the plane
    rms: float  # [m] RMS distance of the inliers to the refined plane

    def as_dict(self) -> dict:
        """JSON-ready summary for reports."""
        return {"height": self.mount.height, "tilt_deg": self.mount.tilt_deg, "roll_deg": self.mount.roll_deg,
                "plane": list(self.plane), "inliers": self.inliers, "rms_m": self.rms}


def parse_mount(text: str) -> Mount:
    """'H,TILT' or 'H,TILT,ROLL' (metres, degrees) -> Mount; ValueError with the expected form otherwise."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not np.isfinite(values).all() or values[0] <= 0:
        raise ValueError(f"--mount {text!r}: expected HEIGHT,TILT[,ROLL] as finite numbers in metres and degrees, "
                         "height > 0, e.g. 4,16")
    return Mount(*values)


def mount_from_plane(normal: np.ndarray, distance: float) -> Mount:
    """Mount whose ground plane in the sensor frame is normal . p + distance = 0 (unit normal pointing up).

    With R = Ry(tilt) @ Rx(roll) (sensor -> ground), the ground's up axis seen from the sensor is R^T e_z =
    (-sin tilt, cos tilt sin roll, cos tilt cos roll); the sensor origin lies `distance` above the plane.
    """
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    tilt = np.degrees(np.arcsin(np.clip(-n[0], -1.0, 1.0)))
    roll = np.degrees(np.arctan2(n[1], n[2]))
    return Mount(height=float(distance), tilt_deg=float(tilt), roll_deg=float(roll))


def estimate_ground(points: np.ndarray, distance_threshold: float = 0.05, max_tilt_deg: float = 70.0,
                    max_planes: int = 4, iterations: int = 2000, seed: int = 0) -> GroundEstimate:
    """Estimate the mount from (N, >=3) points in the sensor frame [m].

    RANSAC planes are tried from the largest down; walls and ceilings are skipped because the ground is the plane
    below the sensor whose normal is within `max_tilt_deg` of the sensor's z axis. Raises ValueError if none is.
    """
    o3d = import_open3d()
    o3d.utility.random.seed(seed)
    remaining = np.asarray(points, dtype=np.float64)[:, :3]
    for _ in range(max_planes):
        if len(remaining) < 100:
            break
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(remaining))
        (a, b, c, d), inliers = cloud.segment_plane(distance_threshold, 3, iterations)
        plane = np.array([a, b, c, d]) / np.linalg.norm([a, b, c])
        plane = plane if plane[3] > 0 else -plane  # orient the normal towards the sensor origin
        if plane[2] >= np.cos(np.radians(max_tilt_deg)) and len(inliers) >= 100:
            return _refine(remaining[inliers], distance_threshold)
        remaining = np.delete(remaining, inliers, axis=0)
    raise ValueError(f"no ground plane found: none of the {max_planes} largest planes lies below the sensor within "
                     f"{max_tilt_deg} deg of level; pass --mount HEIGHT,TILT instead")


def _refine(inliers: np.ndarray, distance_threshold: float) -> GroundEstimate:
    """Least-squares plane through the RANSAC inliers (two passes, the second without points beyond 2 sigma)."""
    keep = np.ones(len(inliers), dtype=bool)
    for _ in range(2):
        centroid = inliers[keep].mean(axis=0)
        normal = np.linalg.svd(inliers[keep] - centroid, full_matrices=False)[2][2]
        distance = -normal @ centroid
        normal, distance = (normal, distance) if distance > 0 else (-normal, -distance)
        residual = inliers @ normal + distance
        keep = np.abs(residual) <= min(distance_threshold, 2.0 * residual[keep].std())
    rms = float(np.sqrt(np.mean(residual[keep] ** 2)))
    return GroundEstimate(mount_from_plane(normal, distance), (*map(float, normal), float(distance)),
                          int(len(inliers)), rms)


def normalise_points(points: np.ndarray, mount: Mount) -> np.ndarray:
    """(N, 4) x, y, z, intensity in the sensor frame -> (N, 4) float32 in the ground frame."""
    out = np.array(points, dtype=np.float32, copy=True)
    out[:, :3] = mount.sensor_to_ground(points[:, :3])
    return out


def normalise_boxes(centers: np.ndarray, rotations: np.ndarray, sizes: np.ndarray, mount: Mount
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Cuboids in the sensor frame -> upright boxes in the ground frame.

    centers (M, 3) [m], rotations (M, 3, 3) box -> sensor, sizes (M, 3) along the box's own x, y, z [m].
    Returns (M, 7) boxes [x, y, z_center, dx, dy, dz, heading] and (M,) levelling [deg]: how far each box's own z
    axis was from vertical in the ground frame (the heading is the box x axis projected onto the ground).
    """
    rotations = mount.rotation @ np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    boxes = np.zeros((len(rotations), 7))
    boxes[:, :3] = mount.sensor_to_ground(np.asarray(centers).reshape(-1, 3))
    boxes[:, 3:6] = np.asarray(sizes).reshape(-1, 3)
    boxes[:, 6] = np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])
    levelling = np.degrees(np.arccos(np.clip(rotations[:, 2, 2], -1.0, 1.0)))
    return boxes, levelling
