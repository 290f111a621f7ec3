"""Boxes of the people of a frame, from the simulator state (never from the points).

One box per person at the frame's mid time (the mean time at which an up-and-down frame scans any elevation):
the posed body's extent in its heading frame from the ground up, heading = direction of travel (facing direction
when standing).
Its points are the returns of the pulses whose nearest hit is that person; its occlusion is the share of the
pulses that would hit it if nothing else were there but hit something nearer.
"""
from __future__ import annotations

import bisect

import numpy as np

from pcdet_memslidar.geometry.boxes import normalize_heading
from pcdet_memslidar.io.kitti import CLASS_NAME, MIN_BOX_POINTS
from pcdet_memslidar.sim.bodies import BodyBank
from pcdet_memslidar.sim.motion import TrajectoryStack
from pcdet_memslidar.sim.people import Person

OCCLUSION_LEVELS = (0.1, 0.5)  # occluded share below which a box is KITTI level 0 (fully visible), 1 (partly)


def person_boxes(bank: BodyBank, lod: str, people: list[Person], time_s: float) -> np.ndarray:
    """(n, 7) boxes [x, y, z_center, dx, dy, dz, heading] of the posed bodies of `people` at `time_s` [s]."""
    if not people:
        return np.zeros((0, 7))
    count = len(people)
    xy, heading, phase, walk = TrajectoryStack.of([p.trajectory for p in people]).state(
        np.arange(count), np.full(count, float(time_s)))
    shape = np.array([p.shape for p in people])
    boxes = bank.posed_boxes(lod, shape, bank.part_transforms(shape, phase, walk))
    low, high = boxes[:, :3], boxes[:, 3:]
    low[:, 2] = 0.0  # people stand on the flat ground; blended gait poses may float up to ~1 cm above it
    centre = 0.5 * (low + high)
    c, s = np.cos(heading), np.sin(heading)
    x = xy[:, 0] + c * centre[:, 0] - s * centre[:, 1]
    y = xy[:, 1] + s * centre[:, 0] + c * centre[:, 1]
    return np.column_stack([x, y, centre[:, 2], high - low, normalize_heading(heading)])


def occlusion_level(occluded_share: float) -> int:
    """KITTI occlusion level: 0 fully visible, 1 partly occluded, 2 largely occluded."""
    return bisect.bisect_right(OCCLUSION_LEVELS, occluded_share)


def label_people(bank: BodyBank, lod: str, people: list[Person], time_s: float, points_per_person: np.ndarray,
                 hits_per_person: np.ndarray, unoccluded: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Boxes of all people.

    points_per_person (people,) returned points of each person; hits_per_person (people,) pulses whose nearest
    hit is the person (before dropout); unoccluded (people,) pulses that would hit each person on its own.
    Returns boxes (M, 7) and names (M,) of the labelled people (>= MIN_BOX_POINTS points) and one metadata dict per
    person (labelled or not)."""
    boxes, records = [], []
    for index, (person, box) in enumerate(zip(people, person_boxes(bank, lod, people, time_s))):
        visible = int(points_per_person[index])
        share = 0.0 if unoccluded[index] == 0 else float(max(0.0, 1.0 - hits_per_person[index] / unoccluded[index]))
        labelled = visible >= MIN_BOX_POINTS
        if labelled:
            boxes.append(box)
        records.append(dict(box=[round(v, 6) for v in box.tolist()], num_points=visible, labelled=labelled,
                            occluded_share=round(share, 4), occlusion_level=occlusion_level(share),
                            shape=person.shape, sex=bank.shape_sex[person.shape],
                            stature_m=float(bank.shape_stature_m[person.shape]),
                            build=bank.shape_build[person.shape], behaviour=person.behaviour, group=person.group,
                            vest=person.vest))
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    return boxes, np.array([CLASS_NAME] * len(boxes), dtype=object), records
