"""Objects that are not people (distractors), ray-cast into a background recording together with the people.

A person detector trained on people composited into an empty site has never seen a new object there: a pallet put
down, a cart, a forklift, a door standing open, a post. Per frame of a background site with `distractors`:
1. draw the frame's distractors from their own generator (`frame_distractors`), so a site without them draws
   nothing and its frames stay as they were;
2. place each on the walkable floor (its whole footprint), in the field of view, CLEARANCE_M clear of what the
   background shows standing on the floor and of the other distractors; they stand still;
3. the people are placed next, walking around the distractors' footprints (sim/composite.py);
4. every pulse is cast against the distractors (`cast_distractors`); a distractor hit nearer than the pulse's real
   return and than any person returns through the site's sensor physics like a person's; distractors get no label.
Each kind is a mesh of boxes or a prism (sim/scenes.py `World`) with one 905 nm reflectivity; its parts stay inside
its length x width footprint (dx along its yaw, dy across it).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.geometry.polygon import points_in_polygon
from pcdet_memslidar.sim.caster import cast_rays
from pcdet_memslidar.sim.pattern import ScanPattern, get_pattern
from pcdet_memslidar.sim.scenes import Scene, Surface, World
from pcdet_memslidar.sim.site import Site, in_field_of_view
from pcdet_memslidar.utils.open3d import import_open3d

MAX_TRIES = 100  # candidate placements per frame; distractors not placed by then are left out
CLEARANCE_M = 0.1  # free floor kept between a distractor's footprint and obstacles or other distractors
DISTRACTOR_STREAM = 0xD157  # spawn key of the distractors' generator under the frame's seed (sim.frame.frame_rng)
PALLET_HEIGHT_M = 0.15  # a pallet's own height; a taller one carries a load


def _box(world: World, centre, size, yaw: float, reflectivity: float) -> None:
    world.box(centre, size, reflectivity, yaw=yaw)


def _pole(world: World, centre, size, yaw: float, reflectivity: float) -> None:
    world.prism(centre, size[0] / 2, size[2], reflectivity, sides=12)


def _at(centre, yaw: float, along: float, across: float = 0.0) -> np.ndarray:
    """(2,) the point `along` [m] ahead of `centre` in the direction `yaw` and `across` [m] to its left."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.asarray(centre) + along * np.array([c, s]) + across * np.array([-s, c])


def _pallet(world: World, centre, size, yaw: float, reflectivity: float) -> None:
    """A pallet with a load (wrapped goods, 5 cm in from its edges) up to the whole height."""
    dx, dy, dz = size
    world.box(centre, (dx, dy, PALLET_HEIGHT_M), reflectivity, yaw=yaw)
    if dz > PALLET_HEIGHT_M:
        world.box(centre, (dx - 0.1, dy - 0.1, dz - PALLET_HEIGHT_M), reflectivity, z0=PALLET_HEIGHT_M, yaw=yaw)


def _cart(world: World, centre, size, yaw: float, reflectivity: float) -> None:
    """A platform trolley: a deck 0.15-0.3 m above the floor, a U-shaped handle of 4 cm tubes at its back end."""
    dx, dy, dz = size
    world.box(centre, (dx, dy, 0.15), reflectivity, z0=0.15, yaw=yaw)
    for side in (-1, 1):
        world.box(_at(centre, yaw, 0.02 - dx / 2, side * (dy / 2 - 0.02)), (0.04, 0.04, dz - 0.34), reflectivity,
                  z0=0.3, yaw=yaw)
    world.box(_at(centre, yaw, 0.02 - dx / 2), (0.04, dy, 0.04), reflectivity, z0=dz - 0.04, yaw=yaw)


def _forklift(world: World, centre, size, yaw: float, reflectivity: float) -> None:
    """A forklift facing `yaw`: body (the back 65 %), cab on it, mast, forks on the floor in front."""
    dx, dy, dz = size
    body_height = 0.45 * dz
    world.box(_at(centre, yaw, -0.175 * dx), (0.65 * dx, dy, body_height), reflectivity, z0=0.1, yaw=yaw)
    world.box(_at(centre, yaw, -0.2 * dx), (0.35 * dx, 0.9 * dy, dz - body_height - 0.1), reflectivity,
              z0=body_height + 0.1, yaw=yaw)
    world.box(_at(centre, yaw, 0.19 * dx), (0.08 * dx, 0.8 * dy, dz), reflectivity, yaw=yaw)
    world.box(_at(centre, yaw, 0.365 * dx), (0.27 * dx, 0.7 * dy, 0.05), reflectivity, z0=0.05, yaw=yaw)


