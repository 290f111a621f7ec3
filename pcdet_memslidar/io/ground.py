"""Normalisation to the ground frame ("recalculated to the origin, tilt and height removed").

The mount comes from the user (height, tilt) or from the ground plane, the lowest large level plane: desk tops,
shelves and machines lie above the floor, and a static sensor may see only a little of the floor behind them.
RANSAC finds the largest level plane, then the largest one below it, and so on; the lowest is refined by least
squares on its inliers, and its normal and distance give height, tilt and roll (yaw is not observable from the
ground and stays 0). A plane that is not a floor (too steep, too few points on it, many points below it) is
refused with a ValueError naming the fix, --mount.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount

# A floor as the sensor sees it. A ceiling or wall mount looks down at most ~60 deg (steeper, the floor fills the view
# and little else is seen), so a plane tilted beyond 70 deg is a wall or a slope; sensors are mounted upright, so a
# plane rolled beyond 30 deg is a wall, a ramp or a strip cut through one, not the floor.
MAX_TILT_DEG = 70.0
MAX_ROLL_DEG = 30.0
# Points that must lie on the floor: the bundled office recording sees its floor only near the back wall, 0.8 % of
# the returns of its first frames, so the share is low; the other checks refuse what a low minimum lets through.
MIN_GROUND_POINTS = 100
MIN_GROUND_SHARE = 0.005
# Under a floor lie only noise, pits, drains and reflections (0.08 % of the returns of the bundled recording lie
# 0.25 m or more below its floor); more than 2 % of the points that far below the plane are a lower surface: the plane
# is a desk top or shelf seen above a floor that did not show as a plane.
BELOW_M = 0.25
MAX_BELOW_SHARE = 0.02
FIX = "pass --mount H,TILT[,ROLL] (metres, degrees) instead"


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
    if len(values) not in (2, 3) or not np.isfinite(values).all() or values[0] <= 0 or \
            any(abs(angle) > 90 for angle in values[1:]):
        raise ValueError(f"--mount {text!r}: expected HEIGHT,TILT[,ROLL] as finite numbers in metres and degrees, "
                         "height > 0, tilt and roll within +-90, e.g. 4,16")
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


def estimate_ground(points: np.ndarray, distance_threshold: float = 0.05, max_tilt_deg: float = MAX_TILT_DEG,
                    max_planes: int = 10, iterations: int = 5000, seed: int = 0, min_inliers: int = MIN_GROUND_POINTS,
                    min_share: float = MIN_GROUND_SHARE, max_skew_deg: float = 10.0) -> GroundEstimate:
    """Estimate the mount from (N, >=3) points in the sensor frame [m]: the ground is the lowest large level plane.

    A plane counts if its normal is within `max_tilt_deg` [deg] of the sensor's z axis, the sensor lies more than
    `distance_threshold` [m] above it, and at least `min_inliers` points and `min_share` (a fraction) of all points
    lie within `distance_threshold` of it. RANSAC (`iterations` random planes, seeded) finds the counting plane with
    the most inliers, then the one with the most among the points below it (parallel within `max_skew_deg` [deg]),
    up to `max_planes` planes; the lowest is refined by least squares. Raises ValueError naming --mount if no plane
    counts or the refined one is not a floor (_check_floor).
    """
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    rng = np.random.default_rng(seed)
    need = max(min_inliers, int(np.ceil(min_share * len(xyz))))
    lowest, remaining = None, xyz  # lowest: (plane (4,), its inliers (K, 3))
    for _ in range(max_planes):
        if len(remaining) < need:
            break
        plane, inliers = _level_plane(remaining, None if lowest is None else lowest[0], distance_threshold,
                                      max_tilt_deg, max_skew_deg, iterations, rng)
        if plane is None or inliers.sum() < need:
            break
        lowest = plane, remaining[inliers]
        remaining = remaining[remaining @ plane[:3] + plane[3] < -distance_threshold]
    if lowest is None:
        raise ValueError(f"no ground plane found: no plane below the sensor within {max_tilt_deg:g} deg of level "
                         f"holds {need} points; {FIX}")
    estimate = _refine(lowest[1], distance_threshold)
    _check_floor(estimate, xyz, max_tilt_deg)
    return estimate


def _check_floor(estimate: GroundEstimate, points: np.ndarray, max_tilt_deg: float) -> None:
    """ValueError naming --mount if the refined plane is beyond max_tilt_deg [deg] / MAX_ROLL_DEG of level (a wall,
    or a strip of one that RANSAC took for a level plane) or more than MAX_BELOW_SHARE of the (N, 3) points [m] lie
    BELOW_M or more below it (a desk top above the floor)."""
    mount = estimate.mount
    if abs(mount.tilt_deg) > max_tilt_deg or abs(mount.roll_deg) > MAX_ROLL_DEG:
        raise ValueError(f"the plane found is not a floor: tilt {mount.tilt_deg:.0f} deg, roll {mount.roll_deg:.0f} "
                         f"deg, beyond the {max_tilt_deg:g} / {MAX_ROLL_DEG:g} deg of a floor (a wall?); {FIX}")
    below = float(np.mean(points @ np.array(estimate.plane[:3]) + estimate.plane[3] < -BELOW_M))
    if below > MAX_BELOW_SHARE:
        raise ValueError(f"the plane found {mount.height:.2f} m below the sensor is not the floor: {100 * below:.1f} % "
                         f"of the points lie more than {BELOW_M:g} m below it (a desk top or shelf?); {FIX}")


def _level_plane(points: np.ndarray, above: np.ndarray | None, distance_threshold: float, max_tilt_deg: float,
                 max_skew_deg: float, iterations: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """RANSAC: of `iterations` planes through 3 random points (N, 3) [m], the one with the most inliers (N,) bool
    that is level (normal within max_tilt_deg of z), lies more than distance_threshold below the sensor and, if
    `above` (4,) is given, lies lower than it within max_skew_deg of parallel. Planes (4,) are a, b, c, d with
    unit normal towards the sensor (d > 0 [m]); (None, None) if no random plane qualifies."""
    corners = points[rng.integers(0, len(points), (iterations, 3))]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    planes = np.column_stack([normals, -(normals * corners[:, 0]).sum(axis=1)])[length > 0] / length[length > 0, None]
    planes *= np.where(planes[:, 3:] < 0, -1.0, 1.0)  # normal towards the sensor origin
    level = (planes[:, 2] >= np.cos(np.radians(max_tilt_deg))) & (planes[:, 3] > distance_threshold)
    if above is not None:
        level &= (planes[:, :3] @ above[:3] >= np.cos(np.radians(max_skew_deg))) & (planes[:, 3] > above[3])
    planes = planes[level]
    if not len(planes):
        return None, None
    homogeneous = np.column_stack([points, np.ones(len(points))])
    counts = np.concatenate([(np.abs(homogeneous @ chunk.T) <= distance_threshold).sum(axis=0)
                             for chunk in np.array_split(planes, -(-len(planes) // 32))])
    best = planes[counts.argmax()]
    return best, np.abs(homogeneous @ best) <= distance_threshold


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
