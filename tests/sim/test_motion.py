"""Trajectories: the stacked interpolation used by the caster and the labels."""
import numpy as np
import pytest

from pcdet_memslidar.sim.motion import WALK_SPEED_FULL, TrajectoryStack, make_trajectory


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
