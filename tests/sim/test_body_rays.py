"""The caster's compiled loops on hand-made cases with exact answers: slab tests at faces, edges and parallel rays;
merging part hits into each ray's nearest hit."""
import numpy as np
import pytest

from pcdet_memslidar.sim.body_rays import _crosses, nearest_body_hits

BOX = np.array([0.0, 0.0, 0.0, 1.0, 2.0, 3.0])  # x 0..1, y 0..2, z 0..3


def crosses(origin, direction, box=BOX):
    direction = np.asarray(direction, dtype=np.float64)
    with np.errstate(divide="ignore"):
        inverse = np.where(direction != 0.0, 1.0 / np.where(direction != 0.0, direction, 1.0), 0.0)
    return _crosses(*map(float, origin), *map(float, direction), *map(float, inverse), box)


@pytest.mark.parametrize("origin, direction, expected", [
    ((-1.0, 1.0, 1.0), (1.0, 0.0, 0.0), True),  # straight through
    ((-1.0, 1.0, 1.0), (-1.0, 0.0, 0.0), False),  # pointing away
    ((0.5, 1.0, 1.0), (0.0, 0.0, 1.0), True),  # starting inside
    ((-1.0, 0.0, 1.0), (1.0, 0.0, 0.0), True),  # in the plane of the face y = 0: touches it
    ((-1.0, -1e-12, 1.0), (1.0, 0.0, 0.0), False),  # parallel, just outside that face
    ((-1.0, 1.0, 1.0), (1.0, -1.0, 0.0), True),  # touching the edge x = 0, y = 0 only
    ((-1.0, 1.0 - 1e-9, 1.0), (1.0, -1.0, 0.0), False),  # just missing that edge
    ((2.0, 3.0, 4.0), (-1.0, -1.0, -1.0), True),  # enters at the corner (1, 2, 3)
    ((0.5, 1.0, 1.0), (0.0, 0.0, 0.0), True),  # no direction, inside
    ((5.0, 1.0, 1.0), (0.0, 0.0, 0.0), False),  # no direction, outside
])
def test_slab_test_at_faces_edges_and_parallel_rays(origin, direction, expected):
    assert crosses(origin, direction) is expected


def test_nearest_body_hits_merges_people_and_the_static_world():
    # 2 pulses, no sub-rays; ray 0 is a candidate of person 0 (parts 3 and 5) and person 1 (part 7); ray 1 of
    # person 1 only, whose hit lies behind the static world
    ray, person = np.array([0, 0, 1]), np.array([0, 1, 1])
    pair = np.array([0, 0, 1, 2])
    geometry = np.array([3, 5, 7, 7])
    rays = np.zeros((4, 6), np.float32)
    rays[:, 3:] = [[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [0.0, 3.0, 4.0], [1.0, 0.0, 0.0]]  # local directions
    t_hit = np.array([7.5, 6.25, 6.5, 9.0], np.float32)
    hit_geometry = np.array([3, 4, 7, 7], np.uint32)  # the second part ray hit another part: not counted
    primitive = np.array([0, 0, 1, 0], np.uint32)
    normal = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], np.float32)
    material = np.array([0, 1, 2, 3, 3, 2, 1, 0])  # triangles of geometries 3, 5, 7 start at 0, 2, 4
    material_start = np.zeros(8, np.int64)
    material_start[[3, 5, 7]] = [0, 2, 4]
    person_reflectivity = np.array([[0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7, 0.8]])
    ray_range, cos, reflectivity = np.array([np.inf, 8.0]), np.zeros(2), np.zeros(2)
    person_hit, unoccluded, changed = np.full(2, -1), np.zeros(2, np.int64), np.zeros(2, bool)
    nearest_body_hits(pair, geometry, rays, t_hit, hit_geometry, primitive, normal, ray, person, 2, 120.0,
                      material, material_start, person_reflectivity, ray_range, cos, reflectivity, person_hit,
                      unoccluded, changed)
    assert ray_range.tolist() == [6.5, 8.0]  # person 1 in front of person 0; the wall in front of person 1
    assert person_hit.tolist() == [1, -1] and changed.tolist() == [True, False]
    assert cos.tolist() == [float(np.float32(0.6)), 0.0]  # |(0, 1, 0) . (0, 3, 4)| / 5 in float32 (Open3D's)
    assert reflectivity.tolist() == [0.7, 0.0]  # person 1, triangle 1 of geometry 7: material 2
    assert unoccluded.tolist() == [1, 2]  # pulses that would hit each person with nothing else there
