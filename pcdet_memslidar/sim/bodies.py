"""The body bank: articulated human bodies as rigid parts posed by per-part transforms.

assets/body_bank.npz (built by tools/research/build_body_bank.py from the anny body model) holds 12 adult body shapes,
4 mesh detail levels ('coarse' 734, 'medium' 1226, 'fine' 2454, 'full' 24540 triangles) and, per shape, one rigid
transform per body part for GAIT_PHASES phases of a walking cycle plus one standing pose. A pose between two
bank entries is a linear blend of their transforms (gait phase and walk <-> stand); the blend is near-rigid for
neighbouring phases (a few degrees apart).

Body frame: x forward (facing direction), y left, z up [m], origin on the ground below the pelvis.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull

from pcdet_memslidar.utils.compiled import kernel

BANK_PATH = Path(__file__).resolve().parents[1] / "assets" / "body_bank.npz"
LODS = ("coarse", "medium", "fine", "full")


@dataclass(frozen=True)
class BodyMesh:
    """One detail level: rest_vertices (S, V, 3) float32 in the body frame; triangles (T, 3) int64 vertex indices,
    each listed once per part it belongs to (triangle_part (T,)); triangle_material (T,) index into
    BodyBank.material_names."""

    rest_vertices: np.ndarray
    triangles: np.ndarray
    triangle_part: np.ndarray
    triangle_material: np.ndarray

    @functools.cached_property
    def part_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """(U,) vertex index and (U,) part of the (vertex, part) pairs that can bound a posed part: those on the
        convex hull of the part's rest vertices of some shape. A pose moves a part by an affine map, which keeps
        the extremes of the part among the images of these vertices, so boxes of posed bodies need no others."""
        vertex, part = [], []
        for index in np.unique(self.triangle_part):
            used = np.unique(self.triangles[self.triangle_part == index])
            hull = np.unique(np.concatenate([ConvexHull(rest[used]).vertices for rest in self.rest_vertices]))
            vertex.append(used[hull])
            part.append(np.full(len(hull), index))
        return np.concatenate(vertex), np.concatenate(part)

    @functools.cached_property
    def rest_part_vertices(self) -> np.ndarray:
        """(S, U, 3) float64 rest positions of the part_vertices of each shape."""
        return self.rest_vertices[:, self.part_vertices[0]].astype(np.float64)


@dataclass(frozen=True, eq=False)  # hashed by identity: body scenes are cached per bank
class BodyBank:
    """transforms (S, GAIT_PHASES + 1, parts, 3, 4): rest body frame -> posed body frame, the last pose standing."""

    part_names: tuple[str, ...]
    material_names: tuple[str, ...]
    shape_sex: tuple[str, ...]
    shape_stature_m: np.ndarray
    shape_build: tuple[str, ...]
    transforms: np.ndarray
    meshes: dict
    rigid_fit_error_m: np.ndarray

    @property
    def gait_phases(self) -> int:
        return self.transforms.shape[1] - 1

    @property
    def num_shapes(self) -> int:
        return self.transforms.shape[0]

    def stride_length(self, shape: np.ndarray) -> np.ndarray:
        """(n,) length [m] of one gait cycle (two steps) of body `shape`: 0.83 x stature (1.44 m at 1.74 m)."""
        return 0.83 * self.shape_stature_m[shape]

    @functools.cached_property
    def transform_rows(self) -> np.ndarray:
        """(12, S * (GAIT_PHASES + 1) * parts) all transforms as flattened 3x4 matrices [R | t] (row-major),
        component-major."""
        return np.ascontiguousarray(self.transforms.reshape(-1, 12).T)

    def part_transforms(self, shape: np.ndarray, phase: np.ndarray, walk_weight: np.ndarray) -> np.ndarray:
        """(12, n, parts) part transforms of n bodies as flattened 3x4 matrices [R | t] (row-major), component-major
        so that numpy loops run over the bodies.

        shape (n,) int; phase (n,) gait phase in cycles (any real, taken mod 1): the bank poses on either side,
        blended; walk_weight (n,) in [0, 1]: 1 = walking, 0 = standing."""
        shape = np.asarray(shape, dtype=np.int64)[:, None]
        cycle = np.mod(np.asarray(phase, dtype=np.float64), 1.0)[:, None] * self.gait_phases
        lower, blend = np.floor(cycle).astype(np.int64) % self.gait_phases, cycle - np.floor(cycle)
        weight = np.clip(np.asarray(walk_weight, dtype=np.float64), 0.0, 1.0)[:, None]
        parts = len(self.part_names)
        first = (shape * (self.gait_phases + 1)) * parts + np.arange(parts)  # column of pose 0 of each part

        def pose(index: np.ndarray) -> np.ndarray:
            return np.take(self.transform_rows, first + index * parts, axis=1)

        walking = (1.0 - blend) * pose(lower) + blend * pose((lower + 1) % self.gait_phases)
        return weight * walking + (1.0 - weight) * pose(np.full_like(lower, self.gait_phases))

    def posed_triangles(self, lod: str, shape: int, xy: np.ndarray, heading: float, phase: float,
                        walk_weight: float) -> np.ndarray:
        """(T, 3, 3) [m] the triangles of body `shape` at detail level `lod` in the ground frame: posed at gait
        `phase` [cycles] with `walk_weight`, turned to `heading` [rad] and standing at `xy` (2,) [m]."""
        transforms = self.part_transforms(np.array([shape]), np.array([phase]), np.array([walk_weight]))
        transforms = transforms[:, 0].T.reshape(-1, 3, 4)
        mesh = self.meshes[lod]
        rest = mesh.rest_vertices[shape][mesh.triangles].astype(np.float64)  # (T, 3, 3)
        t = transforms[mesh.triangle_part]  # (T, 3, 4)
        body = np.einsum("tij,tkj->tki", t[:, :, :3], rest) + t[:, None, :, 3]
        c, s = np.cos(heading), np.sin(heading)
        world = body @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        world[..., :2] += xy
        return world

    def posed_boxes(self, lod: str, shape: np.ndarray, transforms: np.ndarray) -> np.ndarray:
        """(n, 6) axis-aligned boxes [low xyz, high xyz] in the body frame of bodies `shape` (n,) posed by their
        part transforms (12, n, parts) (as `part_transforms` returns them)."""
        mesh = self.meshes[lod]
        return _posed_boxes(mesh.rest_part_vertices, mesh.part_vertices[1], np.asarray(shape, dtype=np.int64),
                            np.ascontiguousarray(transforms.transpose(1, 2, 0)))


@kernel
def _posed_boxes(rest, vertex_part, shape, transforms):
    """(n, 6) boxes of the vertices rest (S, U, 3) of parts vertex_part (U,) of bodies shape (n,) moved by their
    part transforms (n, parts, 12)."""
    boxes = np.empty((len(shape), 6))
    for i in range(len(shape)):
        boxes[i, :3], boxes[i, 3:] = np.inf, -np.inf
        for u in range(rest.shape[1]):
            t = transforms[i, vertex_part[u]]
            x, y, z = rest[shape[i], u, 0], rest[shape[i], u, 1], rest[shape[i], u, 2]
            for axis in range(3):
                value = t[4 * axis] * x + t[4 * axis + 1] * y + t[4 * axis + 2] * z + t[4 * axis + 3]
                boxes[i, axis] = min(boxes[i, axis], value)
                boxes[i, axis + 3] = max(boxes[i, axis + 3], value)
    return boxes


@functools.lru_cache(maxsize=None)
def load_body_bank(path: str | Path = BANK_PATH) -> BodyBank:
    """The body bank at `path` (default: the one shipped with the package), cached per process."""
    with np.load(path) as data:
        meshes = {lod: BodyMesh(rest_vertices=data[f"{lod}_rest_vertices"].astype(np.float32),
                                triangles=data[f"{lod}_triangles"].astype(np.int64),
                                triangle_part=data[f"{lod}_triangle_part"].astype(np.int64),
                                triangle_material=data[f"{lod}_triangle_material"].astype(np.int64))
                  for lod in LODS}
        return BodyBank(part_names=tuple(data["part_names"]), material_names=tuple(data["material_names"]),
                        shape_sex=tuple(data["shape_sex"]), shape_stature_m=data["shape_stature_m"].astype(np.float64),
                        shape_build=tuple(data["shape_build"]), transforms=data["transforms"].astype(np.float64),
                        meshes=meshes, rigid_fit_error_m=data["rigid_fit_error_m"])
