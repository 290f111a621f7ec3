"""Does the sensor still see the site it was trained for? The share of each frame's returns that are foreground
against the site's background model (geometry.background) says so: a person covers a few per cent of them, a
sensor that was bumped, turned or re-mounted, or a site that changed, most of them.

Per frame, in time order:
1. the frame's returns (ground frame), turned by the yaw found so far, are scored: their foreground share;
2. the first frame of a run (a turn of a degree may leave less than MISMATCH_SHARE off the background, and a
   turned sensor must not wait), and MISMATCH_FRAMES frames in a row above MISMATCH_SHARE, look for a turn about the
   vertical that lays the frame back onto the background (BackgroundModel.estimate_yaw, no labels), again every
   MISMATCH_FRAMES frames while the stretch lasts;
3. if that turn brings the share below MISMATCH_SHARE and lays at least MIN_EXPLAINED of the returns back onto the
   background (a person's foreground no turn explains; a turn of a tenth of a degree moves fewer), every
   frame from this one on is turned by it (the detections come out in the site's frame again) and a
   `sensor_turned` event says so; otherwise, after MISMATCH_FRAMES frames, a `background_mismatch` event names the
   frames and detect warns once (the sensor moved, the site changed, or something stood close to the sensor all
   that time).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from pcdet_memslidar.geometry.background import BackgroundModel, turn_about_vertical

MISMATCH_SHARE = 0.05  # foreground share of a frame's returns above which it does not match the background
MIN_EXPLAINED = 0.005  # a turn is taken where it lays at least this share of the returns back onto the background
# frames in a row above it before a turn is searched or a mismatch reported: people close to a low sensor cover more
# than MISMATCH_SHARE of its returns (a person 2 m in front of the bundled room's sensor: about 10 %), but they move
MISMATCH_FRAMES = 10


@dataclass
class BackgroundWatch:
    """Steps 1-3 of the module docstring for one run; events: the run's events (JSON-ready dicts)."""

    model: BackgroundModel
    logger: logging.Logger
    yaw_deg: float = 0.0
    events: list[dict] = field(default_factory=list)
    _off: list[str] = field(default_factory=list)  # names of the frames in a row above the share
    _warned: bool = False
    _frames_seen: int = 0

    def __call__(self, name: str, points: np.ndarray) -> np.ndarray:
        """Frame `name`'s points (N, 3+) in the ground frame -> the same points turned into the site's frame."""
        first = self._frames_seen == 0
        self._frames_seen += 1
        share = self.model.foreground_share(points, self.yaw_deg)
        if share <= MISMATCH_SHARE and not first:
            self._off.clear()
            return turn_about_vertical(points, self.yaw_deg)
        self._off.append(name)
        if first or len(self._off) % MISMATCH_FRAMES == 0:  # a search takes 0.2-0.4 s: once per MISMATCH_FRAMES
            yaw, after = self.model.estimate_yaw(turn_about_vertical(points, self.yaw_deg))
            if after <= MISMATCH_SHARE and share - after >= MIN_EXPLAINED:  # the turn explains the foreground
                self.yaw_deg += yaw
                self.events.append({"type": "sensor_turned", "frames": list(self._off), "yaw_deg": round(yaw, 3),
                                    "total_yaw_deg": round(self.yaw_deg, 3), "foreground_share_before": round(share, 4),
                                    "foreground_share_after": round(after, 4)})
                self.logger.warning(f"frames {', '.join(self._off)}: the sensor looks turned by {yaw:.2f} deg about "
                                    f"the vertical since its background was recorded; realigned (summary.json)")
                self._off.clear()
                return turn_about_vertical(points, self.yaw_deg)
        if share <= MISMATCH_SHARE:  # the first frame, on its background
            self._off.clear()
        elif len(self._off) >= MISMATCH_FRAMES:
            self._report_mismatch(share)
        return turn_about_vertical(points, self.yaw_deg)

    def _report_mismatch(self, share: float) -> None:
        """A background_mismatch event for the frames in a row so far (one per stretch), a warning once per run."""
        if self.events and self.events[-1]["type"] == "background_mismatch" and \
                self.events[-1]["frames"][-1] == self._off[-2]:
            self.events[-1]["frames"].append(self._off[-1])
            return
        self.events.append({"type": "background_mismatch", "frames": list(self._off),
                            "foreground_share": round(share, 4)})
        if not self._warned:
            self._warned = True
            self.logger.warning(f"frames {self._off[0]} to {self._off[-1]}: {share:.0%} of the returns lie in front "
                                f"of the site's background (sensor moved, site changed, or something close to the "
                                f"sensor?): detections may be wrong; if the site changed, record it empty again and "
                                f"rerun `memslidar site train`")
