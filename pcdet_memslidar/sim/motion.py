"""Trajectories of people on the ground plane: walking, turning, stop-and-go and standing.

A trajectory is sampled densely (every SAMPLE_DT s) over a time window around the frame and interpolated at
any pulse time. Times are in s from the frame start, positions in m in the normalised ground frame.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.utils.compiled import kernel

SAMPLE_DT = 0.02  # s between trajectory samples
WALK_SPEED_FULL = 0.6  # m/s at and above which the body is in the full walking gait (below: blend to standing)
BEHAVIOURS = ("walk", "turn", "stop_and_go", "stand")
_TURN, _STOP_AND_GO, _STAND = (BEHAVIOURS.index(name) for name in ("turn", "stop_and_go", "stand"))
RAMP_S = 0.6  # s to stop or to start walking again


@dataclass(frozen=True)
class Trajectory:
    """times (n,) [s] evenly spaced; samples (5, n): x, y [m], heading [rad] unwrapped, direction of travel (facing
    when standing), gait cycles walked so far and speed [m/s] at those times (as one row of a TrajectoryStack)."""

    times: np.ndarray
    samples: np.ndarray

    @property
    def xy(self) -> np.ndarray:
        """(n, 2) [m]"""
        return self.samples[:2].T

    @property
    def heading(self) -> np.ndarray:
        return self.samples[2]

    @property
    def cycles(self) -> np.ndarray:
        return self.samples[3]

    @property
    def speed(self) -> np.ndarray:
        return self.samples[4]

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At times t (m,) [s]: xy (m, 2), heading (m,), gait phase (m,) in cycles, walk weight (m,) in [0, 1]."""
        t = np.asarray(t, dtype=np.float64)
        return TrajectoryStack.of([self]).state(np.zeros(t.shape, dtype=np.int64), t)


