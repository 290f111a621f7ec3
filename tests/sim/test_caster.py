"""Ray casting geometry: ground, box obstacle, parallel and grazing rays, moving people, culling vs brute force."""
import numpy as np
import pytest

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.sim.bodies import LODS, load_body_bank
from pcdet_memslidar.sim.caster import Caster, body_scene
from pcdet_memslidar.sim.motion import make_trajectory
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import Person
from pcdet_memslidar.sim.scenes import Scene, World
from pcdet_memslidar.sim.sensor import get_sensor
from pcdet_memslidar.utils.open3d import import_open3d

PATTERN = get_pattern("cube1_paper")
DIRECTIONS, TIME_OFFSET, _ = PATTERN.pulses()


def make_scene(with_box: bool) -> Scene:
    world = World()
    world.patch((-5, 60), (-40, 40), 0.3)
    if with_box:
        world.box((10.0, 1.0), (1.0, 2.0, 1.5), 0.5)
    return Scene("test", tuple(world.surfaces), (0.0,))


def make_caster(scene, mount, divergence=0.0, directions=DIRECTIONS, times=TIME_OFFSET):
    return Caster(scene, mount, directions, times, PATTERN.frame_period_s, load_body_bank(), lod="fine",
                  beam_divergence_rad=divergence, threads=1)


def points_of(caster, hits, sensor, seed=0):
    measured, _, valid = sensor.measure(hits.range, hits.cos_incidence, hits.reflectivity,
                                        np.random.default_rng(seed), hits.edge_range)
    return caster.origin + caster.pulse_directions[valid] * measured[valid, None]


def test_ground_plane_at_known_mount_is_z0_within_noise():
    sensor = get_sensor("calibrated")
    caster = make_caster(make_scene(False), Mount(4.0, 16.0), sensor.beam_divergence_rad)
    hits = caster.cast_frame([])
    exact = caster.origin + caster.pulse_directions * hits.range[:, None]
    assert np.abs(exact[np.isfinite(hits.range), 2]).max() < 1e-4
    points = points_of(caster, hits, sensor)
    assert np.isfinite(hits.range).mean() > 0.9 and len(points) > 0.5 * len(DIRECTIONS)
    assert np.all(np.isfinite(points))
    assert abs(np.median(points[:, 2])) < 0.002
    assert np.percentile(np.abs(points[:, 2]), 99) < 0.05


def test_box_obstacle_points_lie_inside_its_true_extent():
    caster = make_caster(make_scene(True), Mount(4.0, 16.0))
    hits = caster.cast_frame([])
    exact = caster.origin + caster.pulse_directions * hits.range[:, None]
    above = exact[np.isfinite(hits.range) & (exact[:, 2] > 0.01)]
    assert len(above) > 100
    low, high = np.array([9.5, 0.0, 0.0]), np.array([10.5, 2.0, 1.5])
    assert np.all((above >= low - 1e-3) & (above <= high + 1e-3))
    # with the calibrated sensor nearly all returns above the ground stay within a few cm of the box
    points = points_of(caster, hits, get_sensor("calibrated"))
    above = points[points[:, 2] > 0.05]
    inside = np.all((above >= low - 0.03) & (above <= high + 0.03), axis=1)
    assert inside.mean() > 0.97


