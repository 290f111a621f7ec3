"""Static worlds: three public street crossings, a park pathway, an industrial entrance, and scenes that site
files build from primitives.

Every world is built in the normalised ground frame (origin on the ground below the sensor, x forward, y left,
z up, metres) from boxes and prisms, each surface with a near-infrared (905 nm) reflectivity in [0, 1]. Solid
objects also give footprints that people walk around.

Public API: get_scene(name | SceneSpec) -> Scene; SCENES (bundled names); MATERIALS (name -> reflectivity);
PRIMITIVES (kind -> World method); Scene.triangles() -> (vertices, triangles, reflectivity);
World: builder of new scenes (box, patch, wall, prism, rack, tree, pole, car, bench, zebra; .surfaces).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from pcdet_memslidar.errors import ConfigError

# near-infrared reflectivities of the materials used below
ASPHALT, CONCRETE, PAINT, GRASS, BARK, FOLIAGE, BRICK, METAL, GLASS, CAR, WOOD, PLASTIC = (
    0.12, 0.30, 0.60, 0.45, 0.30, 0.50, 0.35, 0.40, 0.08, 0.25, 0.40, 0.20)
MATERIALS = dict(asphalt=ASPHALT, concrete=CONCRETE, paint=PAINT, grass=GRASS, bark=BARK, foliage=FOLIAGE,
                 brick=BRICK, metal=METAL, glass=GLASS, car=CAR, wood=WOOD, plastic=PLASTIC)

_BOX_TRIANGLES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                           [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


@dataclass(frozen=True)
class Surface:
    """One mesh: vertices (n, 3) [m], triangles (m, 3), reflectivity in [0, 1]; solid surfaces block walking."""

    vertices: np.ndarray
    triangles: np.ndarray
    reflectivity: float
    solid: bool


@dataclass(frozen=True)
class Scene:
    """A static world: surfaces; walk_headings [rad], the typical walking directions (along paths, across
    crossings); walk_x_max [m], how far from the sensor people are placed; obstacles (O, 4) [x0, y0, x1, y1]
    footprints people walk around (default: those of the solid surfaces)."""

    name: str
    surfaces: tuple[Surface, ...]
    walk_headings: tuple[float, ...]
    walk_x_max: float = 28.0
    obstacles: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self):
        if self.obstacles is None:
            footprints = [np.concatenate([s.vertices[:, :2].min(0), s.vertices[:, :2].max(0)])
                          for s in self.surfaces if s.solid]
            object.__setattr__(self, "obstacles", np.array(footprints, dtype=np.float64).reshape(-1, 4))

    def triangles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All surfaces merged: vertices (V, 3) float32, triangles (T, 3) uint32, reflectivity (T,) float32."""
        offsets = np.cumsum([0] + [len(s.vertices) for s in self.surfaces])
        vertices = np.concatenate([s.vertices for s in self.surfaces]).astype(np.float32)
        triangles = np.concatenate([s.triangles + o for s, o in zip(self.surfaces, offsets)]).astype(np.uint32)
        reflectivity = np.concatenate([np.full(len(s.triangles), s.reflectivity) for s in self.surfaces])
        return vertices, triangles, reflectivity.astype(np.float32)


