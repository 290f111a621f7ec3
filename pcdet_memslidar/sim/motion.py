"""Trajectories of people on the ground plane: walking, turning, stop-and-go and standing.

A trajectory is sampled densely (every SAMPLE_DT s) over a time window around the frame and interpolated at
any pulse time. Times are in s from the frame start, positions in m in the normalised ground frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAMPLE_DT = 0.02  # s between trajectory samples
WALK_SPEED_FULL = 0.6  # m/s at and above which the body is in the full walking gait (below: blend to standing)
BEHAVIOURS = ("walk", "turn", "stop_and_go", "stand")


@dataclass(frozen=True)
class Trajectory:
    """times (n,) [s]; xy (n, 2) [m]; heading (n,) [rad] unwrapped, direction of travel (facing when standing);
    cycles (n,) gait cycles walked so far; speed (n,) [m/s]."""

    times: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    cycles: np.ndarray
    speed: np.ndarray

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At times t (m,) [s]: xy (m, 2), heading (m,), gait phase (m,) in cycles, walk weight (m,) in [0, 1]."""
        t = np.asarray(t, dtype=np.float64)
        xy = np.stack([np.interp(t, self.times, self.xy[:, 0]), np.interp(t, self.times, self.xy[:, 1])], 1)
        walk_weight = np.clip(np.interp(t, self.times, self.speed) / WALK_SPEED_FULL, 0.0, 1.0)
        return xy, np.interp(t, self.times, self.heading), np.interp(t, self.times, self.cycles), walk_weight

    def offset(self, lateral_m: float, stride_m: float) -> "Trajectory":
        """The trajectory of a companion walking `lateral_m` to the left (negative: right), same timing."""
        normal = np.stack([-np.sin(self.heading), np.cos(self.heading)], 1)
        return from_path(self.times, self.xy + lateral_m * normal, self.heading, stride_m)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def from_path(times: np.ndarray, xy: np.ndarray, heading: np.ndarray, stride_m: float) -> Trajectory:
    """Trajectory along sampled positions xy (n, 2): speed and gait cycles from the distance walked."""
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    distance = np.concatenate([[0.0], np.cumsum(step)])
    speed = np.gradient(distance, times)
    return Trajectory(times=times, xy=xy, heading=heading, cycles=distance / stride_m, speed=speed)


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
    times = np.arange(-margin_s, frame_period_s + margin_s + SAMPLE_DT / 2, SAMPLE_DT)
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
        stopped = _smoothstep((times - event_time) / ramp) * (1.0 - _smoothstep((times - event_time - ramp - event_length) / ramp))
        speed_profile = speed * (1.0 - stopped)
    elif behaviour == "stand":
        speed_profile = np.zeros(times.shape)
        turn_rate = sign * 0.4 if spin < 0.5 else 0.0  # rad/s
        heading_profile = heading + turn_rate * (times - centre)
    velocity = speed_profile[:, None] * np.stack([np.cos(heading_profile), np.sin(heading_profile)], 1)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * SAMPLE_DT, axis=0)])
    xy += anchor_xy - np.array([np.interp(centre, times, xy[:, 0]), np.interp(centre, times, xy[:, 1])])
    trajectory = from_path(times, xy, heading_profile, stride_m)
    # gait cycles follow the distance walked (frozen while standing); the speed is the planned profile
    return Trajectory(times=times, xy=xy, heading=heading_profile, cycles=trajectory.cycles, speed=speed_profile)