@dataclass(frozen=True)
class Kind:
    """A kind of distractor: size ((low, high) of dx, dy, dz) [m] and reflectivity (low, high), each drawn
    uniformly; cylinder: a vertical cylinder of diameter dx (dy = dx); build(world, centre, size, yaw, reflectivity)
    adds its surfaces."""

    size: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    reflectivity: tuple[float, float]
    build: Callable
    cylinder: bool = False


KINDS = {
    "box": Kind(((0.3, 0.8), (0.3, 0.6), (0.3, 0.9)), (0.2, 0.6), _box),  # cardboard boxes, crates, bins
    "pallet": Kind(((1.2, 1.2), (0.8, 0.8), (0.15, 1.2)), (0.25, 0.5), _pallet),  # EUR pallet, empty to loaded
    "cart": Kind(((0.9, 1.1), (0.5, 0.7), (0.9, 1.1)), (0.2, 0.5), _cart),
    "forklift": Kind(((2.3, 2.7), (1.0, 1.3), (2.0, 2.2)), (0.2, 0.6), _forklift),
    "door": Kind(((0.8, 1.0), (0.04, 0.04), (1.9, 2.1)), (0.15, 0.6), _box),  # a leaf standing open at any yaw
    # hard negatives of a person's size
    "column": Kind(((0.4, 0.6), (0.4, 0.6), (1.5, 1.9)), (0.1, 0.7), _box),
    "pole": Kind(((0.3, 0.5), (0.3, 0.5), (1.6, 2.0)), (0.1, 0.7), _pole, cylinder=True),
}


@dataclass(frozen=True)
class Distractor:
    """One object that is not a person, standing on the floor: kind (a name of KINDS), centre (x, y) [m], size
    (dx, dy, dz) [m] (dx along yaw), yaw [rad], reflectivity in [0, 1]."""

    kind: str
    centre: tuple[float, float]
    size: tuple[float, float, float]
    yaw: float
    reflectivity: float

    @property
    def corners(self) -> np.ndarray:
        """(4, 2) [m] corners of its dx x dy footprint on the floor."""
        half = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]) * np.array(self.size[:2]) / 2
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.asarray(self.centre) + half @ np.array([[c, s], [-s, c]])

    @property
    def footprint(self) -> np.ndarray:
        """(4,) [x0, y0, x1, y1] [m]: the axis-aligned box around its footprint (as Scene.obstacles)."""
        corners = self.corners
        return np.concatenate([corners.min(0), corners.max(0)])

    def surfaces(self) -> tuple[Surface, ...]:
        """Its meshes in the ground frame."""
        world = World()
        KINDS[self.kind].build(world, self.centre, self.size, self.yaw, self.reflectivity)
        return tuple(world.surfaces)

    def record(self) -> dict:
        """Its frame metadata entry."""
        return dict(kind=self.kind, centre=[round(v, 4) for v in self.centre], size=[round(v, 4) for v in self.size],
                    yaw=round(self.yaw, 4), reflectivity=round(self.reflectivity, 4))


def footprints(distractors: Sequence[Distractor]) -> np.ndarray:
    """(D, 4) [x0, y0, x1, y1] [m] of the distractors: obstacles people walk around."""
    return np.array([d.footprint for d in distractors], dtype=np.float64).reshape(-1, 4)


def _overlaps(box: np.ndarray, boxes: np.ndarray, margin: float) -> bool:
    """Whether box (4,) [x0, y0, x1, y1] grown by `margin` [m] overlaps one of boxes (O, 4)."""
    return bool(np.any((boxes[:, 0] < box[2] + margin) & (box[0] - margin < boxes[:, 2])
                       & (boxes[:, 1] < box[3] + margin) & (box[1] - margin < boxes[:, 3])))