class World:
    """Collects surfaces; every helper takes sizes in m and angles in rad."""

    def __init__(self):
        self.surfaces: list[Surface] = []

    def box(self, centre_xy, size, reflectivity, z0=0.0, yaw=0.0, solid=True):
        """A cuboid of size (dx, dy, dz) standing on height z0 at centre_xy, rotated by yaw."""
        dx, dy, dz = size
        corners = np.array([[-dx, -dy], [dx, -dy], [dx, dy], [-dx, dy]]) / 2
        c, s = np.cos(yaw), np.sin(yaw)
        corners = corners @ np.array([[c, s], [-s, c]]) + np.asarray(centre_xy, dtype=np.float64)
        vertices = np.concatenate([np.c_[corners, np.full(4, z0)], np.c_[corners, np.full(4, z0 + dz)]])
        self.surfaces.append(Surface(vertices, _BOX_TRIANGLES.copy(), reflectivity, solid))

    def patch(self, x_range, y_range, reflectivity, height=0.0):
        """A flat rectangle of ground (height 0) or of floor marking (a few mm above the ground)."""
        if height == 0.0:
            (x0, x1), (y0, y1) = x_range, y_range
            vertices = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
            self.surfaces.append(Surface(vertices, np.array([[0, 1, 2], [0, 2, 3]]), reflectivity, False))
        else:
            centre = [(x_range[0] + x_range[1]) / 2, (y_range[0] + y_range[1]) / 2]
            self.box(centre, (x_range[1] - x_range[0], y_range[1] - y_range[0], height), reflectivity, solid=False)

    def wall(self, start_xy, end_xy, height, reflectivity=CONCRETE, thickness=0.2, z0=0.0):
        """A wall of `thickness` from start_xy to end_xy (its centre line), `height` high from z0."""
        start, end = np.asarray(start_xy, dtype=np.float64), np.asarray(end_xy, dtype=np.float64)
        along = end - start
        self.box((start + end) / 2, (np.hypot(*along), thickness, height), reflectivity, z0=z0,
                 yaw=float(np.arctan2(along[1], along[0])))

    def rack(self, centre_xy, length, depth=1.1, height=4.5, levels=(0.1, 1.5, 3.0), yaw=0.0, bay=2.7):
        """A pallet rack along its length: metal uprights every `bay` m, shelves at `levels` [m] with a loaded
        pallet (wood) in each bay."""
        centre, c, s = np.asarray(centre_xy, dtype=np.float64), np.cos(yaw), np.sin(yaw)
        bays = max(1, int(round(length / bay)))
        for k in range(bays + 1):
            self.box(centre + (k / bays - 0.5) * length * np.array([c, s]), (0.1, depth, height), METAL, yaw=yaw)
        for z in levels:
            self.box(centre, (length, depth, 0.08), METAL, z0=z, yaw=yaw, solid=False)
            for k in range(bays):
                at = centre + ((k + 0.5) / bays - 0.5) * length * np.array([c, s])
                self.box(at, (min(1.2, length / bays), 0.8 * depth, 0.9), WOOD, z0=z + 0.08, yaw=yaw, solid=False)

    def prism(self, centre_xy, radius, height, reflectivity, z0=0.0, sides=8, solid=True):
        """A vertical `sides`-gon prism (poles, trunks, bins)."""
        angle = np.arange(sides) * 2 * np.pi / sides
        ring = np.c_[radius * np.cos(angle), radius * np.sin(angle)] + np.asarray(centre_xy, dtype=np.float64)
        vertices = np.concatenate([np.c_[ring, np.full(sides, z0)], np.c_[ring, np.full(sides, z0 + height)],
                                   [[*centre_xy, z0], [*centre_xy, z0 + height]]])
        k = np.arange(sides)
        n = (k + 1) % sides
        triangles = np.concatenate([np.c_[k, n, sides + n], np.c_[k, sides + n, sides + k],
                                    np.c_[np.full(sides, 2 * sides), n, k],
                                    np.c_[np.full(sides, 2 * sides + 1), sides + k, sides + n]])
        self.surfaces.append(Surface(vertices, triangles, reflectivity, solid))

    def tree(self, xy):
        self.prism(xy, 0.18, 3.0, BARK)
        self.prism(xy, 1.6, 3.0, FOLIAGE, z0=2.8, sides=10, solid=False)

    def pole(self, xy, height=4.0):
        self.prism(xy, 0.06, height, METAL, sides=6)

    def car(self, xy, yaw):
        self.box(xy, (4.3, 1.8, 0.8), CAR, z0=0.3, yaw=yaw)
        self.box(xy, (2.2, 1.6, 0.6), GLASS, z0=1.1, yaw=yaw)

    def bench(self, xy, yaw):
        self.box(xy, (1.8, 0.5, 0.45), WOOD, yaw=yaw)

    def zebra(self, x_range, y_range, along_x: bool):
        """Crosswalk stripes 0.5 m wide, 0.5 m apart, long along the walking direction."""
        if along_x:
            for y in np.arange(y_range[0], y_range[1], 1.0):
                self.patch(x_range, (y, y + 0.5), PAINT, height=0.003)
        else:
            for x in np.arange(x_range[0], x_range[1], 1.0):
                self.patch((x, x + 0.5), y_range, PAINT, height=0.003)


