"""Labels: a person is labelled only with enough points; the box is the posed body at mid-frame."""
import numpy as np
import pytest

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.kitti import MIN_BOX_POINTS
from pcdet_memslidar.sim.bodies import load_body_bank
from pcdet_memslidar.sim.frame import get_caster, render
from pcdet_memslidar.sim.labels import person_boxes
from pcdet_memslidar.sim.motion import make_trajectory
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import Person
from pcdet_memslidar.sim.sensor import get_sensor

PATTERN = get_pattern("cube1_paper")


def standing_person(x, y, heading=np.pi / 2, shape=2):
    trajectory = make_trajectory("stand", np.random.default_rng(0), np.array([x, y]), heading, 1.3, 1.44,
                                 PATTERN.frame_period_s)
    return Person(shape, trajectory, np.full(4, 0.5), "stand", 0, False)


def test_person_at_fov_edge_is_labelled_only_with_5_or_more_points():
    bank = load_body_bank()
    caster = get_caster("pathway", Mount(4.0, 16.0), "cube1_paper", "carla", "fine", 1)
    edge_y = -10.0 * np.tan(np.deg2rad(PATTERN.hfov_deg / 2))  # right FoV edge at x = 10 m
    counts = []
    for index, y in enumerate(edge_y + np.arange(0.6, -0.8, -0.05)):
        person = standing_person(10.0, y)
        points, _, boxes, names, records = render(caster, [person], get_sensor("carla"),
                                                  np.random.default_rng(index), bank, "fine", 0.2)
        count = records[0]["num_points"]
        counts.append(count)
        assert records[0]["labelled"] == (count >= MIN_BOX_POINTS) == (len(boxes) == 1)
        assert list(names) == ["Pedestrian"] * len(boxes)
    counts = np.array(counts)
    assert counts[0] > 20 and counts[-1] == 0  # inside the FoV, then outside it
    assert np.any((counts > 0) & (counts < MIN_BOX_POINTS))  # a sliver of a person: hit but not labelled


def test_box_is_the_posed_body_at_mid_frame_heading_along_travel():
    bank = load_body_bank()
    trajectory = make_trajectory("walk", np.random.default_rng(0), np.array([12.0, 1.0]), 0.7, 1.4, 1.44,
                                 PATTERN.frame_period_s)
    person = Person(4, trajectory, np.full(4, 0.5), "walk", 0, False)
    box = person_boxes(bank, "fine", [person], PATTERN.frame_period_s / 2)[0]
    assert box[6] == pytest.approx(0.7)
    assert box[2] - box[5] / 2 == pytest.approx(0.0, abs=1e-3)  # feet on the ground
    assert box[5] == pytest.approx(bank.shape_stature_m[4], abs=0.05)  # 1.86 m tall
    assert 0.3 < box[3] < 1.2 and 0.4 < box[4] < 0.8
    assert np.hypot(box[0] - 12.0, box[1] - 1.0) < 0.3
