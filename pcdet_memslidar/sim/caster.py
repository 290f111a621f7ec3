"""Ray casting of a MEMS scan pattern against a static world and moving, articulated people (Open3D).

How a frame is cast:
1. The static world is one RaycastingScene built once per viewpoint; all rays of the pattern are cast against it
   once and the hits are reused by every frame of that viewpoint (the world does not move).
2. People are not re-meshed per frame. Every body part of every bank shape sits, in its rest pose, in one shared
   RaycastingScene (the "body scene", each part at its own far-apart offset). The rays that can reach a person
   come from an angular index of the rays (time slices of SLICE_S, azimuth bins within each, elevation sorted
   within each bin): per slice, those in the angular range of a cylinder around the person's path while the
   rays of that slice see it. Each is moved into the person's body frame at
   the ray's own pulse time (trajectory), culled with boxes bounding the body and its parts over all poses, moved
   into the rest frame of each remaining part with the part's pose at that time (gait), which makes motion within
   the frame exact per pulse (time slicing with time_step_s > 0 quantises pulse times instead, for comparison),
   culled with the part's rest box, and cast against that part only. All people and parts go through these steps
   together, as arrays of (ray, person) and (ray, part) pairs, and through one cast_rays call.
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
from pcdet_memslidar.sim.motion import TrajectoryStack
from pcdet_memslidar.sim.people import Person
from pcdet_memslidar.sim.scenes import Scene
from pcdet_memslidar.utils.open3d import import_open3d

SUBRAYS = 4  # sub-rays per pulse at the edge of the beam footprint (when the sensor has a beam divergence)
BODY_REACH_M = 0.75  # horizontal reach of a body around its trajectory point (stride, arms)
BODY_HEIGHT_M = 2.0  # height of the bounding volume of a body
PART_SPACING_M = 300.0  # distance between body parts in the body scene: more than twice any cast range
MAX_BODY_RANGE_M = 120.0  # hits on a body part farther than this are foreign parts of the body scene
SLICE_S = 0.04  # s: the angular index is split into time slices of this length (a person moves < 8 cm in one)
AZIMUTH_BINS = 720  # bins of the angular ray index (0.5 deg)
AZIMUTH_BIN_RAD = 2 * np.pi / AZIMUTH_BINS
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


def _cast(scene, rays: np.ndarray, threads: int):
    """Cast rays (n, 6) [origin, direction] against an Open3D RaycastingScene; returns numpy t_hit (n,) float32,
    geometry ids (n,), primitive ids (n,), normals (n, 3) float32."""
    o3d = import_open3d()
    result = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)), nthreads=threads)
    return (result["t_hit"].numpy(), result["geometry_ids"].numpy().astype(np.int64),
            result["primitive_ids"].numpy().astype(np.int64), result["primitive_normals"].numpy())


@dataclass(frozen=True)
class BodyScene:
    """All (shape, part) rest meshes of one detail level in one RaycastingScene, and boxes that cull rays.

    Geometry id g = shape * parts + part sits at offset[:, g] in the scene; the material index of its triangle k
    is material[material_start[g] + k]. Axis-aligned boxes are (2, 3, ...) arrays of corners [low, high],
    component-major so that numpy loops run over the rays:
    rest_box (2, 3, G): geometry g in its rest frame; pose_box (2, 3, G): in the body frame over all bank poses;
    walk_box (2, 3, S * GAIT_PHASES * parts) at (shape * GAIT_PHASES + l) * parts + part: over the gait poses l
    and (l + 1) % GAIT_PHASES; stand_box (2, 3, G): in the standing pose; body_walk_box (2, 3, S * GAIT_PHASES)
    and body_stand_box (2, 3, S): the whole body likewise. A blend of bank poses stays in the convex hull of the
    blended poses, so in the union of their boxes."""

    scene: object
    offset: np.ndarray
    material: np.ndarray
    material_start: np.ndarray
    rest_box: np.ndarray
    pose_box: np.ndarray
    walk_box: np.ndarray
    stand_box: np.ndarray
    body_walk_box: np.ndarray
    body_stand_box: np.ndarray


def _boxes(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(2, 3, n) boxes from corners low, high (..., 3), flattened over the leading axes."""
    return np.stack([low.reshape(-1, 3).T, high.reshape(-1, 3).T])


