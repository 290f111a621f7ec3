"""Ray casting of a MEMS scan pattern against a static world and moving, articulated people (Open3D).

How a frame is cast:
1. The static world is one RaycastingScene built once per viewpoint; all rays of the pattern are cast against it
   once and the hits are reused by every frame of that viewpoint (the world does not move).
2. People are not re-meshed per frame. Every body part of every bank shape sits, in its rest pose, in one shared
   RaycastingScene (the "body scene", each part at its own far-apart offset). A person only receives the rays
   inside its angular bounds (azimuth window, then a bounding-sphere test around its path during the frame).
   Each such ray is moved into the rest frame of each body part with the part's pose at the ray's own pulse time
   (trajectory + gait), which makes motion within the frame exact per pulse (time slicing with time_step_s > 0
   quantises pulse times instead, for comparison), and is cast against that part only.
3. Per ray the nearest hit wins (static or any person).
With a beam divergence > 0, every pulse also casts 4 sub-rays at the edge of its footprint (two opposite pairs);
where a pair straddles a depth edge, its sub-ray farthest in range from the centre gives the second surface
(`edge_range`) for mixed pixels.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.sim.bodies import BodyBank
from pcdet_memslidar.sim.people import Person
from pcdet_memslidar.sim.scenes import Scene
from pcdet_memslidar.utils.open3d import import_open3d

SUBRAYS = 4  # sub-rays per pulse at the edge of the beam footprint (when the sensor has a beam divergence)
BODY_REACH_M = 0.75  # horizontal reach of a body around its trajectory point (stride, arms)
BODY_HEIGHT_M = 2.0  # height of the bounding volume of a body
PART_SPACING_M = 300.0  # distance between body parts in the body scene: more than twice any cast range
MAX_BODY_RANGE_M = 120.0  # hits on a body part farther than this are foreign parts of the body scene
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


def _cast(scene, origins: np.ndarray, directions: np.ndarray, threads: int):
    """Cast rays (n, 3) + (n, 3) against an Open3D RaycastingScene; returns numpy t_hit, geometry ids, primitive
    ids, normals."""
    o3d = import_open3d()
    rays = o3d.core.Tensor(np.concatenate([origins, directions], axis=1).astype(np.float32))
    result = scene.cast_rays(rays, nthreads=threads)
    return (result["t_hit"].numpy().astype(np.float64), result["geometry_ids"].numpy().astype(np.int64),
            result["primitive_ids"].numpy().astype(np.int64), result["primitive_normals"].numpy().astype(np.float64))


@dataclass(frozen=True)
class BodyScene:
    """All (shape, part) rest meshes of one detail level in one RaycastingScene.

    geometry id g = shape * parts + part sits at offset[g]; centre (G, 3), radius (G,) bound it in the rest frame;
    pose_centre (S, parts, 3), pose_radius (S, parts) bound the part in the body frame over all bank poses (and so
    over all their blends), body_centre (S, 3), body_radius (S,) the whole body; the material index of triangle k of geometry g is material[material_start[g] + k]."""

    scene: object
    offset: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    material: np.ndarray
    material_start: np.ndarray
    pose_centre: np.ndarray
    pose_radius: np.ndarray
    body_centre: np.ndarray
    body_radius: np.ndarray


@functools.lru_cache(maxsize=None)
def body_scene(bank: BodyBank, lod: str) -> BodyScene:
    """The body scene of `bank` at detail level `lod`, built once per process."""
    o3d = import_open3d()
    mesh = bank.meshes[lod]
    parts = len(bank.part_names)
    scene = o3d.t.geometry.RaycastingScene()
    side = int(np.ceil((bank.num_shapes * parts) ** (1 / 3)))
    offsets, centres, radii, materials = [], [], [], []
    for shape in range(bank.num_shapes):
        for part in range(parts):
            g = shape * parts + part
            offset = PART_SPACING_M * np.array([g % side, (g // side) % side, g // side ** 2], dtype=np.float64)
            triangles = mesh.triangles[mesh.triangle_part == part]
            used, local = np.unique(triangles, return_inverse=True)
            vertices = mesh.rest_vertices[shape, used].astype(np.float64)
            geometry = scene.add_triangles(o3d.core.Tensor((vertices + offset).astype(np.float32)),
                                           o3d.core.Tensor(local.reshape(-1, 3).astype(np.uint32)))
            assert geometry == g, "Open3D numbers geometries in the order they are added"
            centre = 0.5 * (vertices.min(0) + vertices.max(0))
            offsets.append(offset)
            centres.append(centre)
            radii.append(np.linalg.norm(vertices - centre, axis=1).max())
            materials.append(mesh.triangle_material[mesh.triangle_part == part])
    material_start = np.cumsum([0] + [len(m) for m in materials[:-1]])
    vertex, vertex_part = mesh.part_vertices
    pose_centre = np.zeros((bank.num_shapes, parts, 3))
    pose_radius = np.zeros((bank.num_shapes, parts))
    body_centre = np.zeros((bank.num_shapes, 3))
    body_radius = np.zeros(bank.num_shapes)
    for shape in range(bank.num_shapes):
        posed_parts = []
        for part in range(parts):
            rest = mesh.rest_vertices[shape, vertex[vertex_part == part]].astype(np.float64)
            posed = np.concatenate([rest @ t[:, :3].T + t[:, 3] for t in bank.transforms[shape, :, part]])
            pose_centre[shape, part] = 0.5 * (posed.min(0) + posed.max(0))
            pose_radius[shape, part] = np.linalg.norm(posed - pose_centre[shape, part], axis=1).max()
            posed_parts.append(posed)
        posed = np.concatenate(posed_parts)
        body_centre[shape] = 0.5 * (posed.min(0) + posed.max(0))
        body_radius[shape] = np.linalg.norm(posed - body_centre[shape], axis=1).max()
    return BodyScene(scene, np.array(offsets), np.array(centres), np.array(radii), np.concatenate(materials),
                     material_start, pose_centre, pose_radius, body_centre, body_radius)


class Caster:
    """Casts one scan pattern from one viewpoint; build once, then call cast_frame per frame.

    directions (P, 3) unit pulse directions in the sensor frame, time_offset (P,) [s]; beam_divergence_rad > 0
    adds sub-rays; threads: Open3D threads per cast (0 = all cores)."""

    def __init__(self, scene: Scene, mount: Mount, directions: np.ndarray, time_offset: np.ndarray,
                 frame_period_s: float, bank: BodyBank, lod: str = "fine", beam_divergence_rad: float = 0.0,
                 threads: int = 0):
        o3d = import_open3d()
        self.bank, self.lod, self.threads = bank, lod, threads
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

        vertices, triangles, self.static_reflectivity = scene.triangles()
        self.static_scene = o3d.t.geometry.RaycastingScene()
        self.static_scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
        t_hit, _, primitive, normal = _cast(self.static_scene, np.broadcast_to(self.origin, self.directions.shape),
                                            self.directions, threads)
        hit = np.isfinite(t_hit)
        self.static_range = np.where(hit, t_hit, np.inf)
        self.static_cos = np.where(hit, np.abs(np.einsum("ij,ij->i", normal, self.directions)), 0.0)
        self.static_ray_reflectivity = np.where(hit, self.static_reflectivity[np.where(hit, primitive, 0)], 0.0)
        azimuth = np.arctan2(self.directions[:, 1], self.directions[:, 0])
        self.azimuth_order = np.argsort(azimuth, kind="stable")
        self.azimuth_sorted = azimuth[self.azimuth_order]

    def candidate_rays(self, person: Person) -> np.ndarray:
        """Sorted indices of the rays that can reach `person` during the frame (its angular bounds)."""
        times = person.trajectory.times
        during = (times >= 0.0) & (times <= self.frame_period_s)
        path = person.trajectory.xy[during]
        centre_xy = 0.5 * (path.min(0) + path.max(0))
        reach = np.linalg.norm(path - centre_xy, axis=1).max() + BODY_REACH_M
        centre = np.array([centre_xy[0], centre_xy[1], BODY_HEIGHT_M / 2])
        radius = np.hypot(reach, BODY_HEIGHT_M / 2)
        offset = centre - self.origin
        distance_xy = np.hypot(offset[0], offset[1])
        if distance_xy > radius:
            half_width = np.arcsin(radius / distance_xy)
            middle = np.arctan2(offset[1], offset[0])
            windows = [(middle - half_width, middle + half_width)]
            windows += [(lo + shift, hi + shift) for lo, hi in windows for shift in (-2 * np.pi, 2 * np.pi)]
            rays = np.concatenate([self.azimuth_order[np.searchsorted(self.azimuth_sorted, lo):
                                                      np.searchsorted(self.azimuth_sorted, hi)]
                                   for lo, hi in windows])
        else:
            rays = np.arange(len(self.directions))
        along = self.directions[rays] @ offset
        miss = np.sum(offset ** 2) - along ** 2
        return np.sort(rays[(along > 0) & (miss < radius ** 2)])

    def cast_frame(self, people: list[Person], time_step_s: float = 0.0,
                   phase_steps: int | None = None) -> FrameHits:
        """Nearest hits of all pulses with `people` in the world.

        time_step_s: 0 = each pulse sees the people at its own time; > 0 = pulse times rounded to the middle of
        slices of that length (frame_period_s: one instant for the whole frame). phase_steps: gait phases a body
        can take (None = continuous)."""
        best_range = self.static_range.copy()
        best_cos = self.static_cos.copy()
        best_reflectivity = self.static_ray_reflectivity.copy()
        best_person = np.full(len(self.directions), -1)
        unoccluded = np.zeros(len(people), dtype=np.int64)
        cast_seconds = 0.0
        hits = []
        for index, person in enumerate(people):
            rays = self.candidate_rays(person)
            if len(rays):
                ray, t_hit, cos, reflectivity, seconds = self._cast_person(person, rays, time_step_s, phase_steps)
                cast_seconds += seconds
                unoccluded[index] = np.count_nonzero(ray < self.pulses)
                hits.append((ray, t_hit, cos, reflectivity, np.full(len(ray), index)))
        if hits:
            ray, t_hit, cos, reflectivity, person = (np.concatenate(column) for column in zip(*hits))
            order = np.lexsort((t_hit, ray))
            first = order[np.unique(ray[order], return_index=True)[1]]
            first = first[t_hit[first] < best_range[ray[first]]]
            target = ray[first]
            best_range[target], best_cos[target] = t_hit[first], cos[first]
            best_reflectivity[target], best_person[target] = reflectivity[first], person[first]
        edge_range = self._edge_range(best_range) if self.has_subrays else None
        p = self.pulses
        return FrameHits(range=best_range[:p], cos_incidence=best_cos[:p], reflectivity=best_reflectivity[:p],
                         person=best_person[:p], edge_range=edge_range, unoccluded=unoccluded,
                         cast_seconds=cast_seconds)

    def _edge_range(self, ray_range: np.ndarray) -> np.ndarray:
        """(P,) range of a second surface inside each pulse's footprint, nan where the footprint sees one smooth
        surface. Opposite sub-rays on a smooth surface deviate symmetrically from the centre (a tilted plane
        spreads the footprint's ranges, it does not shift them); a pair that does not is an edge, and its
        sub-ray farthest from the centre range gives the second surface."""
        centre = ray_range[:self.pulses]
        sub = ray_range[self.pulses:].reshape(SUBRAYS // 2, 2, self.pulses)
        both = np.isfinite(sub) & np.isfinite(centre)
        deviation = np.subtract(sub, centre, where=both, out=np.zeros_like(sub))
        smooth = both.all(axis=1) & (np.abs(deviation.sum(axis=1)) <= EDGE_ASYMMETRY_M)
        eligible = both & ~smooth[:, None, :] & (np.abs(deviation) > EDGE_ASYMMETRY_M)
        score = np.where(eligible, np.abs(deviation), -1.0).reshape(SUBRAYS, self.pulses)
        pick = np.argmax(score, axis=0)
        columns = np.arange(self.pulses)
        return np.where(score[pick, columns] > 0, sub.reshape(SUBRAYS, self.pulses)[pick, columns], np.nan)

    def _cast_person(self, person: Person, ray: np.ndarray, time_step_s: float, phase_steps: int | None):
        """Cast rays (n,) against the parts of `person`, each posed at the ray's pulse time.

        Returns ray (k,), range (k,), cos_incidence (k,), reflectivity (k,) of the rays that hit it (nearest part)
        and the seconds spent casting."""
        bodies = body_scene(self.bank, self.lod)
        parts = len(self.bank.part_names)
        time_of_ray = self.time_offset[ray]
        if time_step_s > 0:
            time_of_ray = (np.floor(time_of_ray / time_step_s) + 0.5) * time_step_s
        # each ray in the person's body frame at its pulse time (x_world = yaw x_body + xy); keep those passing
        # near the body in any pose
        xy, heading, phase, walk = person.trajectory.state(time_of_ray)
        c, s = np.cos(heading), np.sin(heading)
        relative = self.origin[:2] - xy
        body_origin = np.stack([c * relative[:, 0] + s * relative[:, 1], -s * relative[:, 0] + c * relative[:, 1],
                                np.full(len(ray), self.origin[2])], 1)
        d = self.directions[ray]
        body_direction = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], 1)
        near = _passes_sphere(body_origin, body_direction, bodies.body_centre[person.shape],
                              bodies.body_radius[person.shape])
        ray, body_origin, body_direction = ray[near], body_origin[near], body_direction[near]
        phase, walk = phase[near], walk[near]
        # keep the (ray, part) pairs passing near the part in any pose, then pose only those parts
        pair, part = np.nonzero(_passes_sphere(body_origin[:, None], body_direction[:, None],
                                               bodies.pose_centre[person.shape], bodies.pose_radius[person.shape]))
        transform = self.bank.part_transforms(np.full(len(pair), person.shape), phase[pair], walk[pair],
                                              phase_steps, part=part)
        rotation = transform[:, :, :3]
        local_origin = _transpose_apply(rotation, body_origin[pair] - transform[:, :, 3])
        local_direction = _transpose_apply(rotation, body_direction[pair])
        geometry = person.shape * parts + part
        near = _passes_sphere(local_origin, local_direction, bodies.centre[geometry], bodies.radius[geometry])
        pair, part, geometry = pair[near], part[near], geometry[near]
        rotation, local_origin, local_direction = rotation[near], local_origin[near], local_direction[near]
        empty = np.zeros(0)
        if not len(pair):
            return np.zeros(0, dtype=np.int64), empty, empty, empty, 0.0
        start = time.perf_counter()
        t_hit, hit_geometry, primitive, normal = _cast(bodies.scene, local_origin + bodies.offset[geometry],
                                                       local_direction, self.threads)
        seconds = time.perf_counter() - start
        hit = np.isfinite(t_hit) & (hit_geometry == geometry) & (t_hit < MAX_BODY_RANGE_M)
        order = np.flatnonzero(hit)[np.lexsort((t_hit[hit], pair[hit]))]
        first = order[np.unique(pair[order], return_index=True)[1]]  # nearest part per ray
        body_normal = np.einsum("nij,nj->ni", rotation[first], normal[first])
        cos = np.abs(np.einsum("ni,ni->n", body_normal, body_direction[pair[first]]))
        cos /= np.linalg.norm(body_normal, axis=1)
        material = bodies.material[bodies.material_start[geometry[first]] + primitive[first]]
        return ray[pair[first]], t_hit[first], cos, person.reflectivity[material], seconds


def _transpose_apply(rotation: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """(n, 3) R^T v for (n, 3, 3) R and (n, 3) v."""
    return (rotation[:, 0, :] * vector[:, 0:1] + rotation[:, 1, :] * vector[:, 1:2]
            + rotation[:, 2, :] * vector[:, 2:3])


def _passes_sphere(origin: np.ndarray, direction: np.ndarray, centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Whether rays origin + t direction (t > 0) pass within `radius` of `centre`; arrays broadcast, the last axis
    of origin, direction and centre is xyz."""
    to_centre = [centre[..., k] - origin[..., k] for k in range(3)]
    dx, dy, dz = direction[..., 0], direction[..., 1], direction[..., 2]
    along = (to_centre[0] * dx + to_centre[1] * dy + to_centre[2] * dz) / (dx * dx + dy * dy + dz * dz)
    gap = [to_centre[0] - along * dx, to_centre[1] - along * dy, to_centre[2] - along * dz]
    return (along > 0) & (gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2] < radius ** 2)
