"""Ray casting of a MEMS scan pattern against a static world and moving, articulated people (Open3D).

How a frame is cast:
1. The static world is one RaycastingScene built once per viewpoint; all rays of the pattern are cast against it
   once and the hits are reused by every frame of that viewpoint (the world does not move).
2. People are not re-meshed per frame. Every body part of every bank shape sits, in its rest pose, in one shared
   RaycastingScene (the "body scene", each part at its own far-apart offset). The rays that can reach a person
   come from an angular index of the rays (time slices of SLICE_S, azimuth bins within each, elevation sorted
   within each bin). Each is moved into the person's body frame at the ray's own pulse time (trajectory),
   culled with boxes of the body and its parts, moved into the rest frame of each remaining part with the part's
   pose at that time (gait), which makes motion within the frame exact per pulse (time slicing with
   time_step_s > 0 quantises pulse times instead, for comparison), culled with the part's rest box, and cast
   against that part only: all people and parts in one cast_rays call. The per-ray loops are compiled
   (`body_rays`).
3. Per ray the nearest hit wins (static or any person).
With a beam divergence > 0, every pulse also casts 4 sub-rays at the edge of its footprint (two opposite pairs);
where a pair straddles a depth edge, its sub-ray farthest in range from the centre gives the second surface
(`edge_range`) for mixed pixels (recomputed per frame only for the pulses whose rays hit a person).
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.sim.bodies import BodyBank
from pcdet_memslidar.sim.body_rays import candidate_pairs, nearest_body_hits, part_rays
from pcdet_memslidar.sim.motion import TrajectoryStack
from pcdet_memslidar.sim.people import Person
from pcdet_memslidar.sim.scenes import Scene
from pcdet_memslidar.utils.open3d import import_open3d

SUBRAYS = 4  # sub-rays per pulse at the edge of the beam footprint (when the sensor has a beam divergence)
PART_SPACING_M = 300.0  # distance between body parts in the body scene: more than twice any cast range
MAX_BODY_RANGE_M = 120.0  # hits on a body part farther than this are foreign parts of the body scene
SLICE_S = 0.04  # s: the angular index is split into time slices of this length (a person moves < 8 cm in one)
AZIMUTH_BINS = 720  # bins of the angular ray index (0.5 deg)
EDGE_ASYMMETRY_M = 0.05  # opposite sub-rays whose range deviations cancel to within this see one smooth surface


@dataclass
class FrameHits:
    """Nearest hit of every pulse (P pulses): range (P,) [m] (inf = no hit); cos_incidence (P,); reflectivity (P,);
    person (P,) index of the person hit, -1 for the static world or none; edge_range (P,) [m] range of a second
    surface inside the footprint (nan = none), None without sub-rays; unoccluded (people,) pulses that would hit
    each person if nothing else were in the way; cast_seconds: time spent inside Open3D's cast_rays."""

    range: np.ndarray
    cos_incidence: np.ndarray
    reflectivity: np.ndarray
    person: np.ndarray
    edge_range: np.ndarray | None
    unoccluded: np.ndarray
    cast_seconds: float


def _subray_directions(directions: np.ndarray, divergence_rad: float) -> np.ndarray:
    """(SUBRAYS, P, 3) unit directions at half the divergence angle around each (P, 3) beam direction."""
    side = np.cross(directions, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    up = np.cross(side, directions)
    spread = np.tan(divergence_rad / 2)
    subrays = np.stack([directions + spread * side, directions - spread * side,
                        directions + spread * up, directions - spread * up])
    return subrays / np.linalg.norm(subrays, axis=2, keepdims=True)


def cast_rays(scene, rays: np.ndarray, threads: int):
    """Cast rays (n, 6) [origin, direction] against an Open3D RaycastingScene; returns numpy t_hit (n,) float32,
    geometry ids (n,) uint32, primitive ids (n,) uint32, normals (n, 3) float32."""
    o3d = import_open3d()
    result = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)), nthreads=threads)
    return (result["t_hit"].numpy(), result["geometry_ids"].numpy(), result["primitive_ids"].numpy(),
            result["primitive_normals"].numpy())


