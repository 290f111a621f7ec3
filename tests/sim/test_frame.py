"""A simulated frame: no people gives an empty label and the static world."""
import dataclasses

import numpy as np

from pcdet_memslidar.sim.frame import simulate_frame
from pcdet_memslidar.sim.site import get_domain


def test_zero_people_gives_an_empty_label_and_the_static_world():
    preset = dataclasses.replace(get_domain("real"), people=(0, 0))
    frame = simulate_frame(preset, seed=0, index=0, threads=1)
    assert frame.boxes.shape == (0, 7) and len(frame.names) == 0 and frame.metadata["people"] == []
    assert len(frame.points) > 20000 and np.isfinite(frame.points).all()


def test_a_sequence_keeps_its_people_and_moves_them_by_walking_distances():
    from pcdet_memslidar.sim.frame import simulate_sequence
    preset = get_domain("industrial")
    frames = list(simulate_sequence(preset, 1002, 4))
    people = [frame.metadata["people"] for frame in frames]
    assert [frame.metadata["frame_index"] for frame in frames] == [0, 1, 2, 3]
    assert [frame.metadata["time_s"] for frame in frames] == [0.0, 0.4, 0.8, 1.2]
    # the same people (body shape, behaviour) in every frame, and the boxes are the labelled ones, in id order
    assert len({tuple((p["shape"], p["behaviour"]) for p in frame_people) for frame_people in people}) == 1
    for frame in frames:
        ids = frame.metadata["person_ids"]
        np.testing.assert_allclose(frame.boxes, [frame.metadata["people"][i]["box"] for i in ids], atol=1e-6)
    # between frames (0.4 s) a person moves at most what a brisk walk and a swinging pose allow
    moves = np.array([[np.hypot(q["box"][0] - p["box"][0], q["box"][1] - p["box"][1]) for p, q in zip(before, after)]
                      for before, after in zip(people, people[1:])])
    assert moves.max() < 1.8 * 0.4 + 0.3 and (moves > 0.3).any()  # and some walk
    # a sequence is its own draw: the same seed gives the same frames
    again = next(simulate_sequence(preset, 1002, 4))
    np.testing.assert_array_equal(again.points, frames[0].points)
