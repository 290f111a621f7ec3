"""The caster's per-ray loops, compiled with numba: a few passes over a frame's rays where numpy would need
~150 small array operations per frame.

1. `candidate_pairs`: the rays that can reach each person, from an angular index of the rays (time slices,
   azimuth bins within each, elevation sorted within each bin): per slice, those in the azimuth and elevation
   range of a vertical cylinder around the person's path while the rays of that slice see it.
2. `part_rays`: each candidate pair moved into the person's body frame at the ray's pulse time (trajectory),
   culled with the box of the body in the poses blended at that time, then per body part culled with the part's
   box, moved into the part's rest frame with the part's pose at that time (gait) and culled with the rest box;
   what remains is cast against that part only, in the body scene.
3. `nearest_body_hits`: the nearest valid part hit of each pair, merged into each ray's nearest hit.

Boxes are float64 (..., 6) [x_low, y_low, z_low, x_high, y_high, z_high]; transforms (..., 12) are flattened 3x4
matrices [R | t] (row-major) from a part's rest frame to the body frame.
"""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.sim.motion import WALK_SPEED_FULL
from pcdet_memslidar.utils.compiled import kernel


@kernel(inline="always")
def _crosses(ox, oy, oz, dx, dy, dz, inverse_x, inverse_y, inverse_z, box) -> bool:
    """True if the ray origin + t direction, t >= 0, passes through the box (6,) (slab test; inverse_* = 1 /
    direction, used where the direction component is not 0)."""
    enter, leave = 0.0, np.inf
    for o, d, inverse, low, high in ((ox, dx, inverse_x, box[0], box[3]), (oy, dy, inverse_y, box[1], box[4]),
                                     (oz, dz, inverse_z, box[2], box[5])):
        if d == 0.0:
            if o < low or o > high:
                return False
            continue
        t_low, t_high = (low - o) * inverse, (high - o) * inverse
        enter = max(enter, min(t_low, t_high))
        leave = min(leave, max(t_low, t_high))
    return leave >= enter


@kernel
def candidate_pairs(pose_times, sample_times, samples, reach, height, origin, angular_key, angular_order, cell_start,
                    azimuth_bins):
    """Ray (n,) and person (n,) of each ray that can reach a person.

    pose_times (2, J) [s]: first and last time at which the rays of each of J time slices see the people;
    sample_times (m,) evenly spaced [s] and samples (5, k, m) the people's trajectories (as TrajectoryStack);
    reach (k,) [m] horizontal reach of each body around its trajectory point; height (k,) [m] its height;
    origin (3,) sensor position; angular_key (R,) sorted keys slice * azimuth_bins + azimuth bin + 0.5 +
    elevation / 4 of the rays angular_order (R,) (azimuth bins of 2 pi / azimuth_bins from -pi, elevation in rad);
    cell_start (J * azimuth_bins + 1,) index of the first key of each (slice, azimuth bin) cell in angular_key (the
    searches stay inside one cell's run of keys, which is in the cache).
    """
    people, slices, last = samples.shape[1], pose_times.shape[1], len(sample_times) - 1
    sample_dt = sample_times[1] - sample_times[0]
    bin_rad = 2 * np.pi / azimuth_bins
    starts = np.empty(people * slices * azimuth_bins, np.int64)
    counts = np.empty(people * slices * azimuth_bins, np.int64)
    owners = np.empty(people * slices * azimuth_bins, np.int64)
    runs = 0
    for k in range(people):
        for j in range(slices):
            # the cylinder around the path between the trajectory samples bracketing the slice's pose times
            first = min(max(int(np.floor((pose_times[0, j] - sample_times[0]) / sample_dt)), 0), last)
            final = min(max(int(np.ceil((pose_times[1, j] - sample_times[0]) / sample_dt)), 0), last)
            x_low, x_high = samples[0, k, first:final + 1].min(), samples[0, k, first:final + 1].max()
            y_low, y_high = samples[1, k, first:final + 1].min(), samples[1, k, first:final + 1].max()
            centre_x, centre_y = 0.5 * (x_low + x_high), 0.5 * (y_low + y_high)
            radius = 0.0
            for q in range(first, final + 1):
                radius = max(radius, np.hypot(samples[0, k, q] - centre_x, samples[1, k, q] - centre_y))
            radius += reach[k]
            distance = np.hypot(centre_x - origin[0], centre_y - origin[1])
            if distance > radius:  # elevation: extremes of atan2(z - sensor height, distance) at the corners
                low = high = np.arctan2(-origin[2], distance - radius)
                for z, d in ((0.0, distance + radius), (height[k], distance - radius),
                             (height[k], distance + radius)):
                    elevation = np.arctan2(z - origin[2], d)
                    low, high = min(low, elevation), max(high, elevation)
                half_width = np.arcsin(radius / distance)
            else:  # the sensor is above the cylinder: all azimuths, all elevations
                low, high, half_width = -np.pi / 2, np.pi / 2, np.pi
            middle = np.arctan2(centre_y - origin[1], centre_x - origin[0])
            first_bin = int(np.floor((middle - half_width + np.pi) / bin_rad))
            bins = min(int(np.floor((middle + half_width + np.pi) / bin_rad)) - first_bin + 1, azimuth_bins)
            # one run of the angular index per azimuth bin
            for b in range(first_bin, first_bin + bins):
                cell = j * azimuth_bins + b % azimuth_bins
                first_key = cell_start[cell]
                keys = angular_key[first_key:cell_start[cell + 1]]
                starts[runs] = first_key + np.searchsorted(keys, cell + 0.5 + low / 4)
                counts[runs] = first_key + np.searchsorted(keys, cell + 0.5 + high / 4, side="right") - starts[runs]
                owners[runs] = k
                runs += 1
    ray = np.empty(counts[:runs].sum(), np.int64)
    person = np.empty(len(ray), np.int64)
    n = 0
    for q in range(runs):
        ray[n:n + counts[q]] = angular_order[starts[q]:starts[q] + counts[q]]
        person[n:n + counts[q]] = owners[q]
        n += counts[q]
    return ray, person