def _crossing_across() -> Scene:
    """A street crossing the view (along y) at 11-18 m with a zebra crossing straight ahead."""
    w = World()
    w.patch((-5, 11), (-60, 60), CONCRETE)
    w.patch((11, 18), (-60, 60), ASPHALT)
    w.patch((18, 80), (-60, 60), CONCRETE)
    w.zebra((11, 18), (-3, 3), along_x=True)
    w.box((24, 0), (1.0, 60, 9), BRICK)
    for y in (-4, 4):
        w.pole((10.6, y), 3.5)
        w.pole((18.4, y), 3.5)
    w.car((13, -10), np.pi / 2)
    w.car((16, 11), np.pi / 2 + 0.05)
    w.bench((20.5, 7), np.pi / 2)
    w.prism((20.5, -6), 0.3, 1.0, PLASTIC)
    return Scene("crossing_across", tuple(w.surfaces), (0.0, np.pi, np.pi / 2, -np.pi / 2))


def _crossing_ahead() -> Scene:
    """A street running away from the sensor (along x) with a zebra crossing across it at 14-18 m."""
    w = World()
    w.patch((-5, 80), (-4, 4), ASPHALT)
    w.patch((-5, 80), (4, 60), CONCRETE)
    w.patch((-5, 80), (-60, -4), CONCRETE)
    w.zebra((14, 18), (-4, 4), along_x=False)
    for side in (-1, 1):
        w.box((35, side * 10), (60, 1.0, 10), BRICK)
        w.pole((12, side * 4.4), 3.5)
        w.pole((20, side * 4.4), 3.5)
    w.car((24, -2.2), 0.0)
    w.car((30, 2.2), np.pi)
    w.prism((9, 6), 0.3, 1.0, PLASTIC)
    return Scene("crossing_ahead", tuple(w.surfaces), (np.pi / 2, -np.pi / 2, 0.0, np.pi))


def _intersection() -> Scene:
    """Two streets crossing at 12-18 m, crosswalks over both, buildings on the far corners."""
    w = World()
    w.patch((-5, 12), (-60, -3), CONCRETE)
    w.patch((-5, 12), (3, 60), CONCRETE)
    w.patch((18, 80), (-60, -3), CONCRETE)
    w.patch((18, 80), (3, 60), CONCRETE)
    w.patch((-5, 80), (-3, 3), ASPHALT)
    w.patch((12, 18), (-60, -3), ASPHALT)
    w.patch((12, 18), (3, 60), ASPHALT)
    w.zebra((12, 18), (4, 8), along_x=True)
    w.zebra((9, 12), (-3, 3), along_x=False)
    for side in (-1, 1):
        w.box((30, side * 16), (18, 18, 12), BRICK)
        w.pole((11.6, side * 3.4), 3.5)
        w.pole((18.4, side * 3.4), 3.5)
    w.car((15, -12), np.pi / 2)
    w.bench((7, -6), 0.0)
    return Scene("intersection", tuple(w.surfaces), (0.0, np.pi / 2, np.pi, -np.pi / 2))


