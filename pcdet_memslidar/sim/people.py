"""People of one frame: body shape, clothing reflectivities and a collision-free trajectory.

People are placed one by one (a newly placed person may bring a companion walking side by side); a placement
whose path during the frame comes closer than the domain's separation to someone already placed, or enters an
obstacle's footprint, is redrawn. Everything is drawn from the frame's numpy Generator, so a frame's people
depend only on its seed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.sim.bodies import BodyBank
from pcdet_memslidar.sim.domains import DomainPreset
from pcdet_memslidar.sim.motion import Trajectory, make_trajectory
from pcdet_memslidar.sim.scenes import Scene

BODY_RADIUS_M = 0.35  # clearance of a body's centre from obstacle footprints
GROUP_SPACING_M = 0.75  # lateral distance of companions walking side by side
MAX_TRIES = 60  # placements tried per frame before giving up on the remaining people
VEST_REFLECTIVITY = 0.95  # fluorescent fabric with retro-reflective stripes


@dataclass(frozen=True)
class Person:
    """shape: body-bank shape index; reflectivity (materials,) per body material (skin, upper clothing, lower
    clothing, shoes); behaviour: walk | turn | stop_and_go | stand; group: index of the group (companions share
    it)."""

    shape: int
    trajectory: Trajectory
    reflectivity: np.ndarray
    behaviour: str
    group: int
    vest: bool


def visible_x_range(mount: Mount, vfov_deg: float, scene: Scene) -> tuple[float, float]:
    """(x_min, x_max) [m] of placements: from where a 1.2 m high head enters the lower FoV edge to the scene's
    walking limit or where the upper FoV edge meets the ground."""
    lower = np.deg2rad(mount.tilt_deg + vfov_deg / 2)
    upper = np.deg2rad(mount.tilt_deg - vfov_deg / 2)
    x_min = max(1.0, (mount.height - 1.2) / np.tan(lower))
    x_max = scene.walk_x_max if upper <= 0 else min(scene.walk_x_max, mount.height / np.tan(upper))
    return x_min, x_max


def _draw_body(rng: np.random.Generator, preset: DomainPreset, bank: BodyBank) -> tuple[int, np.ndarray, bool]:
    """A body shape, its (materials,) reflectivities and whether it wears a high-visibility vest."""
    shapes = preset.shapes if preset.shapes is not None else tuple(range(bank.num_shapes))
    shape = int(shapes[rng.integers(len(shapes))])
    skin, upper, lower, shoes, vest_draw = rng.uniform([0.3, 0.05, 0.05, 0.05, 0.0], [0.55, 0.8, 0.5, 0.3, 1.0])
    vest = bool(vest_draw < preset.vest_probability)
    reflectivity = np.array([skin, VEST_REFLECTIVITY if vest else upper, lower, shoes])
    return shape, reflectivity, vest


def sample_people(rng: np.random.Generator, preset: DomainPreset, scene: Scene, mount: Mount, hfov_deg: float,
                  vfov_deg: float, frame_period_s: float, bank: BodyBank) -> list[Person]:
    """The people of one frame (possibly fewer than drawn when the scene is crowded)."""
    count = int(rng.integers(preset.people[0], preset.people[1] + 1))
    x_min, x_max = visible_x_range(mount, vfov_deg, scene)
    names, weights = zip(*preset.behaviours)
    behaviour_cdf = np.cumsum(np.asarray(weights) / np.sum(weights))  # drawn with one uniform, as Generator.choice
    behaviour_cdf /= behaviour_cdf[-1]
    people: list[Person] = []
    frame, placed = None, None  # mask of the sample times during the frame, (k, F, 2) paths of those placed
    for _ in range(MAX_TRIES):
        if len(people) >= count:
            break
        size = 2 if count - len(people) >= 2 and rng.random() < preset.group_probability else 1
        x = rng.uniform(x_min, x_max)
        y = rng.uniform(-1.0, 1.0) * (x * np.tan(np.deg2rad(hfov_deg / 2)) + 1.0)
        heading = scene.walk_headings[rng.integers(len(scene.walk_headings))] + rng.normal(0.0, 0.2)
        behaviour = names[int(np.searchsorted(behaviour_cdf, rng.random(), side="right"))]
        speed = float(np.clip(rng.normal(1.37, 0.15), 0.9, 1.8))
        group = len(people)
        members = []
        for member in range(size):
            shape, reflectivity, vest = _draw_body(rng, preset, bank)
            stride = float(bank.stride_length(np.array([shape]))[0])
            if member == 0:
                trajectory = make_trajectory(behaviour, rng, np.array([x, y]), heading, speed, stride, frame_period_s)
            else:
                trajectory = members[0].trajectory.offset(GROUP_SPACING_M * (1 if member % 2 else -1), stride)
            # each person starts at their own point of the gait cycle
            phase = rng.random()
            trajectory = Trajectory(trajectory.times, trajectory.xy, trajectory.heading, trajectory.cycles + phase,
                                    trajectory.speed)
            members.append(Person(shape, trajectory, reflectivity, behaviour, group, vest))
        if placed is None:
            frame = (members[0].trajectory.times >= 0.0) & (members[0].trajectory.times <= frame_period_s)
            placed = np.zeros((0, frame.sum(), 2))
        paths = np.stack([m.trajectory.xy[frame] for m in members])
        if all(_is_free(path, placed, scene, preset.min_separation_m) for path in paths):
            people.extend(members)
            placed = np.concatenate([placed, paths])
    return people


def _is_free(path: np.ndarray, others: np.ndarray, scene: Scene, separation_m: float) -> bool:
    """True if the path (F, 2) [m] of a person during the frame stays clear of obstacle footprints and of the paths
    (k, F, 2) of others."""
    if len(scene.obstacles):
        low = scene.obstacles[:, :2] - BODY_RADIUS_M
        high = scene.obstacles[:, 2:] + BODY_RADIUS_M
        inside = ((path[:, None, :] > low[None]) & (path[:, None, :] < high[None])).all(axis=2)
        if inside.any():
            return False
    gap = path - others
    return not len(others) or bool(np.hypot(gap[..., 0], gap[..., 1]).min() >= separation_m)