@dataclass(frozen=True)
class BodyScene:
    """All (shape, part) rest meshes of one detail level in one RaycastingScene, and boxes that cull rays.

    Geometry g = shape * parts + part sits at offset[g] (G, 3) in the scene; the material index of its triangle k
    is material[material_start[g] + k]. Boxes are (..., 6) [low xyz, high xyz] (as in `body_rays`): rest_box
    (S, parts, 6) each part in its rest frame; in the body frame, part_box (3, S, GAIT_PHASES, parts, 6) of each
    part over the gait poses l and (l + 1) % GAIT_PHASES blended with the standing pose ([0] standing only, [1] any
    walk weight, [2] walking only) and body_box (3, S, GAIT_PHASES, 6) of the whole body likewise (a blend of bank
    poses stays in the convex hull of the blended poses, so in the union of their boxes); reach (S,) [m] the
    farthest any posed body reaches horizontally from its body-frame origin, height (S,) [m] its top (a blend
    moves each vertex inside the convex hull of its bank positions, so these bound every blended pose too)."""

    scene: object
    offset: np.ndarray
    material: np.ndarray
    material_start: np.ndarray
    rest_box: np.ndarray
    part_box: np.ndarray
    body_box: np.ndarray
    reach: np.ndarray
    height: np.ndarray