def _pathway() -> Scene:
    """A park path running away from the sensor, a side path at 30 deg, trees, benches and lamp posts."""
    w = World()
    w.patch((-5, 80), (-60, -1.5), GRASS)
    w.patch((-5, 80), (1.5, 60), GRASS)
    w.patch((-5, 80), (-1.5, 1.5), CONCRETE)
    for x, y in ((9, 5), (13, -6), (18, 7), (22, -4), (27, 9), (31, -8), (12, 12), (20, -12)):
        w.tree((x, y))
    for x in (10, 20, 30):
        w.pole((x, 2.0), 4.5)
    w.bench((15, 2.3), 0.0)
    w.bench((24, -2.3), 0.0)
    return Scene("pathway", tuple(w.surfaces), (0.0, np.pi, np.pi / 6, np.pi + np.pi / 6))


def _industrial_entrance() -> Scene:
    """The entrance area of a factory hall: back wall with a roller door and a personnel door, side walls,
    machines, a rack with pallets, pallet stacks, a forklift, pillars and painted walkway lines."""
    w = World()
    w.patch((-5, 60), (-20, 20), CONCRETE)
    w.patch((-5, 24), (-1.6, -1.5), PAINT, height=0.003)
    w.patch((-5, 24), (1.5, 1.6), PAINT, height=0.003)
    # back wall at x = 24 with a 4 m roller door (y -6..-2, open) and a 1.2 m personnel door (y 3..4.2, ajar)
    for y0, y1 in ((-20, -6), (-2, 3), (4.2, 20)):
        w.box((24.2, (y0 + y1) / 2), (0.4, y1 - y0, 6), CONCRETE)
    w.box((24.2, -4), (0.4, 4, 2.0), METAL, z0=4.0)  # rolled-up door above the opening
    w.box((24.2, 0.5), (0.4, 5, 3.8), METAL, z0=2.2, solid=False)  # lintel above the inner wall part
    w.box((23.6, 3.3), (1.1, 0.05, 2.1), METAL, yaw=np.deg2rad(60))  # personnel door leaf, open
    w.box((40, 0), (0.5, 40, 8), CONCRETE)  # inside the hall, seen through the doors
    for side in (-1, 1):
        w.box((10, side * 14.2), (28, 0.4, 6), CONCRETE)
        w.box((12, side * 10.5), (0.4, 0.4, 6), CONCRETE)
        w.box((20, side * 10.5), (0.4, 0.4, 6), CONCRETE)
    w.box((10, 7), (2.5, 1.5, 2.0), METAL)
    w.box((15, 8), (3.0, 2.0, 2.4), METAL)
    w.box((15, 8), (1.0, 1.0, 0.6), METAL, z0=2.4)
    # rack along the right wall: uprights and shelves with pallets
    for x in (6.0, 8.7, 11.4, 14.1):
        w.box((x, -12.5), (0.1, 1.1, 4.5), METAL)
    for z in (0.1, 1.5, 3.0):
        w.box((10.05, -12.5), (8.2, 1.1, 0.08), METAL, z0=z, solid=False)
        for x in (7.35, 10.05, 12.75):
            w.box((x, -12.5), (1.2, 0.8, 0.9), WOOD, z0=z + 0.08, solid=False)
    for x, y, layers in ((9, -6.5, 3), (10.5, -6.5, 1), (12.5, -8, 2)):
        w.box((x, y), (1.2, 0.8, 0.15 * layers), WOOD)
        w.box((x, y), (1.1, 0.7, 0.8), PLASTIC, z0=0.15 * layers)
    # forklift: body, counterweight, mast and forks
    yaw = np.deg2rad(20)
    w.box((17, -4), (2.2, 1.1, 1.2), PAINT, z0=0.2, yaw=yaw)
    w.box((17, -4), (1.0, 1.0, 1.0), METAL, z0=1.4, yaw=yaw, solid=False)
    mast = np.array([17, -4]) + 1.2 * np.array([np.cos(yaw), np.sin(yaw)])
    w.box(mast, (0.15, 0.9, 2.4), METAL, yaw=yaw)
    w.box(mast + 0.6 * np.array([np.cos(yaw), np.sin(yaw)]), (1.1, 0.8, 0.05), METAL, z0=0.1, yaw=yaw)
    return Scene("industrial_entrance", tuple(w.surfaces), (0.0, np.pi, np.pi / 2, -np.pi / 2), walk_x_max=23.0)


