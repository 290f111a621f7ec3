"""People of a frame: collision-free placement, determinism, preset semantics."""
import dataclasses

import numpy as np
import pytest

from pcdet_memslidar.sim.bodies import load_body_bank
from pcdet_memslidar.sim.motion import TrajectoryStack
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import BODY_RADIUS_M, GROUP_SPACING_M, MAX_TRIES, _accepted, sample_people
from pcdet_memslidar.sim.scenes import get_scene
from pcdet_memslidar.sim.site import BUNDLED_SITES, get_domain

PATTERN = get_pattern("cube1_paper")


def people_of(preset, viewpoint, seed, bank):
    rng = np.random.default_rng(seed)
    people = sample_people(rng, preset, get_scene(viewpoint.scene), viewpoint.mount, PATTERN.hfov_deg,
                           PATTERN.vfov_deg, PATTERN.frame_period_s, bank)
    return people, rng


@pytest.mark.parametrize("name", list(BUNDLED_SITES))
def test_people_keep_their_distance_and_clear_of_obstacles_during_the_frame(name):
    preset, bank = get_domain(name), load_body_bank()
    for viewpoint in preset.viewpoints:
        obstacles = get_scene(viewpoint.scene).obstacles
        for seed in range(40):
            people, _ = people_of(preset, viewpoint, seed, bank)
            drawn = np.random.default_rng(seed).integers(preset.people[0], preset.people[1] + 1)
            assert len(people) == drawn  # these scenes have room for everyone
            times = people[0].trajectory.times
            frame = (times >= 0.0) & (times <= PATTERN.frame_period_s)
            paths = np.stack([p.trajectory.xy[frame] for p in people])  # (people, F, 2)
            inside = ((paths[:, :, None] > obstacles[:, :2] - BODY_RADIUS_M)
                      & (paths[:, :, None] < obstacles[:, 2:] + BODY_RADIUS_M)).all(3)
            assert not inside.any()
            gap = np.linalg.norm(paths[:, None] - paths[None], axis=3).min(2)
            group = np.array([p.group for p in people])
            apart = group[:, None] != group[None]
            assert (gap[apart] >= preset.min_separation_m).all()
            assert np.allclose(gap[~apart & ~np.eye(len(people), dtype=bool)], GROUP_SPACING_M)


@pytest.mark.parametrize("name", list(BUNDLED_SITES))
def test_people_follow_the_preset(name):
    preset, bank = get_domain(name), load_body_bank()
    people = []
    for seed in range(60):
        frame_people, _ = people_of(preset, preset.viewpoints[seed % len(preset.viewpoints)], seed, bank)
        groups = [p.group for p in frame_people]
        assert groups == sorted(groups) and max(np.unique(groups, return_counts=True)[1]) <= 2
        assert all(frame_people[g].group == g for g in groups)  # a group is named by its first member
        people += frame_people
    assert {p.shape for p in people} <= set(preset.shapes or range(bank.num_shapes))
    assert {p.behaviour for p in people} == {b for b, weight in preset.behaviours if weight > 0}
    reflectivity = np.stack([p.reflectivity for p in people])
    vest = np.array([p.vest for p in people])
    assert (reflectivity[vest, 1] == 0.95).all()
    assert ((reflectivity[~vest] >= [0.3, 0.05, 0.05, 0.05]) & (reflectivity[~vest] < [0.55, 0.8, 0.5, 0.3])).all()
    assert vest.mean() == pytest.approx(preset.vest_probability, abs=0.08)


def test_same_generator_state_gives_the_same_people_and_a_fixed_number_of_draws():
    preset, bank = get_domain("industrial"), load_body_bank()
    a, rng_a = people_of(preset, preset.viewpoints[0], 3, bank)
    b, rng_b = people_of(preset, preset.viewpoints[0], 3, bank)
    assert len(a) == len(b) >= 3
    for p, q in zip(a, b):
        assert (p.shape, p.behaviour, p.group, p.vest) == (q.shape, q.behaviour, q.group, q.vest)
        assert np.array_equal(p.reflectivity, q.reflectivity)
        assert np.array_equal(TrajectoryStack.of([p.trajectory]).samples, TrajectoryStack.of([q.trajectory]).samples)
    assert rng_a.bit_generator.state == rng_b.bit_generator.state
    # the draws do not depend on what happens: another scene, and a spacing that leaves room for few people
    crowded = dataclasses.replace(preset, min_separation_m=30.0)
    c, rng_c = people_of(crowded, get_domain("sim").viewpoints[3], 3, bank)
    assert len(c) < len(a)
    assert rng_c.bit_generator.state == rng_a.bit_generator.state


def test_people_of_a_frame_share_their_sample_times_covering_the_frame():
    preset, bank = get_domain("sim"), load_body_bank()
    people, _ = people_of(preset, preset.viewpoints[0], 0, bank)
    times = people[0].trajectory.times
    assert all(p.trajectory.times is times for p in people)
    assert times[0] <= 0.0 and times[-1] >= PATTERN.frame_period_s
    TrajectoryStack.of([p.trajectory for p in people])  # as the caster and the labels stack them


def reference_accepted(paths, grouped, count, scene, separation_m):
    """One candidate after the other, each member's path tested sample by sample."""
    low, high = scene.obstacles[:, :2] - BODY_RADIUS_M, scene.obstacles[:, 2:] + BODY_RADIUS_M

    def free(person, placed):
        xy = paths[:, :, person].T
        if ((xy[:, None] > low) & (xy[:, None] < high)).all(2).any():
            return False
        return all(np.hypot(*(paths[:, :, person] - paths[:, :, other])).min() >= separation_m for other in placed)

    accepted, placed = [], []
    for candidate in range(paths.shape[2] // 2):
        if len(placed) >= count:
            break
        members = list(range(2 * candidate, 2 * candidate + (2 if grouped[candidate] and count - len(placed) >= 2
                                                            else 1)))
        if all(free(person, placed) for person in members):
            accepted.append(members)
            placed += members
    return accepted


@pytest.mark.parametrize("scene_name", ["industrial_entrance", "pathway"])
def test_accepted_candidates_are_those_of_one_by_one_placement(scene_name):
    scene = get_scene(scene_name)
    rng = np.random.default_rng(1)
    centre = scene.obstacles[:, :2].mean(0)
    for trial in range(60):
        tries = int(rng.integers(1, MAX_TRIES + 1))
        start = centre[:, None, None] + rng.uniform(-6, 6, (2, 1, 2 * tries))  # a crowd among the obstacles
        paths = start + np.cumsum(rng.normal(0, 0.05, (2, 21, 2 * tries)), axis=1)
        grouped = (rng.random(tries) < 0.4).tolist()
        count = int(rng.integers(0, 12))
        separation = float(rng.choice([0.7, 1.5]))
        expected = reference_accepted(paths, grouped, count, scene, separation)
        assert [list(m) for m in _accepted(paths, grouped, count, scene, separation)] == expected