@kernel
def part_rays(ray, person, ray_time, origin, directions, sample_times, samples, heading_cos, heading_sin, shape,
              phase_steps, transforms, body_box, part_box, rest_box, offset):
    """The rays of n candidate pairs that pass through a body part, in the part's rest frame in the body scene.

    ray (n,), person (n,): the pair's ray and person; ray_time (n,) [s]: when the ray sees the person; origin (3,)
    sensor position and directions (R, 3) ray directions in the ground frame; sample_times (m,) evenly spaced
    [s], samples (5, k, m) the people's trajectories (as TrajectoryStack), heading_cos and heading_sin (k, m) of
    their headings; shape (k,) body-bank shape of each person; phase_steps: gait phases a body can take
    (0 = continuous). Bank data of S shapes, G gait phases and J parts: transforms (S, G + 1, J, 12), the last
    pose standing; body_box (3, S, G, 6) and part_box (3, S, G, J, 6) in the body frame, over gait poses g and
    (g + 1) % G blended with the standing pose: [0] standing only, [1] any walk weight, [2] walking only;
    rest_box (S, J, 6); offset (S * J, 3) of geometry s * J + j in the body scene.
    Returns pair (c,) int64 candidate pair of each part ray, in pair order; geometry (c,) int64; rays (c, 6)
    float32 [origin, direction] in the body scene.
    """
    gait, parts = transforms.shape[1] - 1, transforms.shape[2]
    pair_out = np.empty(len(ray) * parts, np.int64)
    geometry_out = np.empty(len(ray) * parts, np.int64)
    rays_out = np.empty((len(ray) * parts, 6), np.float32)
    last = len(sample_times) - 1
    span = sample_times[last] - sample_times[0]
    pose = np.empty(12)
    count = 0
    for i in range(len(ray)):
        k, r = person[i], ray[i]
        s = shape[k]
        # the person's state at the ray's time, linearly interpolated between trajectory samples (the heading's
        # rotation too, renormalised: exact to ~1e-6 rad for the <= 3 deg a heading turns between samples)
        position = min(max((ray_time[i] - sample_times[0]) / span * last, 0.0), float(last))
        j = min(int(position), last - 1)
        f = position - j
        x = samples[0, k, j] + f * (samples[0, k, j + 1] - samples[0, k, j])
        y = samples[1, k, j] + f * (samples[1, k, j + 1] - samples[1, k, j])
        cycles = samples[3, k, j] + f * (samples[3, k, j + 1] - samples[3, k, j])
        speed = samples[4, k, j] + f * (samples[4, k, j + 1] - samples[4, k, j])
        c = heading_cos[k, j] + f * (heading_cos[k, j + 1] - heading_cos[k, j])
        sn = heading_sin[k, j] + f * (heading_sin[k, j + 1] - heading_sin[k, j])
        norm = np.sqrt(c * c + sn * sn)
        c, sn = c / norm, sn / norm
        walk = min(max(speed / WALK_SPEED_FULL, 0.0), 1.0)
        blended = 0 if walk == 0.0 else (2 if walk == 1.0 else 1)
        cycle = (cycles % 1.0) * gait
        if phase_steps > 0:
            step = gait / phase_steps
            cycle = (round(cycle / step) * step) % gait
        lower = int(np.floor(cycle)) % gait
        blend = cycle - np.floor(cycle)
        upper = (lower + 1) % gait
        # the ray in the body frame (x_world = yaw x_body + xy)
        rx, ry = origin[0] - x, origin[1] - y
        ox, oy, oz = c * rx + sn * ry, c * ry - sn * rx, origin[2]
        dx, dy, dz = (c * directions[r, 0] + sn * directions[r, 1], c * directions[r, 1] - sn * directions[r, 0],
                      directions[r, 2])
        ix, iy, iz = 1.0 / dx if dx != 0.0 else 0.0, 1.0 / dy if dy != 0.0 else 0.0, 1.0 / dz if dz != 0.0 else 0.0
        if not _crosses(ox, oy, oz, dx, dy, dz, ix, iy, iz, body_box[blended, s, lower]):
            continue
        for part in range(parts):
            if not _crosses(ox, oy, oz, dx, dy, dz, ix, iy, iz, part_box[blended, s, lower, part]):
                continue
            # the part's pose at the ray's time (gait blend, then walk <-> stand blend) and the ray in the part's
            # rest frame: R^T (o - t), R^T d
            first, second, standing = transforms[s, lower, part], transforms[s, upper, part], transforms[s, gait, part]
            for q in range(12):
                pose[q] = walk * ((1.0 - blend) * first[q] + blend * second[q]) + (1.0 - walk) * standing[q]
            vx, vy, vz = ox - pose[3], oy - pose[7], oz - pose[11]
            lox = pose[0] * vx + pose[4] * vy + pose[8] * vz
            loy = pose[1] * vx + pose[5] * vy + pose[9] * vz
            loz = pose[2] * vx + pose[6] * vy + pose[10] * vz
            ldx = pose[0] * dx + pose[4] * dy + pose[8] * dz
            ldy = pose[1] * dx + pose[5] * dy + pose[9] * dz
            ldz = pose[2] * dx + pose[6] * dy + pose[10] * dz
            if not _crosses(lox, loy, loz, ldx, ldy, ldz, 1.0 / ldx if ldx != 0.0 else 0.0,
                            1.0 / ldy if ldy != 0.0 else 0.0, 1.0 / ldz if ldz != 0.0 else 0.0, rest_box[s, part]):
                continue
            g = s * parts + part
            pair_out[count], geometry_out[count] = i, g
            rays_out[count, 0] = lox + offset[g, 0]
            rays_out[count, 1] = loy + offset[g, 1]
            rays_out[count, 2] = loz + offset[g, 2]
            rays_out[count, 3], rays_out[count, 4], rays_out[count, 5] = ldx, ldy, ldz
            count += 1
    return pair_out[:count], geometry_out[:count], rays_out[:count]


