"""Trajectories: one at a time and in batches, the stacked interpolation used by the caster and the labels."""
import numpy as np
import pytest

from pcdet_memslidar.sim.motion import (
    BEHAVIOURS,
    SAMPLE_DT,
    WALK_SPEED_FULL,
    TrajectoryStack,
    make_trajectories,
    make_trajectory,
)


def test_stacked_states_equal_per_trajectory_linear_interpolation():
    rng = np.random.default_rng(0)
    trajectories = [make_trajectory(behaviour, rng, np.array([10.0, y]), 0.5, 1.3, 1.44, 0.4)
                    for behaviour, y in (("walk", 0.0), ("stop_and_go", 2.0), ("turn", -2.0), ("stand", 4.0))]
    person = rng.integers(0, len(trajectories), 500)
    t = np.concatenate([rng.uniform(-0.5, 0.9, 496), [0.0, 0.4, -9.0, 9.0]])  # the last two are clamped
    xy, heading, phase, walk = TrajectoryStack.of(trajectories).state(person, t)
    for index, trajectory in enumerate(trajectories):
        mine = person == index
        times = trajectory.times
        assert xy[mine, 0] == pytest.approx(np.interp(t[mine], times, trajectory.xy[:, 0]), abs=1e-12)
        assert xy[mine, 1] == pytest.approx(np.interp(t[mine], times, trajectory.xy[:, 1]), abs=1e-12)
        assert heading[mine] == pytest.approx(np.interp(t[mine], times, trajectory.heading), abs=1e-12)
        assert phase[mine] == pytest.approx(np.interp(t[mine], times, trajectory.cycles), abs=1e-12)
        expected_walk = np.clip(np.interp(t[mine], times, trajectory.speed) / WALK_SPEED_FULL, 0.0, 1.0)
        assert walk[mine] == pytest.approx(expected_walk, abs=1e-12)


def test_stacking_trajectories_with_other_sample_times_is_refused():
    rng = np.random.default_rng(0)
    short = make_trajectory("walk", rng, np.zeros(2), 0.0, 1.3, 1.44, 0.4)
    long = make_trajectory("walk", rng, np.zeros(2), 0.0, 1.3, 1.44, 0.4, margin_s=3.0)
    with pytest.raises(ValueError, match="share their sample times"):
        TrajectoryStack.of([short, long])


@pytest.mark.parametrize("margin_s", [2.0, SAMPLE_DT])
def test_batch_of_trajectories_equals_one_trajectory_at_a_time(margin_s):
    rng = np.random.default_rng(3)
    behaviour = np.array(BEHAVIOURS * 5)
    k = len(behaviour)
    anchor_xy, heading = rng.uniform(-10, 10, (k, 2)), rng.uniform(-4, 4, k)
    speed, stride = rng.uniform(0.9, 1.8, k), rng.uniform(1.2, 1.6, k)
    stack = make_trajectories(behaviour, np.random.default_rng(7).random((k, 5)), anchor_xy, heading, speed, stride,
                              0.4, margin_s)
    one_by_one = np.random.default_rng(7)  # make_trajectory draws the same 5 numbers per person
    for i in range(k):
        single = make_trajectory(behaviour[i], one_by_one, anchor_xy[i], heading[i], speed[i], stride[i], 0.4, margin_s)
        assert single.times is stack.times
        assert TrajectoryStack.of([single]).samples[:, 0] == pytest.approx(stack.samples[:, i], abs=1e-12)
        assert np.allclose(single.state(np.array([0.2]))[0], anchor_xy[i])  # passes the anchor at mid-frame
    with pytest.raises(ValueError, match="unknown behaviour 'run'"):
        make_trajectories(np.array(["walk", "run"]), rng.random((2, 5)), anchor_xy[:2], heading[:2], speed[:2],
                          stride[:2], 0.4)


def companion(trajectory):
    """The trajectory of someone walking 0.75 m to the left of `trajectory`, with 1.3 m strides."""
    return TrajectoryStack.of([trajectory]).offset(np.array([0.75]), np.array([1.3])).trajectory(0)


def test_a_short_window_gives_the_same_motion_during_the_frame():
    t = np.linspace(0.0, 0.4, 41)
    for seed in range(20):
        for behaviour in BEHAVIOURS:
            args = (np.array([5.0, 1.0]), 1.0, 1.4, 1.44, 0.4)
            long = make_trajectory(behaviour, np.random.default_rng(seed), *args, margin_s=2.0)
            short = make_trajectory(behaviour, np.random.default_rng(seed), *args, margin_s=SAMPLE_DT)
            assert len(short.times) == 23 and short.times[0] < 0.0 and short.times[-1] > 0.4
            for a, b in ((long, short), (companion(long), companion(short))):
                (xy_a, heading_a, phase_a, walk_a), (xy_b, heading_b, phase_b, walk_b) = a.state(t), b.state(t)
                assert xy_a == pytest.approx(xy_b, abs=1e-9) and heading_a == pytest.approx(heading_b, abs=1e-9)
                assert walk_a == pytest.approx(walk_b, abs=1e-9)
                assert np.ptp(phase_a - phase_b) < 1e-9  # gait cycles counted from another start


def test_companions_walk_beside_at_the_same_timing():
    rng = np.random.default_rng(5)
    behaviour = np.array(BEHAVIOURS * 3)
    k = len(behaviour)
    leaders = make_trajectories(behaviour, rng.random((k, 5)), rng.uniform(-5, 5, (k, 2)), rng.uniform(-3, 3, k),
                                np.full(k, 1.4), np.full(k, 1.44), 0.4)
    lateral, stride = rng.uniform(-1, 1, k), np.full(k, 1.3)
    companions = leaders.offset(lateral, stride)
    for i in range(k):
        single = TrajectoryStack.of([leaders.trajectory(i)]).offset(lateral[i:i + 1], stride[i:i + 1])
        assert single.samples[:, 0] == pytest.approx(companions.samples[:, i], abs=1e-12)
    gap = companions.samples[:2] - leaders.samples[:2]
    assert np.hypot(*gap) == pytest.approx(np.abs(lateral)[:, None] * np.ones(leaders.times.shape))
    # walking straight, the companion's gait follows the leader's distance walked
    straight = np.isin(behaviour, ["walk", "stop_and_go"])
    cycles = companions.samples[3] * stride[:, None] - leaders.samples[3] * 1.44
    assert np.abs(cycles[straight]).max() < 1e-9
    assert np.abs(companions.samples[4] - leaders.samples[4])[behaviour == "walk"].max() < 1e-9
    path = TrajectoryStack.along_paths(leaders.times, leaders.samples[:2, :1], leaders.samples[2, :1], np.array([1.44]))
    assert path.samples[3, 0] == pytest.approx(leaders.samples[3, 0])
    assert path.samples[4, 0] == pytest.approx(leaders.samples[4, 0])