_BUILDERS = {"crossing_across": _crossing_across, "crossing_ahead": _crossing_ahead,
             "intersection": _intersection, "pathway": _pathway, "industrial_entrance": _industrial_entrance}
SCENES = tuple(_BUILDERS)
# primitive kind of a site file -> (World method, its parameters: required, then optional); a `material` parameter
# takes a name of MATERIALS or a reflectivity in [0, 1]; angles in deg
PRIMITIVES = {
    "patch": ("patch", ("x", "y", "material"), ("height",)),
    "box": ("box", ("centre", "size", "material"), ("z0", "yaw_deg", "solid")),
    "machine": ("box", ("centre", "size"), ("material", "z0", "yaw_deg")),
    "wall": ("wall", ("start", "end", "height"), ("material", "thickness", "z0")),
    "pillar": ("prism", ("centre", "radius", "height"), ("material", "sides")),
    "rack": ("rack", ("centre", "length"), ("depth", "height", "levels", "yaw_deg", "bay")),
}
_PARAMETERS = dict(x="x_range", y="y_range", centre="centre_xy", start="start_xy", end="end_xy",
                   material="reflectivity", yaw_deg="yaw")


@dataclass(frozen=True)
class SceneSpec:
    """A scene of a site file: an optional bundled `base` scene, then primitives, each (kind, ((parameter,
    value), ...)) with values as the file gives them (lists as tuples); walk_headings_deg and walk_x_max [m] (None:
    the base scene's, or eight directions and 40 m)."""

    name: str
    base: str | None = None
    primitives: tuple[tuple[str, tuple], ...] = ()
    walk_headings_deg: tuple[float, ...] | None = None
    walk_x_max: float | None = None


def _build(spec: SceneSpec) -> Scene:
    """The Scene of a site file's scene spec."""
    base = get_scene(spec.base) if spec.base else None
    world = World()
    world.surfaces = list(base.surfaces) if base else []
    for kind, parameters in spec.primitives:
        method, _, _ = PRIMITIVES[kind]
        arguments = {_PARAMETERS.get(key, key): value for key, value in parameters}
        if kind == "machine":
            arguments.setdefault("reflectivity", "metal")
        if "reflectivity" in arguments and isinstance(arguments["reflectivity"], str):
            arguments["reflectivity"] = MATERIALS[arguments["reflectivity"]]
        if "yaw" in arguments:
            arguments["yaw"] = float(np.deg2rad(arguments["yaw"]))
        getattr(world, method)(**arguments)
    headings = (tuple(np.deg2rad(spec.walk_headings_deg)) if spec.walk_headings_deg is not None
                else base.walk_headings if base else tuple(np.arange(8) * np.pi / 4))
    walk_x_max = spec.walk_x_max if spec.walk_x_max is not None else base.walk_x_max if base else 40.0
    return Scene(spec.name, tuple(world.surfaces), tuple(float(h) for h in headings), float(walk_x_max))


@functools.lru_cache(maxsize=None)
def get_scene(scene: str | SceneSpec) -> Scene:
    """The static world `scene`: a bundled name (one of SCENES) or a site file's SceneSpec."""
    if isinstance(scene, SceneSpec):
        return _build(scene)
    if scene not in _BUILDERS:
        raise ConfigError(f"unknown scene '{scene}': choose one of {list(SCENES)}")
    return _BUILDERS[scene]()


def scene_name(scene: str | SceneSpec) -> str:
    """The name a frame's metadata gives its scene."""
    return scene.name if isinstance(scene, SceneSpec) else scene