def test_parallel_and_grazing_rays_give_no_nan_or_spurious_points():
    scene = make_scene(True)  # box x 9.5..10.5, y 0..2, z 0..1.5
    azimuth = np.deg2rad(np.linspace(-30, 30, 61))
    horizontal = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros_like(azimuth)], 1)
    # rays in the plane of the box's side face y = 0 (sensor at y = 0), and rays skimming the ground
    in_face_plane = np.array([[1.0, 0.0, -z] for z in np.linspace(0.0, 0.4, 9)])
    skimming = np.array([[1.0, -1.0, -np.tan(np.deg2rad(e))] for e in (1e-4, 1e-3, 0.01)])
    directions = np.concatenate([horizontal, in_face_plane, skimming])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    caster = make_caster(scene, Mount(1.0, 0.0), get_sensor("calibrated").beam_divergence_rad, directions,
                         np.zeros(len(directions)))
    hits = caster.cast_frame([])
    assert not np.isnan(hits.range).any() and not np.isnan(hits.cos_incidence).any()
    exact = caster.origin + caster.pulse_directions * np.where(np.isfinite(hits.range), hits.range, 0.0)[:, None]
    hit = np.isfinite(hits.range)
    on_ground = np.abs(exact[:, 2]) < 1e-3
    on_box = np.all((exact >= [9.5 - 1e-3, -1e-3, -1e-3]) & (exact <= [10.5 + 1e-3, 2 + 1e-3, 1.5 + 1e-3]), axis=1)
    assert np.all(on_ground[hit] | on_box[hit])
    # parallel rays return only where they meet the box (azimuth 0..~12 deg), never from the ground
    parallel_hits = hit[:len(horizontal)]
    assert np.array_equal(parallel_hits, on_box[:len(horizontal)]) and 0 < parallel_hits.sum() < 20
    assert np.isinf(hits.range[-3:-1]).all()  # skimming at 1e-4 / 1e-3 deg: the ground ends before they meet it
    for name in ("calibrated", "carla"):
        points = points_of(caster, hits, get_sensor(name))
        assert np.all(np.isfinite(points)) and len(points) <= hit.sum()
        assert points[:, 2].min() > -0.05 and points[:, 2].max() < 1.5 + 0.05


def test_each_pulse_sees_a_walking_person_where_it_is_at_the_pulse_time():
    rng = np.random.default_rng(1)
    trajectory = make_trajectory("walk", rng, np.array([10.0, 0.0]), np.pi / 2, 1.5, 1.44, PATTERN.frame_period_s)
    person = Person(2, trajectory, np.full(4, 0.5), "walk", 0, False)
    caster = make_caster(make_scene(False), Mount(4.0, 16.0))
    hits = caster.cast_frame([person])
    on_person = hits.person == 0
    assert on_person.sum() > 50
    points = caster.origin + caster.pulse_directions[on_person] * hits.range[on_person, None]
    at_pulse, _, _, _ = trajectory.state(caster.time_offset[:caster.pulses][on_person])
    at_middle, _, _, _ = trajectory.state(np.array([PATTERN.frame_period_s / 2]))
    to_pulse = np.linalg.norm(points[:, :2] - at_pulse, axis=1)
    to_middle = np.linalg.norm(points[:, :2] - at_middle, axis=1)
    assert to_pulse.max() < 0.6  # the body around its position at the pulse's own time
    assert to_middle.max() > 0.3  # the person moved 0.6 m during the 0.4 s frame
    # with one instant for the whole frame, all hits gather around the mid-frame position instead
    frozen = caster.cast_frame([person], time_step_s=PATTERN.frame_period_s)
    mask = frozen.person == 0
    frozen_points = caster.origin + caster.pulse_directions[mask] * frozen.range[mask, None]
    assert np.linalg.norm(frozen_points[:, :2] - at_middle, axis=1).max() < 0.6


@pytest.mark.parametrize("lod", ["coarse", "full"])
def test_detail_levels_hit_the_same_body(lod):
    bank = load_body_bank()
    trajectory = make_trajectory("stand", np.random.default_rng(0), np.array([8.0, 0.0]), np.pi, 1.3, 1.44,
                                 PATTERN.frame_period_s)
    person = Person(3, trajectory, np.full(4, 0.5), "stand", 0, False)
    scene = make_scene(False)
    fine = make_caster(scene, Mount(4.0, 16.0)).cast_frame([person])
    other = Caster(scene, Mount(4.0, 16.0), DIRECTIONS, TIME_OFFSET, PATTERN.frame_period_s, bank, lod=lod,
                   threads=1).cast_frame([person])
    both = (fine.person == 0) & (other.person == 0)
    assert both.sum() > 0.9 * (fine.person == 0).sum()
    assert np.median(np.abs(fine.range[both] - other.range[both])) < 0.02


def posed_body_triangles(bank, person, time_s):
    """(T * 3, 3) corners of the triangles of `person`'s 'fine' body posed at `time_s`, in the ground frame."""
    xy, heading, phase, walk = person.trajectory.state(np.array([time_s]))
    return bank.posed_triangles("fine", person.shape, xy[0], heading[0], phase[0], walk[0]).reshape(-1, 3)