@dataclass(frozen=True)
class TrajectoryStack:
    """The trajectories of k people sampled at the same evenly spaced times (n,) [s], as one table samples
    (5, k, n) of x [m], y [m], heading [rad], gait cycles and speed [m/s]; channel-major, so that numpy loops run
    over the many (person, time) pairs whose states it interpolates in one pass."""

    times: np.ndarray
    samples: np.ndarray

    @classmethod
    def of(cls, trajectories: list[Trajectory]) -> "TrajectoryStack":
        times = trajectories[0].times
        if any(t.times is not times and not np.array_equal(t.times, times) for t in trajectories[1:]):
            raise ValueError("trajectories stacked together must share their sample times")
        return cls(times, np.stack([t.samples for t in trajectories], axis=1))

    @classmethod
    def along_paths(cls, times: np.ndarray, xy: np.ndarray, heading: np.ndarray,
                    stride_m: np.ndarray) -> "TrajectoryStack":
        """k people along sampled positions xy (2, k, n) [m] with heading (k, n) [rad]: speed and gait cycles (of
        stride_m (k,) [m]) from the distance walked."""
        step = np.hypot(*np.diff(xy))  # (k, n - 1) [m] walked between samples
        walked = step @ _walked(len(times))
        distance, speed = walked[:, :len(times)], walked[:, len(times):] / (times[1] - times[0])
        return cls(times, np.stack([xy[0], xy[1], heading, distance / stride_m[:, None], speed]))

    def trajectory(self, person: int) -> Trajectory:
        """The trajectory of one person (a view into the table)."""
        return Trajectory(self.times, self.samples[:, person])

    def offset(self, lateral_m: np.ndarray, stride_m: np.ndarray) -> "TrajectoryStack":
        """Companions walking lateral_m (k,) [m] to the left (negative: right) of the k people, same timing, with
        gait cycles of stride_m (k,) [m]."""
        heading = self.samples[2]
        normal = np.stack([-np.sin(heading), np.cos(heading)])
        return self.along_paths(self.times, self.samples[:2] + lateral_m[:, None] * normal, heading, stride_m)

    def state(self, person: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Of person (m,) at times t (m,) [s] (clamped to the sampled window), linearly interpolated: xy (m, 2),
        heading (m,), gait phase (m,) in cycles, walk weight (m,) in [0, 1]."""
        last = len(self.times) - 1
        position = np.clip((t - self.times[0]) / (self.times[-1] - self.times[0]) * last, 0.0, last)
        lower = np.minimum(position.astype(np.int64), last - 1)
        column = person * len(self.times) + lower
        flat = self.samples.reshape(len(self.samples), -1)
        low, high = flat.take(column, axis=1), flat.take(column + 1, axis=1)
        x, y, heading, cycles, speed = low + (position - lower) * (high - low)
        return np.stack([x, y], axis=1), heading, cycles, np.clip(speed / WALK_SPEED_FULL, 0.0, 1.0)


@kernel(inline="always")
def _smoothstep(x: float) -> float:
    """0 below 0, 1 above 1 and 3 x^2 - 2 x^3 between: a ramp with zero slope at both ends."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@functools.lru_cache(maxsize=None)
def _sample_times(frame_period_s: float, margin_s: float) -> np.ndarray:
    """(n,) read-only sample times [s] of a trajectory, one array shared by all trajectories of a frame."""
    times = np.arange(-margin_s, frame_period_s + margin_s + SAMPLE_DT / 2, SAMPLE_DT)
    times.flags.writeable = False
    return times


@functools.lru_cache(maxsize=None)
def _walked(n: int) -> np.ndarray:
    """(n - 1, 2 n) matrix m taking the steps (..., n - 1) [m] between n samples, as steps @ m, to the distance
    walked up to each sample and to its central differences (one-sided at the ends, as np.gradient) times the
    sample spacing."""
    step = np.arange(n - 1)
    walked = np.zeros((n - 1, 2 * n))
    walked[:, :n] = np.triu(np.ones((n - 1, n)), 1)
    walked[step, n + step] = walked[step, n + step + 1] = 0.5
    walked[0, n] = walked[-1, -1] = 1.0
    walked.flags.writeable = False
    return walked


@functools.lru_cache(maxsize=None)
def _integrals(frame_period_s: float, margin_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(n, n) matrices m that integrate rates (..., n) given at the sample times (trapezoidal rule) as rates @ m:
    from the window start, and from mid-frame (interpolated between the samples around it)."""
    times = _sample_times(frame_period_s, margin_s)
    from_start = np.triu(np.full((len(times), len(times)), SAMPLE_DT))  # [j, i]: weight of rate j in integral i
    from_start[np.diag_indices(len(times))] -= SAMPLE_DT / 2
    from_start[0] -= SAMPLE_DT / 2
    j = int(np.searchsorted(times, frame_period_s / 2, side="right")) - 1
    weight = (frame_period_s / 2 - times[j]) / (times[j + 1] - times[j])
    from_centre = from_start - (from_start[:, j] + weight * (from_start[:, j + 1] - from_start[:, j]))[:, None]
    from_start.flags.writeable = from_centre.flags.writeable = False
    return from_start, from_centre


@functools.lru_cache(maxsize=None)
def _event_range(frame_period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower bounds (5,) and widths (5,) of the uniform event draws: time [s], length [s], turn [rad], turn
    direction and spin (< 0.5: left, spinning)."""
    low = np.array([-1.0, 1.0, np.deg2rad(45), 0.0, 0.0])
    high = np.array([frame_period_s + 1.0, 3.0, np.deg2rad(120), 1.0, 1.0])
    return low, high - low


def make_trajectories(behaviour: np.ndarray, events: np.ndarray, anchor_xy: np.ndarray, heading: np.ndarray,
                      speed: np.ndarray, stride_m: np.ndarray, frame_period_s: float,
                      margin_s: float = 2.0) -> TrajectoryStack:
    """k trajectories sampled from `margin_s` before to `margin_s` after the frame: person i does behaviour[i] (one
    of BEHAVIOURS), passes anchor_xy[i] (k, 2) [m] at mid-frame heading about heading[i] [rad] (turns are centred
    on it) at speed[i] [m/s], with gait cycles of stride_m[i] [m]; events (k, 5) are uniform draws in [0, 1) that
    place each person's event (time, length, turn angle, turn direction, spin).

    walk: constant speed and heading. turn: a turn of 45-120 deg within 0.5-1.5 s somewhere in the window.
    stop_and_go: decelerate, stand 1-3 s, walk on. stand: no motion, slowly turning on the spot half the time.
    """
    behaviour = np.asarray(behaviour)
    unknown = set(behaviour.tolist()).difference(BEHAVIOURS)
    if unknown:
        raise ValueError(f"unknown behaviour '{min(unknown)}': choose one of {BEHAVIOURS}")
    times = _sample_times(frame_period_s, margin_s)
    code = (behaviour[:, None] == np.array(BEHAVIOURS)).argmax(axis=1)
    low, width = _event_range(frame_period_s)
    heading_profile, speed_profile = _profiles(code, np.asarray(events, dtype=np.float64),
                                               np.asarray(heading, dtype=np.float64),
                                               np.asarray(speed, dtype=np.float64), times, frame_period_s / 2, low,
                                               width)
    # positions: the velocity integrated from mid-frame, where they pass the anchor; gait cycles: the distance
    # walked (the speed integrated; frozen while standing) in strides; the speed is the planned profile
    from_start, from_centre = _integrals(frame_period_s, margin_s)
    velocity = speed_profile * np.stack([np.cos(heading_profile), np.sin(heading_profile)])
    x, y = np.asarray(anchor_xy, dtype=np.float64).T[:, :, None] + velocity @ from_centre
    cycles = (speed_profile @ from_start) / np.asarray(stride_m)[:, None]
    return TrajectoryStack(times, np.stack([x, y, heading_profile, cycles, speed_profile]))


@kernel
def _profiles(code, events, heading, speed, times, centre, low, width):
    """Heading [rad] and speed [m/s] profiles (k, n) of k people at the sample times (n,) [s], as make_trajectories
    describes them: code (k,) index of each behaviour in BEHAVIOURS, events (k, 5) uniform draws scaled to
    low (5,) + width (5,) x draw, heading (k,) [rad] and speed (k,) [m/s] planned, centre [s] mid-frame.

    turn: the heading swings by sign x turn within event_length / 2; stop_and_go: the speed ramps down, stays 0
    for event_length and ramps up again; stand: no motion, spinning on the spot half the time."""
    heading_profile = np.empty((len(code), len(times)))
    speed_profile = np.empty((len(code), len(times)))
    for i in range(len(code)):
        event_time, event_length = low[0] + width[0] * events[i, 0], low[1] + width[1] * events[i, 1]
        turn, direction, spin = (low[2] + width[2] * events[i, 2], low[3] + width[3] * events[i, 3],
                                 low[4] + width[4] * events[i, 4])
        turning, stopping, standing = code[i] == _TURN, code[i] == _STOP_AND_GO, code[i] == _STAND
        sign = 1.0 if direction < 0.5 else -1.0
        cruise = 0.0 if standing else speed[i]
        spin_rate = sign * 0.4 if standing and spin < 0.5 else 0.0  # rad/s
        for j in range(len(times)):
            since = times[j] - event_time
            rise = _smoothstep(since / (0.5 * event_length if turning else RAMP_S))
            fall = _smoothstep((since - RAMP_S - event_length) / RAMP_S)
            speed_profile[i, j] = cruise * (1.0 - rise * (1.0 - fall)) if stopping else cruise
            heading_profile[i, j] = heading[i] + (sign * turn * (rise - 0.5) if turning
                                                  else spin_rate * (times[j] - centre))
    return heading_profile, speed_profile


def make_trajectory(behaviour: str, rng: np.random.Generator, anchor_xy: np.ndarray, heading: float,
                    speed: float, stride_m: float, frame_period_s: float, margin_s: float = 2.0) -> Trajectory:
    """The trajectory of one person (as `make_trajectories`) doing `behaviour` through `anchor_xy` (2,) [m] at
    mid-frame, heading about `heading` [rad]. Draws 5 random numbers whatever the behaviour."""
    return make_trajectories(np.array([behaviour]), rng.random((1, 5)), np.reshape(anchor_xy, (1, 2)),
                             np.array([heading]), np.array([speed]), np.array([stride_m]), frame_period_s,
                             margin_s).trajectory(0)
