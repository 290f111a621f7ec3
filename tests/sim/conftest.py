"""Fixtures of the simulator's tests."""
import numpy as np
import pytest

from pcdet_memslidar.sim.motion import Trajectory
from pcdet_memslidar.sim.people import Person


def _standing_person(x: float, y: float) -> Person:
    """Body shape 5 standing still at (x, y) [m] through a frame and around it."""
    times = np.arange(-0.1, 0.3, 0.02)
    samples = np.zeros((5, len(times)))
    samples[0], samples[1] = x, y
    return Person(shape=5, trajectory=Trajectory(times, samples), reflectivity=np.full(4, 0.5), behaviour="stand",
                  group=0, vest=False)


@pytest.fixture(scope="session")
def standing_person():
    """standing_person(x, y) -> a Person standing still there."""
    return _standing_person
