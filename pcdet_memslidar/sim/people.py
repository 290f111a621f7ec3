"""People of one frame: body shape, clothing reflectivities and a collision-free trajectory.

MAX_TRIES candidate placements are drawn at once (a candidate may bring a companion walking side by side) and
accepted in order unless one of their paths during the frame comes closer than the domain's separation to
someone accepted before, or enters an obstacle's footprint. All draws are made up front with a fixed number of
calls to the frame's numpy Generator, so a frame's people depend only on its seed; trajectories and conflicts
are worked out for the first FIRST_TRIES candidates, and for all of them only in the rare frame that needs more.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.geometry.polygon import points_in_polygon
from pcdet_memslidar.sim.bodies import BodyBank
from pcdet_memslidar.sim.motion import SAMPLE_DT, Trajectory, TrajectoryStack, make_trajectories
from pcdet_memslidar.sim.scenes import Scene
from pcdet_memslidar.sim.site import Site
from pcdet_memslidar.utils.compiled import kernel

BODY_RADIUS_M = 0.35  # clearance of a body's centre from obstacle footprints
GROUP_SPACING_M = 0.75  # lateral distance of companions walking side by side
MAX_TRIES = 60  # candidate placements per frame; people not placed by then are left out
FIRST_TRIES = 16  # candidates worked out first: enough for > 99 % of frames of every domain
# trajectories are sampled this long beyond each end of the frame: the pulse times lie within, and the motion
# during the frame (anchored at mid-frame) does not depend on it
MARGIN_S = SAMPLE_DT
VEST_REFLECTIVITY = 0.95  # fluorescent fabric with retro-reflective stripes
_REFLECTIVITY_LOW = np.array([0.3, 0.05, 0.05, 0.05])  # skin, upper clothing, lower clothing, shoes: uniform
_REFLECTIVITY_WIDTH = np.array([0.55, 0.8, 0.5, 0.3]) - _REFLECTIVITY_LOW


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


def visible_x_range(mount: Mount, vfov_deg: float, scene: Scene,
                    walkable: tuple | None = None) -> tuple[float, float]:
    """(x_min, x_max) [m] of placements: from where a 1.2 m high head enters the lower FoV edge to the scene's
    walking limit or where the upper FoV edge meets the ground, within the walkable polygon's x extent if any."""
    lower = math.radians(mount.tilt_deg + vfov_deg / 2)
    upper = math.radians(mount.tilt_deg - vfov_deg / 2)
    x_min = max(1.0, (mount.height - 1.2) / math.tan(lower)) if lower > 0 else 1.0
    x_max = scene.walk_x_max if upper <= 0 else min(scene.walk_x_max, mount.height / math.tan(upper))
    if walkable is not None:
        corners = np.asarray(walkable)
        x_min, x_max = max(x_min, corners[:, 0].min()), min(x_max, corners[:, 0].max())
    return x_min, x_max


@functools.lru_cache(maxsize=None)
def _behaviour_table(behaviours: tuple[tuple[str, float], ...]) -> tuple[np.ndarray, np.ndarray]:
    """Names (b,) and cumulative probabilities (b,) of a site's behaviours (one uniform picks one, as
    Generator.choice)."""
    names, weights = zip(*behaviours)
    cdf = np.cumsum(np.asarray(weights) / np.sum(weights))
    return np.asarray(names), cdf / cdf[-1]