@functools.lru_cache(maxsize=None)
def body_scene(bank: BodyBank, lod: str) -> BodyScene:
    """The body scene of `bank` at detail level `lod`, built once per process."""
    o3d = import_open3d()
    mesh = bank.meshes[lod]
    shapes, parts, gait = bank.num_shapes, len(bank.part_names), bank.gait_phases
    scene = o3d.t.geometry.RaycastingScene()
    side = int(np.ceil((shapes * parts) ** (1 / 3)))
    offset = np.zeros((3, shapes * parts))
    rest_low, rest_high = np.zeros((shapes, parts, 3)), np.zeros((shapes, parts, 3))
    posed_low, posed_high = np.zeros((shapes, gait + 1, parts, 3)), np.zeros((shapes, gait + 1, parts, 3))
    vertex, vertex_part = mesh.part_vertices
    materials = []
    for shape in range(shapes):
        for part in range(parts):
            g = shape * parts + part
            offset[:, g] = PART_SPACING_M * np.array([g % side, (g // side) % side, g // side ** 2])
            triangles = mesh.triangles[mesh.triangle_part == part]
            used, local = np.unique(triangles, return_inverse=True)
            vertices = mesh.rest_vertices[shape, used].astype(np.float64)
            geometry = scene.add_triangles(o3d.core.Tensor((vertices + offset[:, g]).astype(np.float32)),
                                           o3d.core.Tensor(local.reshape(-1, 3).astype(np.uint32)))
            assert geometry == g, "Open3D numbers geometries in the order they are added"
            materials.append(mesh.triangle_material[mesh.triangle_part == part])
            rest_low[shape, part], rest_high[shape, part] = vertices.min(0), vertices.max(0)
            rest = mesh.rest_vertices[shape, vertex[vertex_part == part]].astype(np.float64)
            transform = bank.transforms[shape, :, part]  # (poses, 3, 4)
            posed = np.einsum("pij,vj->pvi", transform[:, :, :3], rest) + transform[:, None, :, 3]
            posed_low[shape, :, part], posed_high[shape, :, part] = posed.min(1), posed.max(1)
    material_start = np.cumsum([0] + [len(m) for m in materials[:-1]])
    walk_low = np.minimum(posed_low[:, :gait], np.roll(posed_low[:, :gait], -1, axis=1))  # (S, gait, parts, 3)
    walk_high = np.maximum(posed_high[:, :gait], np.roll(posed_high[:, :gait], -1, axis=1))
    stand_low, stand_high = posed_low[:, gait], posed_high[:, gait]
    return BodyScene(scene, offset, np.concatenate(materials), material_start,
                     rest_box=_boxes(rest_low, rest_high), pose_box=_boxes(posed_low.min(1), posed_high.max(1)),
                     walk_box=_boxes(walk_low, walk_high), stand_box=_boxes(stand_low, stand_high),
                     body_walk_box=_boxes(walk_low.min(2), walk_high.max(2)),
                     body_stand_box=_boxes(stand_low.min(1), stand_high.max(1)))


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
        self.direction_rows = np.ascontiguousarray(self.directions.T)  # (3, R)
        self.time_offset = np.tile(np.asarray(time_offset, dtype=np.float64), len(rays))
        self.has_subrays = len(rays) > 1

        vertices, triangles, self.static_reflectivity = scene.triangles()
        self.static_scene = o3d.t.geometry.RaycastingScene()
        self.static_scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
        t_hit, _, primitive, normal = _cast(
            self.static_scene, np.column_stack([np.broadcast_to(self.origin, self.directions.shape), self.directions]),
            threads)
        hit = np.isfinite(t_hit)
        self.static_range = np.where(hit, t_hit.astype(np.float64), np.inf)  # (R,)
        hit, normal, primitive = hit[:self.pulses], normal[:self.pulses], primitive[:self.pulses]
        self.static_cos = np.where(hit, np.abs(np.einsum("ij,ij->i", normal, self.pulse_directions)), 0.0)  # (P,)
        self.static_ray_reflectivity = np.where(hit, self.static_reflectivity[np.where(hit, primitive, 0)], 0.0)
        self.static_edge_range = (self._edge_range(self.static_range, np.arange(self.pulses)) if self.has_subrays
                                  else None)
        # angular index: rays sorted by time slice, azimuth bin, then elevation;
        # key = slice * AZIMUTH_BINS + azimuth bin + 0.5 + elevation / 4
        ray_slice = np.minimum(np.floor(self.time_offset / SLICE_S), np.ceil(frame_period_s / SLICE_S) - 1)
        self.slice_times = np.array([[self.time_offset[ray_slice == j].min(), self.time_offset[ray_slice == j].max()]
                                     for j in range(int(ray_slice.max()) + 1)]).T  # (2, J) first and last pulse
        azimuth = np.arctan2(self.directions[:, 1], self.directions[:, 0])
        azimuth_bin = np.minimum(np.floor((azimuth + np.pi) / AZIMUTH_BIN_RAD), AZIMUTH_BINS - 1)
        key = ray_slice * AZIMUTH_BINS + azimuth_bin + 0.5 + np.arcsin(np.clip(self.directions[:, 2], -1.0, 1.0)) / 4
        self.angular_order = np.argsort(key, kind="stable")
        self.angular_key = key[self.angular_order]

    def candidate_pairs(self, people: TrajectoryStack, time_step_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Ray (n,) and person (n,) indices of the rays that can reach each person: per time slice of the pattern,
        those in the azimuth and elevation range of a vertical cylinder around the person's path while the rays
        of that slice see it (pulse times quantised by time_step_s as in `cast_frame`)."""
        # the trajectory samples bracketing each slice's pose times, (k, J, m) paths
        times = people.times
        sample_dt = times[1] - times[0]
        pose_times = _pose_time(self.slice_times, time_step_s)
        first = np.clip(np.floor((pose_times[0] - times[0]) / sample_dt).astype(np.int64), 0, len(times) - 1)
        last = np.clip(np.ceil((pose_times[1] - times[0]) / sample_dt).astype(np.int64), 0, len(times) - 1)
        samples = np.minimum(first[:, None] + np.arange((last - first).max() + 1), last[:, None])
        x, y = people.samples[0][:, samples], people.samples[1][:, samples]
        slices = len(first)
        # one cylinder per (person, slice), flattened
        centre_x, centre_y = (0.5 * (x.min(2) + x.max(2))).ravel(), (0.5 * (y.min(2) + y.max(2))).ravel()
        reach = np.hypot(x - centre_x.reshape(-1, slices, 1), y - centre_y.reshape(-1, slices, 1)).max(2).ravel()
        reach += BODY_REACH_M
        distance = np.hypot(centre_x - self.origin[0], centre_y - self.origin[1])
        outside = distance > reach  # else the sensor is above the cylinder: all azimuths, all elevations
        # elevation range: extremes of atan2(z - height, horizontal distance) at the cylinder's corners
        closest = np.where(outside, distance - reach, 1e-9)
        corners = np.arctan2(np.array([0.0, BODY_HEIGHT_M])[:, None, None] - self.origin[2],
                             np.stack([closest, distance + reach]))  # (z, distance, k * J)
        low = np.where(outside, corners.min((0, 1)), -np.pi / 2)
        high = np.where(outside, corners.max((0, 1)), np.pi / 2)
        half_width = np.where(outside, np.arcsin(reach / np.maximum(distance, reach)), np.pi)
        middle = np.arctan2(centre_y - self.origin[1], centre_x - self.origin[0])
        first_bin = np.floor((middle - half_width + np.pi) / AZIMUTH_BIN_RAD).astype(np.int64)
        last_bin = np.floor((middle + half_width + np.pi) / AZIMUTH_BIN_RAD).astype(np.int64)
        bins = np.minimum(last_bin - first_bin + 1, AZIMUTH_BINS)
        # one run of the angular index per (person, slice, azimuth bin)
        cylinder = np.repeat(np.arange(len(centre_x)), bins)
        base = (cylinder % slices) * AZIMUTH_BINS + _runs(first_bin, bins) % AZIMUTH_BINS + 0.5
        start = np.searchsorted(self.angular_key, base + low[cylinder] / 4)
        count = np.searchsorted(self.angular_key, base + high[cylinder] / 4, side="right") - start
        return self.angular_order[_runs(start, count)], np.repeat(cylinder // slices, count)

    def cast_frame(self, people: list[Person], time_step_s: float = 0.0,
                   phase_steps: int | None = None) -> FrameHits:
        """Nearest hits of all pulses with `people` in the world.

        time_step_s: 0 = each pulse sees the people at its own time; > 0 = pulse times rounded to the middle of
        slices of that length (frame_period_s: one instant for the whole frame). phase_steps: gait phases a body
        can take (None = continuous)."""
        p = self.pulses
        ray_range, cos = self.static_range.copy(), self.static_cos.copy()
        reflectivity, person = self.static_ray_reflectivity.copy(), np.full(p, -1)
        edge_range = self.static_edge_range.copy() if self.has_subrays else None
        unoccluded = np.zeros(len(people), dtype=np.int64)
        cast_seconds = 0.0
        if people:
            body = self._cast_people(people, time_step_s, phase_steps)
            cast_seconds = body.cast_seconds
            pulse_pairs = np.unique(body.person[body.ray < p] * p + body.ray[body.ray < p])
            unoccluded = np.bincount(pulse_pairs // p, minlength=len(people))
            order = np.lexsort((body.range, body.ray))
            first = order[np.diff(body.ray[order], prepend=-1) != 0]  # nearest hit of each ray
            first = first[body.range[first] < ray_range[body.ray[first]]]
            target = body.ray[first]
            ray_range[target] = body.range[first]
            if self.has_subrays:
                changed = np.unique(target % p)
                edge_range[changed] = self._edge_range(ray_range, changed)
            first = first[target < p]  # the beam centres: what the pulses measure
            pulse = body.ray[first]
            cos[pulse], reflectivity[pulse], person[pulse] = (body.cos_incidence[first], body.reflectivity[first],
                                                              body.person[first])
        return FrameHits(range=ray_range[:p], cos_incidence=cos, reflectivity=reflectivity, person=person,
                         edge_range=edge_range, unoccluded=unoccluded, cast_seconds=cast_seconds)

    def _edge_range(self, ray_range: np.ndarray, pulse: np.ndarray) -> np.ndarray:
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

    def _cast_people(self, people: list[Person], time_step_s: float, phase_steps: int | None) -> BodyHits:
        """Cast the candidate rays of all people against their body parts, each part posed at the ray's pulse
        time, in one cast. Vectors are component rows (3, n), so that numpy loops run over the rays."""
        bodies = body_scene(self.bank, self.lod)
        parts, gait = len(self.bank.part_names), self.bank.gait_phases
        trajectories = TrajectoryStack.of([p.trajectory for p in people])
        ray, person = self.candidate_pairs(trajectories, time_step_s)
        time_of_ray = _pose_time(self.time_offset.take(ray), time_step_s)
        # each ray in its person's body frame at its pulse time (x_world = yaw x_body + xy); keep those passing
        # through the box of the body in the poses blended at that time
        xy, heading, phase, walk = trajectories.state(person, time_of_ray)
        c, s = np.cos(heading), np.sin(heading)
        relative_x, relative_y = self.origin[0] - xy[:, 0], self.origin[1] - xy[:, 1]
        d = self.direction_rows.take(ray, axis=1)
        origin = np.stack([c * relative_x + s * relative_y, c * relative_y - s * relative_x,
                           np.full(len(ray), self.origin[2])])
        direction = np.stack([c * d[0] + s * d[1], c * d[1] - s * d[0], d[2]])
        shape = np.array([p.shape for p in people])[person]
        lower, _ = self.bank.gait_pose(phase, phase_steps)
        enter, leave = _box_interval(origin, direction, _blend_box(
            bodies.body_walk_box.take(shape * gait + lower, axis=-1), bodies.body_stand_box.take(shape, axis=-1), walk))
        ray, person, shape, phase, lower, walk, enter, leave, origin, direction = _take(
            np.flatnonzero(leave >= enter), ray, person, shape, phase, lower, walk, enter, leave, origin, direction)
        # the (ray, part) pairs whose heights inside the body box overlap the part's in any pose, then those
        # passing through the box of the part in the poses blended at the ray's time
        height = origin[2] + np.stack([enter, leave]) * direction[2]
        part_height = bodies.pose_box[:, 2].reshape(2, -1, parts).transpose(0, 2, 1).take(shape, axis=-1)
        part, pair = np.nonzero((part_height[0] <= height.max(0)) & (part_height[1] >= height.min(0)))
        geometry = shape[pair] * parts + part
        box = _blend_box(bodies.walk_box.take((shape[pair] * gait + lower[pair]) * parts + part, axis=-1),
                         bodies.stand_box.take(geometry, axis=-1), walk[pair])
        enter, leave = _box_interval(origin.take(pair, axis=1), direction.take(pair, axis=1), box)
        pair, part, geometry = _take(np.flatnonzero(leave >= enter), pair, part, geometry)
        # pose those parts at the rays' pulse times, move the rays into the parts' rest frames and keep those
        # passing through the box of the rest part
        transform = self.bank.part_transforms(shape[pair], phase[pair], walk[pair], phase_steps, part=part)
        local_origin = _rotate(transform, origin.take(pair, axis=1) - transform[[3, 7, 11]], inverse=True)
        local_direction = _rotate(transform, direction.take(pair, axis=1), inverse=True)
        enter, leave = _box_interval(local_origin, local_direction, bodies.rest_box.take(geometry, axis=-1))
        pair, geometry, transform, local_origin, local_direction = _take(
            np.flatnonzero(leave >= enter), pair, geometry, transform, local_origin, local_direction)
        rays = np.concatenate([local_origin + bodies.offset.take(geometry, axis=1), local_direction]).T
        start = time.perf_counter()
        t_hit, hit_geometry, primitive, normal = _cast(bodies.scene, rays, self.threads)
        cast_seconds = time.perf_counter() - start
        hit = np.flatnonzero(np.isfinite(t_hit) & (hit_geometry == geometry) & (t_hit < MAX_BODY_RANGE_M))
        pair, geometry, transform = _take(hit, pair, geometry, transform)
        body_normal = _rotate(transform, normal[hit].T)
        cos_incidence = (np.abs((body_normal * direction.take(pair, axis=1)).sum(0))
                         / np.linalg.norm(body_normal, axis=0))
        material = bodies.material[bodies.material_start[geometry] + primitive[hit]]
        reflectivity = np.array([p.reflectivity for p in people])[person[pair], material]
        return BodyHits(ray[pair], person[pair], t_hit[hit].astype(np.float64), cos_incidence, reflectivity,
                        cast_seconds)


@dataclass
class BodyHits:
    """Every hit of a ray on a body part (n hits): ray (n,), person (n,), range (n,) [m], cos_incidence (n,),
    reflectivity (n,); cast_seconds: time spent inside Open3D's cast_rays."""

    ray: np.ndarray
    person: np.ndarray
    range: np.ndarray
    cos_incidence: np.ndarray
    reflectivity: np.ndarray
    cast_seconds: float


def _pose_time(pulse_time: np.ndarray, time_step_s: float) -> np.ndarray:
    """The times [s] at which pulses sent at `pulse_time` see the people: their own (time_step_s = 0), else the
    middle of their slice of length time_step_s."""
    if time_step_s > 0:
        return (np.floor(pulse_time / time_step_s) + 0.5) * time_step_s
    return pulse_time


def _runs(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenated runs start[i], start[i] + 1, ..., start[i] + count[i] - 1 of integers."""
    return np.arange(count.sum()) + np.repeat(start - (np.cumsum(count) - count), count)


def _take(index: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each of `arrays` at `index` along its last axis."""
    return tuple(np.take(a, index, axis=-1) for a in arrays)


def _rotate(transform: np.ndarray, vector: np.ndarray, inverse: bool = False) -> np.ndarray:
    """(3, n) R v (or R^T v) for the rotations R of (12, n) flattened 3x4 transforms [R | t] and (3, n) v."""
    r = transform.reshape(3, 4, -1)[:, :3]
    if inverse:
        r = r.transpose(1, 0, 2)
    return r[:, 0] * vector[0] + r[:, 1] * vector[1] + r[:, 2] * vector[2]


def _blend_box(walking: np.ndarray, standing: np.ndarray, walk: np.ndarray) -> np.ndarray:
    """(2, 3, n) boxes of poses blended from walking poses (boxes walking (2, 3, n)) and the standing pose (boxes
    standing) with walk weights walk (n,) in [0, 1]: the union of the boxes of the poses with a weight."""
    low = np.minimum(np.where(walk > 0, walking[0], np.inf), np.where(walk < 1, standing[0], np.inf))
    high = np.maximum(np.where(walk > 0, walking[1], -np.inf), np.where(walk < 1, standing[1], -np.inf))
    return np.stack([low, high])


def _box_interval(origin: np.ndarray, direction: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameters t >= 0 at which rays origin + t direction enter and leave the axis-aligned boxes (2, 3, ...)
    [low, high] (slab test; leave < enter where a ray misses its box); arrays broadcast, the first axis of origin
    and direction is xyz."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / direction
        t_low, t_high = (box[0] - origin) * inverse, (box[1] - origin) * inverse
    enter = np.maximum(np.fmax.reduce(np.fmin(t_low, t_high), axis=0), 0.0)  # fmin / fmax skip 0 * inf = nan
    return enter, np.fmin.reduce(np.fmax(t_low, t_high), axis=0)