def _drawn(name: str, centre: np.ndarray, yaw: float, draw: np.ndarray) -> Distractor:
    """The distractor of kind `name` at centre (2,) [m] and yaw [rad] whose dx, dy, dz and reflectivity lie draw (4,)
    (uniform in [0, 1)) of the way through the kind's ranges."""
    spec = KINDS[name]
    low, high = np.array([*spec.size, spec.reflectivity]).T
    value = low + draw * (high - low)
    if spec.cylinder:
        value[1] = value[0]
    return Distractor(name, (float(centre[0]), float(centre[1])), tuple(value[:3].tolist()), float(yaw),
                      float(value[3]))


def sample_distractors(rng: np.random.Generator, count: int, walkable, obstacles: np.ndarray, mount: Mount,
                       pattern: str | ScanPattern, kinds: tuple[str, ...] | None = None) -> list[Distractor]:
    """Up to `count` distractors of `kinds` (None: all KINDS) on the floor polygon walkable ((x, y), ...) [m].

    MAX_TRIES candidates are drawn at once (kind, centre in the polygon's bounding box, yaw, size and reflectivity
    in the kind's ranges) and accepted in order while fewer than `count` are placed: the whole footprint inside
    `walkable`, its centre line (foot, middle or top) in the field of view of `pattern` from `mount`, the footprint
    CLEARANCE_M clear of obstacles (O, 4) [x0, y0, x1, y1] and of the distractors accepted before."""
    names, polygon = tuple(kinds or KINDS), np.asarray(walkable, dtype=np.float64)
    kind = (len(names) * rng.random(MAX_TRIES)).astype(np.intp)  # uniform, as rng.integers
    centre = rng.uniform(polygon.min(0), polygon.max(0), (MAX_TRIES, 2))
    yaw = rng.uniform(0.0, 2 * np.pi, MAX_TRIES)
    draw = rng.random((MAX_TRIES, 4))
    candidates = [_drawn(names[kind[c]], centre[c], yaw[c], draw[c]) for c in range(MAX_TRIES)]
    on_floor = points_in_polygon(np.stack([d.corners for d in candidates]), polygon).all(axis=1)
    centre_line = np.array([[[*d.centre, share * d.size[2]] for share in (0.0, 0.5, 1.0)] for d in candidates])
    in_view = in_field_of_view(centre_line.reshape(-1, 3), mount, get_pattern(pattern)).reshape(-1, 3).any(axis=1)
    taken, placed = np.asarray(obstacles, dtype=np.float64).reshape(-1, 4), []
    for candidate in np.flatnonzero(on_floor & in_view):
        if len(placed) >= count:
            break
        if not _overlaps(candidates[candidate].footprint, taken, CLEARANCE_M):
            placed.append(candidates[candidate])
            taken = np.vstack([taken, candidates[candidate].footprint])
    return placed


def frame_distractors(site: Site, seed: int, index: int, obstacles: np.ndarray) -> list[Distractor]:
    """The distractors of frame `index` of a background site with dataset seed `seed`: site.distractors (min, max)
    of site.distractor_kinds, clear of obstacles (O, 4), drawn from their own generator (a child of the frame's seed,
    spawn key DISTRACTOR_STREAM): a site without distractors draws nothing and its frames stay as they were."""
    if site.distractors[1] == 0:
        return []
    rng = np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(index, DISTRACTOR_STREAM)))
    count = int(rng.integers(site.distractors[0], site.distractors[1] + 1))
    return sample_distractors(rng, count, site.walkable, obstacles, site.viewpoints[0].mount, site.pattern,
                              site.distractor_kinds)


def cast_distractors(distractors: Sequence[Distractor], origin: np.ndarray, directions: np.ndarray,
                     threads: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest distractor hit of rays from origin (3,) along directions (R, 3) (ground frame): range (R,) [m]
    (inf: none), cos_incidence (R,) and reflectivity (R,) (0 where none)."""
    o3d = import_open3d()
    vertices, triangles, reflectivity = Scene("distractors", sum((d.surfaces() for d in distractors), ()),
                                              ()).triangles()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    t_hit, _, primitive, normal = cast_rays(scene, np.column_stack([np.broadcast_to(origin, directions.shape),
                                                                directions]), threads)
    hit = np.isfinite(t_hit)
    return (np.where(hit, t_hit.astype(np.float64), np.inf),
            np.where(hit, np.abs(np.einsum("ij,ij->i", normal, directions)), 0.0),
            np.where(hit, reflectivity[np.where(hit, primitive, 0)], 0.0))