@kernel
def nearest_body_hits(pair, geometry, rays, t_hit, hit_geometry, primitive, normal, ray, person, pulses, max_range,
                      material, material_start, person_reflectivity, ray_range, cos_incidence, reflectivity,
                      person_hit, unoccluded, changed):
    """Merge the part hits of a frame into each ray's nearest hit, in place.

    pair (c,), geometry (c,), rays (c, 6) as `part_rays` returns them; t_hit (c,), hit_geometry (c,), primitive
    (c,), normal (c, 3): Open3D's answer for those rays (a hit counts on the ray's own part, nearer than
    max_range); ray (n,), person (n,) the candidate pairs; pulses P: ray r is pulse r % P, a beam centre if
    r < P; material (T,) of the body scene's triangles, triangle k of geometry g at material_start[g] + k;
    person_reflectivity (k, materials).
    Updated: ray_range (R,) [m], and for beam centres cos_incidence (P,) (in the part's rest frame),
    reflectivity (P,), person_hit (P,); unoccluded (k,) += beam centres that hit each person if nothing else were
    in the way; changed (P,) True for pulses with a ray whose range changed.
    """
    i = 0
    while i < len(pair):
        p, best, best_i = pair[i], np.inf, -1
        while i < len(pair) and pair[i] == p:
            t = np.float64(t_hit[i])
            if t < max_range and hit_geometry[i] == geometry[i] and t < best:
                best, best_i = t, i
            i += 1
        if best_i < 0:
            continue
        r, k = ray[p], person[p]
        if r < pulses:
            unoccluded[k] += 1
        if best >= ray_range[r]:
            continue
        ray_range[r] = best
        changed[r % pulses] = True
        if r < pulses:
            n, d = normal[best_i], rays[best_i, 3:]
            norm = np.sqrt((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))
            cos_incidence[r] = abs(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / norm if norm > 0 else 0.0
            triangle = material_start[geometry[best_i]] + primitive[best_i]
            reflectivity[r] = person_reflectivity[k, material[triangle]]
            person_hit[r] = k
