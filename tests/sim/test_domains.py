"""Domain presets: their documented properties, the people they place and the frames they give."""
import numpy as np
import pytest

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.kitti import MIN_BOX_POINTS
from pcdet_memslidar.sim.bodies import load_body_bank
from pcdet_memslidar.sim.frame import simulate_frame
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import sample_people
from pcdet_memslidar.sim.scenes import get_scene
from pcdet_memslidar.sim.site import BUNDLED_SITES, get_domain

PATTERN = get_pattern("cube1_paper")


@pytest.mark.parametrize("name", list(BUNDLED_SITES))
def test_domain_presets_have_their_documented_properties(name):
    preset = get_domain(name)
    assert preset.pattern == "cube1_paper"
    if name == "sim":
        assert preset.sensor == "carla" and len({v.scene for v in preset.viewpoints}) == 4
        assert preset.people == (3, 10) and len(preset.shapes) == 4 and preset.phase_steps == 8
    elif name == "real":
        assert preset.sensor == "calibrated" and preset.viewpoints[0].mount == Mount(4.0, 16.0)
        assert len(preset.viewpoints) == 1 and preset.people == (1, 4) and preset.min_separation_m >= 1.5
    else:
        assert preset.sensor == "calibrated" and preset.viewpoints[0].mount == Mount(5.0, 23.0)
        assert preset.viewpoints[0].scene == "industrial_entrance" and preset.people == (1, 8)
        assert preset.default_frames == 230
    bank = load_body_bank()
    scene = get_scene(preset.viewpoints[0].scene)
    shapes = set()
    for index in range(20):
        people = sample_people(np.random.default_rng(index), preset, scene, preset.viewpoints[0].mount,
                               PATTERN.hfov_deg, PATTERN.vfov_deg, PATTERN.frame_period_s, bank)
        assert preset.people[0] - 1 <= len(people) <= preset.people[1]
        frame = (people[0].trajectory.times >= 0) & (people[0].trajectory.times <= PATTERN.frame_period_s)
        for i, a in enumerate(people):
            shapes.add(a.shape)
            for b in people[i + 1:]:
                gap = np.linalg.norm(a.trajectory.xy[frame] - b.trajectory.xy[frame], axis=1).min()
                assert gap >= (0.6 if a.group == b.group else preset.min_separation_m)
    assert shapes <= set(preset.shapes or range(bank.num_shapes))
    frame = simulate_frame(preset, seed=1, index=0, threads=1)
    assert frame.metadata["sensor"] == preset.sensor and len(frame.time_offset) == len(frame.points)
    assert np.all(frame.time_offset >= 0) and np.all(frame.time_offset <= PATTERN.frame_period_s)
    for record, box in zip([r for r in frame.metadata["people"] if r["labelled"]], frame.boxes):
        assert record["num_points"] >= MIN_BOX_POINTS and np.allclose(record["box"], box, atol=1e-5)
