"""A static site's background: the range at which each pulse of the scan pattern ends when nobody is there.

Learned from frames of the empty site (`BackgroundModel.learn`):
1. every return is matched to the nearest pulse direction of the site's scan pattern (sensor frame), as
   compositing matches point-cloud frames;
2. a pulse's background range is the nearest return over all empty frames of that pulse and of the pulses within
   `radius` of it, so beam jitter, mixed pixels at depth edges and dropout never make the background look farther
   than it is; a pulse none of whose neighbours ever returned has no background (inf: open space, glass, beyond
   range), and every return along it is foreground.

A return is foreground when it comes back nearer than its pulse's background by more than the margin
    margin(b) = margin_m + margin_per_m * b        [m], b the background range [m]
(range noise and the pointing jitter that moves a grazing surface's return grow with range). The per-point feature
`background_depth` [m] says how far in front of its background a return is: b - r for a foreground return, clipped
to depth_clip_m (also where there is no background), 0 for a background return. Points in the ground frame are
taken into the sensor frame by the model's mount; a mount turned about the vertical since the empty recording is
found again by `estimate_yaw` (docs/sites.md, "The background").
"""
from __future__ import annotations

import dataclasses
import functools
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.utils.atomic import write_bytes

MARGIN_M = 0.2  # a return this much nearer than its background (plus MARGIN_PER_M per m) is foreground
MARGIN_PER_M = 0.01
DEPTH_CLIP_M = 2.0  # the feature saturates here: a person stands at most about this far in front of what is behind
RADIUS_SPACINGS = 1.5  # neighbours of a pulse: pulses within this many of the pattern's angle spacings
YAW_SEARCH_DEG = (12.0, 0.5, 0.05)  # estimate_yaw: +- range, coarse step, fine step [deg]
YAW_SAMPLE = 4000  # estimate_yaw scores at most this many returns of a frame
FORMAT_VERSION = 2


