"""Trajectories of people on the ground plane: walking, turning, stop-and-go and standing.

A trajectory is sampled densely (every SAMPLE_DT s) over a time window around the frame and interpolated at
any pulse time. Times are in s from the frame start, positions in m in the normalised ground frame.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

SAMPLE_DT = 0.02  # s between trajectory samples
WALK_SPEED_FULL = 0.6  # m/s at and above which the body is in the full walking gait (below: blend to standing)
BEHAVIOURS = ("walk", "turn", "stop_and_go", "stand")


@dataclass(frozen=True)
class Trajectory:
    """times (n,) [s] evenly spaced; xy (n, 2) [m]; heading (n,) [rad] unwrapped, direction of travel (facing when
    standing); cycles (n,) gait cycles walked so far; speed (n,) [m/s]."""

    times: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    cycles: np.ndarray
    speed: np.ndarray

    @functools.cached_property
    def samples(self) -> np.ndarray:
        """(5, n) x, y, heading, cycles and speed at the sample times."""
        return np.stack([self.xy[:, 0], self.xy[:, 1], self.heading, self.cycles, self.speed])

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At times t (m,) [s]: xy (m, 2), heading (m,), gait phase (m,) in cycles, walk weight (m,) in [0, 1]."""
        t = np.asarray(t, dtype=np.float64)
        return TrajectoryStack.of([self]).state(np.zeros(t.shape, dtype=np.int64), t)

    def offset(self, lateral_m: float, stride_m: float) -> "Trajectory":
        """The trajectory of a companion walking `lateral_m` to the left (negative: right), same timing."""
        normal = np.stack([-np.sin(self.heading), np.cos(self.heading)], 1)
        return from_path(self.times, self.xy + lateral_m * normal, self.heading, stride_m)


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


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _distance_walked(xy: np.ndarray) -> np.ndarray:
    """(n,) length [m] of the path through the positions xy (n, 2) up to each of them."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xy[:, 0]), np.diff(xy[:, 1])))])


def from_path(times: np.ndarray, xy: np.ndarray, heading: np.ndarray, stride_m: float) -> Trajectory:
    """Trajectory along sampled positions xy (n, 2): speed and gait cycles from the distance walked."""
    distance = _distance_walked(xy)
    return Trajectory(times=times, xy=xy, heading=heading, cycles=distance / stride_m,
                      speed=np.gradient(distance, times))


@functools.lru_cache(maxsize=None)
def _sample_times(frame_period_s: float, margin_s: float) -> np.ndarray:
    """(n,) read-only sample times [s] of a trajectory, one array shared by all trajectories of a frame."""
    times = np.arange(-margin_s, frame_period_s + margin_s + SAMPLE_DT / 2, SAMPLE_DT)
    times.flags.writeable = False
    return times


def make_trajectory(behaviour: str, rng: np.random.Generator, anchor_xy: np.ndarray, heading: float,
                    speed: float, stride_m: float, frame_period_s: float, margin_s: float = 2.0) -> Trajectory:
    """A trajectory of `behaviour` that passes `anchor_xy` (2,) [m] at mid-frame, heading about `heading` [rad]
    (turns are centred on it).

    walk: constant speed and heading. turn: a turn of 45-120 deg within 1-2 s somewhere in the window.
    stop_and_go: decelerate, stand 1-3 s, walk on. stand: no motion, slowly turning on the spot half the time.
    Draws a fixed number of random numbers whatever the behaviour.
    """
    if behaviour not in BEHAVIOURS:
        raise ValueError(f"unknown behaviour '{behaviour}': choose one of {BEHAVIOURS}")
    times = _sample_times(frame_period_s, margin_s)
    centre = frame_period_s / 2
    event_time, event_length, turn, direction, spin = rng.uniform(
        [-1.0, 1.0, np.deg2rad(45), 0.0, 0.0], [frame_period_s + 1.0, 3.0, np.deg2rad(120), 1.0, 1.0])
    sign = 1.0 if direction < 0.5 else -1.0
    speed_profile = np.full(times.shape, speed)
    heading_profile = np.full(times.shape, heading)
    if behaviour == "turn":
        heading_profile = heading + sign * turn * (_smoothstep((times - event_time) / (0.5 * event_length)) - 0.5)
    elif behaviour == "stop_and_go":
        ramp = 0.6  # s to stop or to start
        stopped = (_smoothstep((times - event_time) / ramp)
                   * (1.0 - _smoothstep((times - event_time - ramp - event_length) / ramp)))
        speed_profile = speed * (1.0 - stopped)
    elif behaviour == "stand":
        speed_profile = np.zeros(times.shape)
        turn_rate = sign * 0.4 if spin < 0.5 else 0.0  # rad/s
        heading_profile = heading + turn_rate * (times - centre)
    velocity = speed_profile[:, None] * np.stack([np.cos(heading_profile), np.sin(heading_profile)], 1)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * SAMPLE_DT, axis=0)])
    xy += anchor_xy - np.array([np.interp(centre, times, xy[:, 0]), np.interp(centre, times, xy[:, 1])])
    # gait cycles follow the distance walked (frozen while standing); the speed is the planned profile
    return Trajectory(times=times, xy=xy, heading=heading_profile, cycles=_distance_walked(xy) / stride_m,
                      speed=speed_profile)

