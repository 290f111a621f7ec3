"""Multi-person tracking on the ground plane: one constant-velocity Kalman filter per person, detections assigned
to tracks by the Hungarian method on the distance between a track's predicted and a detection's BEV centre.

    per frame: predict every track to the frame's time
    -> assign detections to tracks (scipy's linear_sum_assignment, pairs farther apart than MAX_DISTANCE refused)
    -> update the assigned tracks; start a tentative track at every unassigned detection
    -> a tentative track is confirmed (and gets the next id, 1, 2, ...) after MIN_HITS hits in a row and is
       dropped at its first miss; a confirmed track is dropped after more than MAX_MISSES misses in a row

Ids go to confirmed tracks only, so a false positive that flickers for a frame uses no id. Parameters: the
optional `TRACKER` block of a detector config (TrackerConfig's fields in upper case).
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import linear_sum_assignment

from pcdet_memslidar.errors import ConfigError


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker parameters (SI units)."""

    max_distance: float = 1.0  # m: farthest a detection may lie from a track's predicted centre and still be it
    min_hits: int = 2  # hits in a row that confirm a track
    max_misses: int = 3  # misses in a row a confirmed track survives (3 frames of 0.4 s: 1.2 s)
    accel_noise: float = 2.0  # m/s^2: std of a walker's acceleration (white-noise acceleration model)
    measurement_noise: float = 0.15  # m: std of a detected centre
    initial_speed: float = 1.5  # m/s: std of a new track's unknown velocity
    min_score: float = 0.3  # detections below this score are neither tracked nor reported

    @classmethod
    def from_block(cls, block: dict | None, where: str) -> "TrackerConfig":
        """A TrackerConfig from a config's TRACKER block ({MAX_DISTANCE: 1.0, ...}); ConfigError naming `where`
        and the close match for an unknown key or a value of the wrong kind."""
        names = {f.name.upper(): f for f in fields(cls)}
        if block is not None and not isinstance(block, dict):
            raise ConfigError(f"{where}: TRACKER is {block!r}: give a mapping of its keys, e.g. {{MAX_DISTANCE: 1.0}} "
                              f"(known keys: {', '.join(names)})")
        values = {}
        for key, value in (block or {}).items():
            if key not in names:
                close = difflib.get_close_matches(key, names, n=1)
                hint = f"did you mean {close[0]}?" if close else f"known keys: {', '.join(names)}"
                raise ConfigError(f"{where}: unknown key TRACKER.{key}; {hint}")
            kind = int if names[key].type == "int" else float
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
                    value < 0 or (kind is int and value != int(value)):
                raise ConfigError(f"{where}: TRACKER.{key} is {value!r}: give a finite, non-negative {kind.__name__}")
            values[names[key].name] = kind(value)
        return cls(**values)


@dataclass
class Track:
    """One person's Kalman state: x = [x, y, vx, vy] (m, m/s) in the ground frame, covariance P (4, 4)."""

    x: np.ndarray
    P: np.ndarray
    box: np.ndarray  # (7,) the last assigned detection's box
    score: float
    hits: int = 1
    misses: int = 0
    track_id: int | None = None  # set at confirmation
    history: list = field(default_factory=list)  # (time_s, x, y) of every hit

    @property
    def confirmed(self) -> bool:
        return self.track_id is not None


@dataclass
class FrameTracks:
    """What one frame's update returns."""

    detection_ids: list[int | None]  # per kept detection: its track's id, None while the track is tentative
    kept: np.ndarray  # (M,) indices of the detections at or above min_score, in input order
    lost: list[Track]  # confirmed tracks dropped in this frame


class Tracker:
    """Tracks of people across frames; feed frames in time order with update()."""

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self.tracks: list[Track] = []
        self.time_s: float | None = None
        self._next_id = 1

    def update(self, boxes: np.ndarray, scores: np.ndarray, time_s: float) -> FrameTracks:
        """Advance to `time_s` (s, non-decreasing) with one frame's detections: boxes (N, 7) OpenPCDet LiDAR boxes,
        scores (N,). Returns the ids of the detections kept (score >= min_score) and the tracks lost."""
        if self.time_s is not None and time_s < self.time_s:
            raise ValueError(f"frame time {time_s} s is before the previous frame's {self.time_s} s: feed frames "
                             "in time order")
        dt = 0.0 if self.time_s is None else time_s - self.time_s
        self.time_s = time_s
        kept = np.flatnonzero(np.asarray(scores) >= self.config.min_score)
        boxes, scores = np.asarray(boxes, np.float64).reshape(-1, 7)[kept], np.asarray(scores, np.float64)[kept]
        for track in self.tracks:
            self._predict(track, dt)
        assigned = dict(self._assign(boxes[:, :2]))
        ids: list[int | None] = []
        touched = set()
        for d in range(len(boxes)):
            if d in assigned:
                track = self.tracks[assigned[d]]
                self._correct(track, boxes[d], scores[d])
            else:
                track = self._start(boxes[d], scores[d])
            touched.add(id(track))
            track.history.append((time_s, float(track.x[0]), float(track.x[1])))
            if track.track_id is None and track.hits >= self.config.min_hits:
                track.track_id, self._next_id = self._next_id, self._next_id + 1
            ids.append(track.track_id)
        lost, survivors = [], []
        for track in self.tracks:
            if id(track) in touched:
                survivors.append(track)
                continue
            track.misses += 1
            if track.confirmed:  # a tentative track is dropped at its first miss
                (lost if track.misses > self.config.max_misses else survivors).append(track)
        self.tracks = survivors
        return FrameTracks(detection_ids=ids, kept=kept, lost=lost)

    # --- Kalman filter (constant velocity, white-noise acceleration)
    def _predict(self, track: Track, dt: float) -> None:
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.config.accel_noise ** 2
        block = np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]]) * q
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = block
        Q[np.ix_([1, 3], [1, 3])] = block
        track.x = F @ track.x
        track.P = F @ track.P @ F.T + Q

    def _correct(self, track: Track, box: np.ndarray, score: float) -> None:
        H = np.eye(2, 4)
        R = np.eye(2) * self.config.measurement_noise ** 2
        S = H @ track.P @ H.T + R
        K = track.P @ H.T @ np.linalg.inv(S)
        track.x = track.x + K @ (box[:2] - H @ track.x)
        track.P = (np.eye(4) - K @ H) @ track.P
        track.box, track.score = box.copy(), float(score)
        track.hits, track.misses = track.hits + 1, 0

    def _start(self, box: np.ndarray, score: float) -> Track:
        P = np.diag([self.config.measurement_noise ** 2] * 2 + [self.config.initial_speed ** 2] * 2)
        track = Track(x=np.array([box[0], box[1], 0.0, 0.0]), P=P, box=box.copy(), score=float(score))
        self.tracks.append(track)
        return track

    def _assign(self, centres: np.ndarray) -> list[tuple[int, int]]:
        """(detection, track) index pairs of the least total distance, each within max_distance."""
        if not len(centres) or not self.tracks:
            return []
        predicted = np.array([track.x[:2] for track in self.tracks])
        cost = np.linalg.norm(centres[:, None, :] - predicted[None, :, :], axis=2)
        gate = self.config.max_distance
        rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, gate * 1e3 + 1.0))
        return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] <= gate]