def _draw_bodies(rng: np.random.Generator, count: int, site: Site,
                 bank: BodyBank) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body shapes (count,), their (count, materials) reflectivities and whether they wear a high-visibility vest
    (count,)."""
    shapes = np.asarray(site.shapes if site.shapes is not None else range(bank.num_shapes))
    shape = shapes[(len(shapes) * rng.random(count)).astype(np.intp)]  # uniform, as rng.integers
    reflectivity = _REFLECTIVITY_LOW + _REFLECTIVITY_WIDTH * rng.random((count, 4))
    vest = rng.random(count) < site.vest_probability
    reflectivity[vest, 1] = VEST_REFLECTIVITY
    return shape, reflectivity, vest


def sample_people(rng: np.random.Generator, site: Site, scene: Scene, mount: Mount, hfov_deg: float,
                  vfov_deg: float, frame_period_s: float, bank: BodyBank) -> list[Person]:
    """The people of one frame (possibly fewer than drawn when the scene is crowded)."""
    count = int(rng.integers(site.people[0], site.people[1] + 1))
    # candidate c: a leader (person 2 c) and a companion (person 2 c + 1) who comes along if it is a group
    x_min, x_max = visible_x_range(mount, vfov_deg, scene, site.walkable)
    grouped = rng.random(MAX_TRIES) < site.group_probability
    x = rng.uniform(x_min, x_max, MAX_TRIES)
    y = rng.uniform(-1.0, 1.0, MAX_TRIES) * (x * math.tan(math.radians(hfov_deg / 2)) + 1.0)
    side = (len(scene.walk_headings) * rng.random(MAX_TRIES)).astype(np.intp)  # uniform, as rng.integers
    heading = np.asarray(scene.walk_headings)[side] + rng.normal(0.0, 0.2, MAX_TRIES)
    names, behaviour_cdf = _behaviour_table(site.behaviours)
    behaviour = names[np.searchsorted(behaviour_cdf, rng.random(MAX_TRIES), side="right")]
    speed = np.clip(rng.normal(1.37, 0.15, MAX_TRIES), 0.9, 1.8)
    events = rng.random((MAX_TRIES, 5))
    shape, reflectivity, vest = _draw_bodies(rng, 2 * MAX_TRIES, site, bank)
    phase = rng.random(2 * MAX_TRIES)  # each person starts at their own point of the gait cycle
    anchor_xy, stride = np.stack([x, y], 1), bank.stride_length(shape)
    for tries in (FIRST_TRIES, MAX_TRIES):
        leaders = make_trajectories(behaviour[:tries], events[:tries], anchor_xy[:tries], heading[:tries],
                                    speed[:tries], stride[0:2 * tries:2], frame_period_s, MARGIN_S)
        companions = leaders.offset(np.full(tries, GROUP_SPACING_M), stride[1:2 * tries:2])
        samples = np.stack([leaders.samples, companions.samples], axis=2).reshape(5, 2 * tries, -1)
        samples[3] += phase[:2 * tries, None]
        frame = np.flatnonzero((leaders.times >= 0.0) & (leaders.times <= frame_period_s))
        paths = np.ascontiguousarray(samples[:2, :, frame[0]:frame[-1] + 1].transpose(0, 2, 1))
        accepted = _accepted(paths, grouped, count, scene, site.min_separation_m, site.walkable)
        if sum(map(len, accepted)) >= count:
            break
    trajectories = TrajectoryStack(leaders.times, samples)
    people: list[Person] = []
    for members in accepted:
        people += [Person(int(shape[p]), trajectories.trajectory(p), reflectivity[p], str(behaviour[p // 2]),
                          len(people), bool(vest[p])) for p in members]
    return people


def _accepted(paths: np.ndarray, grouped: np.ndarray, count: int, scene: Scene, separation_m: float,
              walkable: tuple | None = None) -> list[range]:
    """The members of the candidates accepted in order until they make up `count` people, given the paths
    (2, F, m) [m] (x and y during the frame) of m people (person 2 c + member of candidate c): all clear of
    obstacles and of those accepted before (a group of two only where two people are still missing), and inside
    the walkable polygon ((x, y), ...) if any."""
    off_floor = np.zeros(paths.shape[2], dtype=np.bool_)
    if walkable is not None:
        off_floor = ~points_in_polygon(paths.transpose(2, 1, 0), np.asarray(walkable)).all(axis=1)
    sizes = _accepted_sizes(paths, np.asarray(grouped, dtype=np.bool_), count,
                            scene.obstacles[:, :2].T - BODY_RADIUS_M, scene.obstacles[:, 2:].T + BODY_RADIUS_M,
                            separation_m, off_floor)
    return [range(2 * candidate, 2 * candidate + size) for candidate, size in enumerate(sizes.tolist()) if size]


@kernel
def _accepted_sizes(paths, grouped, count, obstacle_low, obstacle_high, separation_m, off_floor):
    """(m // 2,) people accepted of each candidate (0: not accepted) of the paths (2, F, m) [m], grouped (m // 2,)
    bool, obstacle footprints grown by the body (2, O) low and high x, y [m] (a path enters one where it is strictly
    inside), people closer than separation_m [m] at some sample clash, off_floor (m,) bool paths that leave the
    walkable area."""
    frames, people = paths.shape[1], paths.shape[2]
    sizes = np.zeros(people // 2, np.int64)
    placed = np.empty(people, np.int64)
    count_placed = 0
    for candidate in range(people // 2):
        if count_placed >= count:
            break
        members = 2 if grouped[candidate] and count - count_placed >= 2 else 1
        clear = True
        for p in range(2 * candidate, 2 * candidate + members):
            if off_floor[p]:
                clear = False
            for o in range(obstacle_low.shape[1]):
                for f in range(frames):
                    x, y = paths[0, f, p], paths[1, f, p]
                    if obstacle_low[0, o] < x < obstacle_high[0, o] and obstacle_low[1, o] < y < obstacle_high[1, o]:
                        clear = False
            for q in placed[:count_placed]:
                for f in range(frames):
                    dx, dy = paths[0, f, q] - paths[0, f, p], paths[1, f, q] - paths[1, f, p]
                    if dx * dx + dy * dy < separation_m * separation_m:
                        clear = False
        if clear:
            sizes[candidate] = members
            for p in range(2 * candidate, 2 * candidate + members):
                placed[count_placed] = p
                count_placed += 1
    return sizes
