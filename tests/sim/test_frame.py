"""A simulated frame: no people gives an empty label and the static world."""
import dataclasses

import numpy as np

from pcdet_memslidar.sim.domains import get_domain
from pcdet_memslidar.sim.frame import simulate_frame


def test_zero_people_gives_an_empty_label_and_the_static_world():
    preset = dataclasses.replace(get_domain("real"), people=(0, 0))
    frame = simulate_frame(preset, seed=0, index=0, threads=1)
    assert frame.boxes.shape == (0, 7) and len(frame.names) == 0 and frame.metadata["people"] == []
    assert len(frame.points) > 20000 and np.isfinite(frame.points).all()
