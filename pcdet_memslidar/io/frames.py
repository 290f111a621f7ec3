"""What the readers of input formats (io.formats) yield: frames to load, and frames of every pulse; and how a
recording is read again to load them (SequentialReader)."""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Callable, Iterator

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
    """One file of a format that carries pulses: its frames' names and start times [ns], load(index) -> the frame
    (read again from the file when asked, so a recording of any length is held one frame at a time) and the scan
    pattern it records (hfov_deg, vfov_deg [deg], lines_up, lines_down, angle_spacing_deg [deg]; None: not
    recorded)."""

    names: list[str]
    start_times_ns: list[int]
    load: Callable[[int], PulseFrame]
    pattern: dict[str, float] | None = None

    @property
    def frames(self) -> list[PulseFrame]:
        """Every frame, loaded (for a short recording: a site's background)."""
        return [self.load(index) for index in range(len(self.names))]


class SequentialReader:
    """A recording's items (messages, frames) by index, for loading its frames after they were listed: read in
    order by one open reader, opened again from the start for an item before the last one read. So a recording
    is held in memory one item at a time, whatever its length, and loading its frames in order reads it once.

    open_items() -> (iterator of (index, item) in order, close()); gone(index) -> the exception for an index the
    recording no longer has (it changed after it was listed)."""

    def __init__(self, open_items: Callable[[], tuple[Iterator, Callable[[], None]]],
                 gone: Callable[[int], Exception]):
        self._open_items, self._gone = open_items, gone
        self._open: list = []  # [items, close] while a reader is open (closed when this is collected)
        self._next = 0  # the index the open reader yields next
        weakref.finalize(self, _close, self._open)

    def item(self, index: int):
        """The item `index`."""
        if not self._open or index < self._next:
            _close(self._open)
            self._open += self._open_items()
            self._next = 0
        for position, item in self._open[0]:
            self._next = position + 1
            if position == index:
                return item
        _close(self._open)
        raise self._gone(index)


def _close(opened: list) -> None:
    """Close the reader in `opened` ([items, close] or empty) and empty it."""
    if opened:
        opened[1]()
        opened.clear()