@dataclass(frozen=True)
class BackgroundModel:
    """directions (P, 3) unit pulse directions (sensor frame); range (P,) [m] background range (inf: none);
    own_range (P,) [m] each pulse's own nearest return (step 2 without the neighbours: what a turn is refined on);
    mount: sensor -> ground frame of the points it is asked about; frames: empty frames it was learned from; radius_rad:
    the neighbourhood of step 2; margin_m, margin_per_m, depth_clip_m: see the module docstring."""

    directions: np.ndarray
    range: np.ndarray
    own_range: np.ndarray
    mount: Mount
    frames: int
    radius_rad: float
    margin_m: float = MARGIN_M
    margin_per_m: float = MARGIN_PER_M
    depth_clip_m: float = DEPTH_CLIP_M

    @classmethod
    def learn(cls, directions: np.ndarray, frames: list[np.ndarray], mount: Mount, spacing_rad: float,
              **settings) -> BackgroundModel:
        """The background of pulse `directions` (P, 3) from `frames`, each (N, 3+) returns [m] in the sensor frame;
        spacing_rad: the pattern's angle spacing (the neighbourhood is RADIUS_SPACINGS of it)."""
        directions = np.asarray(directions, dtype=np.float64)
        tree, nearest = cKDTree(directions), np.full(len(directions), np.inf)
        for points in frames:
            ranges = np.linalg.norm(np.asarray(points, dtype=np.float64)[:, :3], axis=1)
            valid = np.isfinite(ranges) & (ranges > 0)
            _, pulse = tree.query(points[valid, :3] / ranges[valid, None])
            np.minimum.at(nearest, pulse, ranges[valid])
        radius = RADIUS_SPACINGS * spacing_rad
        neighbours = tree.query_ball_point(directions, 2 * np.sin(radius / 2))  # chord of the angle
        background = np.array([nearest[group].min() for group in neighbours])
        return cls(directions, background, nearest, mount, len(frames), radius, **settings)

    @functools.cached_property
    def _tree(self) -> cKDTree:
        return cKDTree(self.directions)

    def lookup(self, points: np.ndarray, yaw_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(range (N,), background range (N,)) [m] of (N, 3+) points in the ground frame, turned by yaw_deg about
        the vertical through the sensor first (estimate_yaw)."""
        ranges, pulse = self._match(points, yaw_deg)
        return ranges, self.range[pulse]

    def _match(self, points: np.ndarray, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """(range (N,) [m], nearest pulse (N,)) of (N, 3+) ground-frame points turned by yaw_deg."""
        xyz = turn_about_vertical(np.asarray(points, dtype=np.float64)[:, :3], yaw_deg)
        local = self.mount.ground_to_sensor(xyz)
        ranges = np.linalg.norm(local, axis=1)
        if not len(local):
            return ranges, np.zeros(0, dtype=np.int64)
        _, pulse = self._tree.query(local / np.maximum(ranges, 1e-9)[:, None])
        return ranges, pulse

    def residual(self, points: np.ndarray, yaw_deg: float = 0.0) -> float:
        """Mean |range - own range of its pulse| [m], capped at 1 m, of the returns (N, 3+) whose pulse returned in
        the empty frames: sharp in a turn, where the foreground share is flat within the neighbourhood."""
        ranges, pulse = self._match(points, yaw_deg)
        own = self.own_range[pulse]
        known = np.isfinite(own)
        return float(np.minimum(np.abs(ranges[known] - own[known]), 1.0).mean()) if known.any() else np.inf

    def margin(self, background: np.ndarray) -> np.ndarray:
        """(N,) margin [m] at background ranges (N,) [m]."""
        return self.margin_m + self.margin_per_m * background

    def foreground(self, points: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
        """(N,) bool: returns nearer than their background by more than the margin (all, where there is none)."""
        ranges, background = self.lookup(points, yaw_deg)
        return _in_front(ranges, background, self.margin(background))

    def depth(self, points: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
        """(N,) float32 background_depth [m] of (N, 3+) ground-frame points (module docstring)."""
        ranges, background = self.lookup(points, yaw_deg)
        ahead = np.minimum(background - ranges, self.depth_clip_m)
        return np.where(_in_front(ranges, background, self.margin(background)), ahead, 0.0).astype(np.float32)

    def foreground_share(self, points: np.ndarray, yaw_deg: float = 0.0) -> float:
        """Share of the returns (N, 3+) that are foreground (0 for no return): a person covers a few per cent, a
        moved sensor or a changed site most."""
        return float(self.foreground(points, yaw_deg).mean()) if len(points) else 0.0

    def estimate_yaw(self, points: np.ndarray, seed: int = 0) -> tuple[float, float]:
        """(yaw [deg], foreground share there): the turn about the vertical that best lays a frame's returns (N, 3+,
        ground frame) onto the background, searched within +-YAW_SEARCH_DEG[0]: coarse on the foreground share, then
        fine on the residual (a floor seen from above looks the same turned; what stands on it does not); no labels."""
        span, coarse, fine = YAW_SEARCH_DEG
        if len(points) > YAW_SAMPLE:
            points = points[np.random.default_rng(seed).choice(len(points), YAW_SAMPLE, replace=False)]
        best = 0.0
        for low, high, step, cost in ((-span, span, coarse, self.foreground_share),
                                      (-coarse, coarse, fine, self.residual)):
            offsets = step * np.arange(round(low / step), round(high / step) + 1)  # 0 exactly among them
            candidates = best + offsets[np.argsort(np.abs(offsets), kind="stable")]  # ties: the smallest turn
            best = float(candidates[int(np.argmin([cost(points, yaw) for yaw in candidates]))])
        return best, self.foreground_share(points, best)

    def save(self, path: str | Path) -> None:
        """Write the model as .npz (atomic)."""
        buffer = io.BytesIO()
        np.savez(buffer, version=FORMAT_VERSION, directions=self.directions, range=self.range, own_range=self.own_range,
                 mount=np.array(dataclasses.astuple(self.mount)), frames=self.frames,
                 settings=np.array([self.radius_rad, self.margin_m, self.margin_per_m, self.depth_clip_m]))
        write_bytes(path, buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> BackgroundModel:
        """A model written by save(); DataFormatError naming the file and the fix otherwise."""
        return _load(str(Path(path).resolve()))


@functools.lru_cache(maxsize=8)
def _load(path: str) -> BackgroundModel:
    fix = "give the background.npz that `memslidar site train` wrote (DATA_CONFIG.BACKGROUND_MODEL)"
    try:
        with np.load(path) as data:
            if int(data["version"]) != FORMAT_VERSION:
                raise DataFormatError(path, f"background model version {int(data['version'])}, this package reads "
                                            f"{FORMAT_VERSION}: run `memslidar site train` again")
            radius, margin, per_m, clip = data["settings"].tolist()
            return BackgroundModel(data["directions"], data["range"], data["own_range"], Mount(*data["mount"].tolist()),
                                   int(data["frames"]), radius, margin, per_m, clip)
    except FileNotFoundError:
        raise DataFormatError(path, f"background model not found: {fix}") from None
    except (OSError, ValueError, KeyError) as error:
        if isinstance(error, DataFormatError):
            raise
        raise DataFormatError(path, f"not a background model ({error}): {fix}") from None


def _in_front(ranges: np.ndarray, background: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(N,) bool: ranges (N,) nearer than their background (N,) by more than margin (N,) [m], or no background."""
    return ~np.isfinite(background) | (background - ranges > margin)


def turn_about_vertical(points: np.ndarray, yaw_deg: float) -> np.ndarray:
    """(N, 3+) ground-frame points with x, y turned by yaw_deg [deg] (counter-clockwise) about the vertical through
    the sensor (the ground frame's z axis): what a sensor turned by -yaw_deg since its mount was measured needs."""
    if not yaw_deg:
        return points
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    turned = np.array(points, copy=True)
    turned[:, 0], turned[:, 1] = c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]
    return turned
