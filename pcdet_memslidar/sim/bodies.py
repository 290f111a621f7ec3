"""The body bank: articulated human bodies as rigid parts posed by per-part transforms.

assets/body_bank.npz (built by tools/build_body_bank.py from the anny body model) holds 12 adult body shapes,
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
        """(U,) vertex index and (U,) part of every distinct (vertex, part) pair of the part meshes."""
        pairs = np.unique(np.stack([self.triangles.ravel(), np.repeat(self.triangle_part, 3)], 1), axis=0)
        return pairs[:, 0], pairs[:, 1]


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

    def part_transforms(self, shape: np.ndarray, phase: np.ndarray, walk_weight: np.ndarray,
                        phase_steps: int | None = None, part: np.ndarray | None = None) -> np.ndarray:
        """Part transforms of n bodies: (n, parts, 3, 4), or (n, 3, 4) for one given part per body.

        shape (n,) int; phase (n,) gait phase in cycles (any real, taken mod 1); walk_weight (n,) in [0, 1]:
        1 = walking, 0 = standing. phase_steps: quantise the phase to that many steps per cycle (nearest bank
        entry) instead of blending neighbouring phases. part (n,) int: only that part of each body.
        """
        shape = np.asarray(shape, dtype=np.int64)
        cycle = np.mod(np.asarray(phase, dtype=np.float64), 1.0) * self.gait_phases
        if phase_steps is not None:
            step = self.gait_phases / phase_steps
            cycle = np.mod(np.round(cycle / step) * step, self.gait_phases)
        lower = np.floor(cycle).astype(np.int64) % self.gait_phases
        upper = (lower + 1) % self.gait_phases
        blend = cycle - np.floor(cycle)
        weight = np.clip(np.asarray(walk_weight, dtype=np.float64), 0.0, 1.0)
        stand = np.full_like(lower, self.gait_phases)
        index = (shape, lower), (shape, upper), (shape, stand)
        if part is not None:
            index = tuple(i + (np.asarray(part, dtype=np.int64),) for i in index)
        per_body = (slice(None),) + (None,) * (3 if part is None else 2)  # broadcast over (parts,) 3, 4
        blend, weight = blend[per_body], weight[per_body]
        return weight * ((1.0 - blend) * self.transforms[index[0]] + blend * self.transforms[index[1]]) + (
            1.0 - weight) * self.transforms[index[2]]

    def posed_vertices(self, lod: str, shape: int, transforms: np.ndarray) -> np.ndarray:
        """(U, 3) vertices of body `shape` posed by (parts, 3, 4) `transforms`, in the body frame."""
        mesh = self.meshes[lod]
        vertex, part = mesh.part_vertices
        rest = mesh.rest_vertices[shape, vertex]
        return np.einsum("nij,nj->ni", transforms[part, :, :3], rest) + transforms[part, :, 3]


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