@pytest.mark.parametrize("mount, placements", [
    (Mount(4.0, 16.0), [(6, 0, "walk"), (9, -3, "stand"), (12, 4, "turn"), (4.5, 0.5, "walk"),
                        (20, -8, "stop_and_go"), (8, 5.5, "walk")]),
    (Mount(2.5, 60.0), [(0.3, 0.1, "stand"), (1.8, -1.0, "walk"), (2.5, 1.2, "turn")]),  # from above
])
def test_culled_casting_finds_exactly_the_hits_of_a_brute_force_cast(mount, placements):
    """Every pulse against one scene holding the ground and all bodies posed at mid-frame (no culling at all) vs
    the caster with one instant for the whole frame: the same pulses hit the same people."""
    o3d = import_open3d()
    bank = load_body_bank()
    rng = np.random.default_rng(3)
    people = []
    for index, (x, y, behaviour) in enumerate(placements):
        trajectory = make_trajectory(behaviour, rng, np.array([x, y], dtype=float), rng.uniform(-3, 3), 1.4, 1.44,
                                     PATTERN.frame_period_s)
        people.append(Person(index, trajectory, np.full(4, 0.5), behaviour, index, False))
    scene = make_scene(False)
    caster = make_caster(scene, mount)
    hits = caster.cast_frame(people, time_step_s=PATTERN.frame_period_s)

    brute = o3d.t.geometry.RaycastingScene()
    vertices, triangles, _ = scene.triangles()
    brute.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))  # geometry 0
    for person in people:  # geometry 1 + person index
        corners = posed_body_triangles(bank, person, PATTERN.frame_period_s / 2).astype(np.float32)
        brute.add_triangles(o3d.core.Tensor(corners),
                            o3d.core.Tensor(np.arange(len(corners), dtype=np.uint32).reshape(-1, 3)))
    rays = np.concatenate([np.broadcast_to(caster.origin, DIRECTIONS.shape), caster.pulse_directions], 1)
    result = brute.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    t_hit, geometry = result["t_hit"].numpy(), result["geometry_ids"].numpy().astype(np.int64)
    person = np.where(np.isfinite(t_hit) & (geometry > 0), geometry - 1, -1)
    assert np.all(np.bincount(person[person >= 0], minlength=len(people)) > 20)
    # the caster's body parts sit far apart in float32 (about 0.1 mm resolution): a grazing ray may flip
    assert np.count_nonzero(hits.person != person) <= 0.002 * np.count_nonzero((hits.person >= 0) | (person >= 0))
    on_person = (person >= 0) & (hits.person == person)
    error = np.abs(hits.range[on_person] - t_hit[on_person])
    assert np.median(error) < 1e-4 and np.percentile(error, 99) < 2e-3 and error.max() < 0.05
    static = (person < 0) & (hits.person < 0) & np.isfinite(t_hit)
    assert np.allclose(hits.range[static], t_hit[static], atol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("lod", LODS)
def test_candidate_cylinder_holds_every_vertex_of_every_pose(lod):
    """The rays cast against a person come from a cylinder of the body's reach around its path, up to its height:
    every vertex of every bank pose of every shape lies inside."""
    bank = load_body_bank()
    bodies = body_scene(bank, lod)
    mesh = bank.meshes[lod]
    vertex, part = np.unique(np.stack([mesh.triangles.ravel(), np.repeat(mesh.triangle_part, 3)]), axis=1)
    transform = bank.transforms[:, :, part]  # (S, poses, U, 3, 4)
    rest = mesh.rest_vertices[:, vertex].astype(np.float64)  # (S, U, 3)
    posed = np.einsum("spuij,suj->spui", transform[..., :3], rest) + transform[..., 3]
    assert np.all(np.hypot(posed[..., 0], posed[..., 1]).max((1, 2)) <= bodies.reach)
    assert np.all(posed[..., 2].max((1, 2)) <= bodies.height) and posed[..., 2].min() > -0.01
    assert 0.4 < bodies.reach.min() and bodies.reach.max() < 0.75 and 1.4 < bodies.height.min()
