"""Safety zones: named polygons on the ground with a level, and the enter / leave events of tracked people.

A zone file (YAML) in the ground frame of the detections (x forward, y left, metres):

    zones:
      - name: press
        level: protective          # or warning
        polygon: [[3, -1], [6, -1], [6, 1.5], [3, 1.5]]
        z_range: [0.0, 2.5]        # optional: only boxes that reach into these heights count

A person is in a zone when the BEV centre of its box lies inside the polygon or on its border, and (with z_range)
its box overlaps those heights. Events come from confirmed tracks: `enter` when a track is first seen inside,
`leave` when it is seen outside again or its track is lost (reason "lost"). A confirmed track that was missed in a
frame keeps its zones, so one missed detection raises no event.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.polygon import points_in_polygon, self_intersection

LEVELS = ("warning", "protective")
ZONE_KEYS = ("name", "level", "polygon", "z_range")
MIN_ZONE_AREA_M2 = 1e-4  # a polygon enclosing less than this is a line or a point, no zone


@dataclass(frozen=True)
class Zone:
    name: str
    level: str
    polygon: np.ndarray  # (K, 2) float64 x, y [m], K >= 3, simple (no self-intersection)
    z_range: tuple[float, float] | None = None

    def contains(self, boxes: np.ndarray) -> np.ndarray:
        """(N,) bool: which of boxes (N, 7) [x, y, z_center, dx, dy, dz, heading] are in this zone."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 7)
        inside = points_in_polygon(boxes[:, :2], self.polygon)
        if self.z_range is not None:
            bottom, top = boxes[:, 2] - boxes[:, 5] / 2, boxes[:, 2] + boxes[:, 5] / 2
            inside &= (top >= self.z_range[0]) & (bottom <= self.z_range[1])
        return inside


def read_zones(path: str | Path) -> list[Zone]:
    """The zones of a zone file (module docstring); DataFormatError naming the file, the zone and the fix for
    anything malformed."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "zone file not found: give a YAML file with a 'zones' list (docs/detect.md, Zones)")
    try:
        document = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise DataFormatError(path, f"is not valid YAML: {error}") from None
    if not isinstance(document, dict) or not isinstance(document.get("zones"), list) or not document["zones"]:
        raise DataFormatError(path, "needs a top-level 'zones:' list with at least one zone (name, level, polygon)")
    unknown = [key for key in document if key != "zones"]
    if unknown:
        raise DataFormatError(path, f"unknown top-level key {unknown[0]!r}: a zone file holds only 'zones:'; move it "
                                    f"into a zone or remove it")
    zones = [_zone(path, index, entry) for index, entry in enumerate(document["zones"])]
    names = [zone.name for zone in zones]
    duplicate = next((name for name in names if names.count(name) > 1), None)
    if duplicate is not None:
        raise DataFormatError(path, f"zone name {duplicate!r} is used twice: give every zone its own name")
    return zones


def _zone(path: Path, index: int, entry) -> Zone:
    where = f"zone {index + 1}"
    if not isinstance(entry, dict):
        raise DataFormatError(path, f"{where} is not a mapping: write name, level and polygon keys")
    where = f"zone {index + 1} ({entry.get('name', 'no name')!r})"
    for key in entry:
        if key not in ZONE_KEYS:
            close = difflib.get_close_matches(str(key), ZONE_KEYS, n=1)
            raise DataFormatError(path, f"{where}: unknown key {key!r}"
                                        f"{f'; did you mean {close[0]!r}?' if close else ''}")
    if not isinstance(entry.get("name"), str) or not entry["name"]:
        raise DataFormatError(path, f"{where}: give it a 'name' (text)")
    if entry.get("level") not in LEVELS:
        raise DataFormatError(path, f"{where}: level is {entry.get('level')!r}; use one of {', '.join(LEVELS)}")
    try:
        polygon = np.asarray(entry.get("polygon"), dtype=np.float64)
    except (TypeError, ValueError):
        polygon = np.zeros((0,))
    if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3 or not np.isfinite(polygon).all():
        raise DataFormatError(path, f"{where}: polygon must be a list of at least 3 finite [x, y] points in metres")
    crossing = self_intersection(polygon)
    if crossing is not None:
        i, j = crossing
        k = len(polygon)
        raise DataFormatError(path, f"{where}: the polygon intersects itself (edge {i + 1}-{(i + 1) % k + 1} meets "
                                    f"edge {j + 1}-{(j + 1) % k + 1}, counting vertices from 1); list its corners "
                                    "in order around the zone")
    x, y = polygon.T
    if abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2 < MIN_ZONE_AREA_M2:
        raise DataFormatError(path, f"{where}: the polygon encloses no area (its corners lie on one line or repeat); "
                                    "give at least 3 corners around the zone")
    z_range = entry.get("z_range")
    if z_range is not None:
        z = np.asarray(z_range, dtype=np.float64) if isinstance(z_range, list) else np.zeros(0)
        if z.shape != (2,) or not np.isfinite(z).all() or z[0] >= z[1]:
            raise DataFormatError(path, f"{where}: z_range must be [low, high] in metres with low < high")
        z_range = (float(z[0]), float(z[1]))
    return Zone(name=entry["name"], level=entry["level"], polygon=polygon, z_range=z_range)


class ZoneMonitor:
    """Which zones each confirmed track is in, and the events when that changes."""

    def __init__(self, zones: list[Zone]):
        self.zones = zones
        self.inside: dict[int, list[str]] = {}  # track id -> the names of the zones it is in, in zone-file order

    def update(self, time_s: float, track_ids: list[int | None], boxes: np.ndarray, lost_ids: list[int]
               ) -> tuple[list[list[str]], list[dict]]:
        """One frame: track_ids (M,) of the detections boxes (M, 7) (None: tentative, in no zone), lost_ids the
        tracks lost in this frame. Returns each detection's zone names and the frame's events."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 7)
        member = np.stack([zone.contains(boxes) for zone in self.zones], axis=1) if len(boxes) and self.zones \
            else np.zeros((len(boxes), len(self.zones)), bool)
        levels = {zone.name: zone.level for zone in self.zones}
        events, per_detection = [], []
        for row, track_id in enumerate(track_ids):
            now = [zone.name for zone, yes in zip(self.zones, member[row]) if yes] if track_id is not None else []
            per_detection.append(now)
            if track_id is None:
                continue
            before = self.inside.get(track_id, [])
            events += [self._event("leave", name, levels[name], track_id, time_s) for name in before if name not in now]
            events += [self._event("enter", name, levels[name], track_id, time_s) for name in now if name not in before]
            self.inside[track_id] = now
        for track_id in lost_ids:
            events += [self._event("leave", name, levels[name], track_id, time_s, reason="lost")
                       for name in self.inside.pop(track_id, [])]
        return per_detection, events

    @staticmethod
    def _event(kind: str, zone: str, level: str, track_id: int, time_s: float, **extra) -> dict:
        return {"event": kind, "zone": zone, "level": level, "track_id": track_id, "time_s": time_s, **extra}