@functools.lru_cache(maxsize=None)
def body_scene(bank: BodyBank, lod: str) -> BodyScene:
    """The body scene of `bank` at detail level `lod`, built once per process."""
    o3d = import_open3d()
    mesh = bank.meshes[lod]
    shapes, parts, gait = bank.num_shapes, len(bank.part_names), bank.gait_phases
    scene = o3d.t.geometry.RaycastingScene()
    side = int(np.ceil((shapes * parts) ** (1 / 3)))
    offset = np.zeros((shapes * parts, 3))
    rest_box = np.zeros((shapes, parts, 6))
    posed_box = np.zeros((shapes, gait + 1, parts, 6))
    reach = np.zeros(shapes)
    vertex, vertex_part = mesh.part_vertices
    materials = []
    for shape in range(shapes):
        for part in range(parts):
            g = shape * parts + part
            offset[g] = PART_SPACING_M * np.array([g % side, (g // side) % side, g // side ** 2])
            triangles = mesh.triangles[mesh.triangle_part == part]
            used, local = np.unique(triangles, return_inverse=True)
            vertices = mesh.rest_vertices[shape, used].astype(np.float64)
            geometry = scene.add_triangles(o3d.core.Tensor((vertices + offset[g]).astype(np.float32)),
                                           o3d.core.Tensor(local.reshape(-1, 3).astype(np.uint32)))
            assert geometry == g, "Open3D numbers geometries in the order they are added"
            materials.append(mesh.triangle_material[mesh.triangle_part == part])
            rest_box[shape, part] = np.concatenate([vertices.min(0), vertices.max(0)])
            rest = mesh.rest_vertices[shape, vertex[vertex_part == part]].astype(np.float64)
            transform = bank.transforms[shape, :, part]  # (poses, 3, 4)
            posed = np.einsum("pij,vj->pvi", transform[:, :, :3], rest) + transform[:, None, :, 3]
            posed_box[shape, :, part] = np.concatenate([posed.min(1), posed.max(1)], axis=1)
            reach[shape] = max(reach[shape], np.hypot(posed[..., 0], posed[..., 1]).max())
    material_start = np.cumsum([0] + [len(m) for m in materials[:-1]])
    cast_rays(scene, np.array([[0.0, 0.0, -1.0, 0.0, 0.0, 1.0]]), 1)  # Open3D builds the BVH on the first cast: here,
    # not in two threads casting at once
    walking = _union(np.stack([posed_box[:, :gait], np.roll(posed_box[:, :gait], -1, axis=1)]), axis=0)
    standing = np.broadcast_to(posed_box[:, gait:], walking.shape)
    part_box = np.stack([standing, _union(np.stack([walking, standing]), axis=0), walking])  # (3, S, G, parts, 6)
    return BodyScene(scene, offset, np.concatenate(materials), material_start, rest_box=rest_box, part_box=part_box,
                     body_box=_union(part_box, axis=3), reach=reach, height=posed_box[..., 5].max((1, 2)))


def _union(boxes: np.ndarray, axis: int) -> np.ndarray:
    """The boxes (..., 6) bounding all boxes along `axis`."""
    return np.concatenate([boxes[..., :3].min(axis), boxes[..., 3:].max(axis)], axis=-1)


class Caster:
    """Casts one scan pattern from one viewpoint; build once, then call cast_frame per frame.

    scene: the static world, or (P,) ranges [m] of a background recording's returns along the pulses (inf: none),
    which people hide where they are nearer; directions (P, 3) unit pulse directions in the sensor frame,
    time_offset (P,) [s]; beam_divergence_rad > 0 adds sub-rays; threads: Open3D threads per cast (0 = all cores)."""

    def __init__(self, scene: Scene | np.ndarray, mount: Mount, directions: np.ndarray, time_offset: np.ndarray,
                 frame_period_s: float, bank: BodyBank, lod: str = "fine", beam_divergence_rad: float = 0.0,
                 threads: int = 0):
        o3d = import_open3d()
        self.bank, self.lod, self.threads = bank, lod, threads
        self.bodies = body_scene(bank, lod)
        self.frame_period_s = frame_period_s
        self.origin = mount.origin
        self.pulse_directions = mount.directions_to_ground(directions)
        self.pulses = len(self.pulse_directions)
        rays = [self.pulse_directions]
        if beam_divergence_rad > 0:
            rays.extend(_subray_directions(self.pulse_directions, beam_divergence_rad))
        self.directions = np.concatenate(rays)  # (R, 3), R = P or P * (1 + SUBRAYS); pulse of ray r = r % P
        self.time_offset = np.tile(np.asarray(time_offset, dtype=np.float64), len(rays))
        self.has_subrays = len(rays) > 1

        if isinstance(scene, Scene):
            self._cast_static(scene, o3d, threads)
        else:  # a background recording: each pulse's real return; its footprint sees the same surface
            self.static_range = np.tile(np.asarray(scene, dtype=np.float64), len(rays))  # (R,)
            self.static_cos = self.static_ray_reflectivity = np.zeros(self.pulses)
            self.static_edge_range = np.full(self.pulses, np.nan) if self.has_subrays else None
        # angular index: rays sorted by time slice, azimuth bin, then elevation;
        # key = slice * AZIMUTH_BINS + azimuth bin + 0.5 + elevation / 4
        ray_slice = np.minimum(np.floor(self.time_offset / SLICE_S), np.ceil(frame_period_s / SLICE_S) - 1)
        self.slice_times = np.array([[self.time_offset[ray_slice == j].min(), self.time_offset[ray_slice == j].max()]
                                     for j in range(int(ray_slice.max()) + 1)]).T  # (2, J) first and last pulse
        azimuth = np.arctan2(self.directions[:, 1], self.directions[:, 0])
        azimuth_bin = np.minimum(np.floor((azimuth + np.pi) / (2 * np.pi / AZIMUTH_BINS)), AZIMUTH_BINS - 1)
        key = ray_slice * AZIMUTH_BINS + azimuth_bin + 0.5 + np.arcsin(np.clip(self.directions[:, 2], -1.0, 1.0)) / 4
        self.angular_order = np.argsort(key, kind="stable")
        self.angular_key = key[self.angular_order]
        self.cell_start = np.searchsorted(self.angular_key, np.arange(self.slice_times.shape[1] * AZIMUTH_BINS + 1))

    def _cast_static(self, scene: Scene, o3d, threads: int) -> None:
        """Cast every ray against the static world once: range (R,), cosine, reflectivity and edge range (P,)."""
        vertices, triangles, reflectivity = scene.triangles()
        static_scene = o3d.t.geometry.RaycastingScene()
        static_scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
        t_hit, _, primitive, normal = cast_rays(
            static_scene, np.column_stack([np.broadcast_to(self.origin, self.directions.shape), self.directions]),
            threads)
        hit = np.isfinite(t_hit)
        self.static_range = np.where(hit, t_hit.astype(np.float64), np.inf)  # (R,)
        hit, normal, primitive = hit[:self.pulses], normal[:self.pulses], primitive[:self.pulses]
        self.static_cos = np.where(hit, np.abs(np.einsum("ij,ij->i", normal, self.pulse_directions)), 0.0)  # (P,)
        self.static_ray_reflectivity = np.where(hit, reflectivity[np.where(hit, primitive, 0)], 0.0)
        self.static_edge_range = (self.edge_range(self.static_range, np.arange(self.pulses)) if self.has_subrays
                                  else None)

    def cast_frame(self, people: list[Person], time_step_s: float = 0.0,
                   phase_steps: int | None = None) -> FrameHits:
        """Nearest hits of all pulses with `people` in the world.

        time_step_s: 0 = each pulse sees the people at its own time; > 0 = pulse times rounded to the middle of
        slices of that length (frame_period_s: one instant for the whole frame). phase_steps: gait phases a body
        can take (None = continuous)."""
        p = self.pulses
        ray_range, cos = self.static_range.copy(), self.static_cos.copy()
        reflectivity, person_hit = self.static_ray_reflectivity.copy(), np.full(p, -1)
        edge_range = self.static_edge_range.copy() if self.has_subrays else None
        unoccluded = np.zeros(len(people), dtype=np.int64)
        if not people:
            return FrameHits(ray_range[:p], cos, reflectivity, person_hit, edge_range, unoccluded, 0.0)
        # the candidate rays of every person, each moved into the rest frames of the body parts it can reach
        bodies = self.bodies
        trajectories = TrajectoryStack.of([someone.trajectory for someone in people])
        shape = np.array([someone.shape for someone in people])
        ray, person = candidate_pairs(_pose_time(self.slice_times, time_step_s), trajectories.times,
                                      trajectories.samples, bodies.reach[shape], bodies.height[shape], self.origin,
                                      self.angular_key, self.angular_order, self.cell_start, AZIMUTH_BINS)
        heading = trajectories.samples[2]
        pair, geometry, rays = part_rays(
            ray, person, _pose_time(self.time_offset.take(ray), time_step_s), self.origin, self.directions,
            trajectories.times, trajectories.samples, np.cos(heading), np.sin(heading), shape, phase_steps or 0,
            self.bank.transforms.reshape(*self.bank.transforms.shape[:3], 12), bodies.body_box, bodies.part_box,
            bodies.rest_box, bodies.offset)
        start = time.perf_counter()
        t_hit, hit_geometry, primitive, normal = cast_rays(bodies.scene, rays, self.threads)
        cast_seconds = time.perf_counter() - start
        changed = np.zeros(p, dtype=bool)
        nearest_body_hits(pair, geometry, rays, t_hit, hit_geometry, primitive, normal, ray, person, p,
                          MAX_BODY_RANGE_M, bodies.material, bodies.material_start,
                          np.array([someone.reflectivity for someone in people]), ray_range, cos, reflectivity,
                          person_hit, unoccluded, changed)
        if self.has_subrays:
            changed = np.flatnonzero(changed)
            edge_range[changed] = self.edge_range(ray_range, changed)
        return FrameHits(ray_range[:p], cos, reflectivity, person_hit, edge_range, unoccluded, cast_seconds)

    def edge_range(self, ray_range: np.ndarray, pulse: np.ndarray) -> np.ndarray:
        """(n,) range of a second surface inside the footprint of pulses `pulse` (n,), nan where the footprint
        sees one smooth surface. Opposite sub-rays on a smooth surface deviate symmetrically from the centre (a
        tilted plane spreads the footprint's ranges, it does not shift them); a pair that does not is an edge, and
        its sub-ray farthest from the centre range gives the second surface."""
        centre = ray_range[pulse]
        sub = ray_range[pulse + self.pulses * np.arange(1, SUBRAYS + 1)[:, None]].reshape(SUBRAYS // 2, 2, len(pulse))
        both = np.isfinite(sub) & np.isfinite(centre)
        deviation = np.subtract(sub, centre, where=both, out=np.zeros_like(sub))
        smooth = both.all(axis=1) & (np.abs(deviation.sum(axis=1)) <= EDGE_ASYMMETRY_M)
        eligible = both & ~smooth[:, None, :] & (np.abs(deviation) > EDGE_ASYMMETRY_M)
        score = np.where(eligible, np.abs(deviation), -1.0).reshape(SUBRAYS, len(pulse))
        pick = np.argmax(score, axis=0)
        columns = np.arange(len(pulse))
        return np.where(score[pick, columns] > 0, sub.reshape(SUBRAYS, len(pulse))[pick, columns], np.nan)


def _pose_time(pulse_time: np.ndarray, time_step_s: float) -> np.ndarray:
    """The times [s] at which pulses sent at `pulse_time` see the people: their own (time_step_s = 0), else the
    middle of their slice of length time_step_s."""
    if time_step_s > 0:
        return (np.floor(pulse_time / time_step_s) + 0.5) * time_step_s
    return pulse_time

