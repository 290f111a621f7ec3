"""What the readers of input formats (io.formats) yield: frames to load, and frames of every pulse."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pcdet_memslidar.io.cvat import CvatFrame
from pcdet_memslidar.io.pointclouds import LoadedCloud


@dataclass
class SourceFrame:
    """One frame of a recording: its name in the source, a loader of its cloud, its cuboids (None: no labels), its
    start time [s] since the recording's first frame, its recorded start time [ns] since the epoch and the name of
    its coordinate frame (a ROS header's frame_id) (None: the format does not say)."""

    name: str
    load: Callable[[], LoadedCloud]
    cuboids: CvatFrame | None = None
    time_s: float | None = None
    stamp_ns: int | None = None
    frame_id: str | None = None


def frame_stamp_ns(frame: SourceFrame, time_s: float) -> int:
    """The frame's recorded start time [ns since the epoch], else its time `time_s` [s] since the first frame."""
    return frame.stamp_ns if frame.stamp_ns is not None else round(time_s * 1e9)


@dataclass(frozen=True)
class PulseFrame:
    """One frame of every pulse of the scan pattern, with or without a return (P pulses, sensor frame, KITTI axes):
    directions (P, 3) unit vectors, time_offset (P,) [s] from the frame start, points (P, 4) float32 x, y, z,
    intensity of each pulse's strongest return (nan: none); start_time_ns [ns] of the frame; unmatched: weaker
    returns left out; name: '<file>#<frame>'."""

    name: str
    start_time_ns: int
    directions: np.ndarray
    time_offset: np.ndarray
    points: np.ndarray
    unmatched: int = 0

    @property
    def returned(self) -> np.ndarray:
        """(P,) bool: pulses with a return."""
        return ~np.isnan(self.points[:, 0])


@dataclass(frozen=True)
class PulseRecording:
    """One file of a format that carries pulses: its frames, and the scan pattern it records (hfov_deg, vfov_deg
    [deg], lines_up, lines_down, angle_spacing_deg [deg]; None: not recorded)."""

    frames: list[PulseFrame]
    pattern: dict[str, float] | None = None
