"""Tiny generated MEMS-LiDAR domains (people-like boxes with points inside, a noisy ground) for dataset tests."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar import cli
from pcdet_memslidar.io.layout import KittiLayout, write_frame

REPO = Path(__file__).resolve().parents[2]
# Each domain's points carry their own intensity band, so tests can tell which database a pasted person came from.
INTENSITY = {"sim": (0.0, 1.0), "real": (100.0, 101.0), "industrial": (200.0, 201.0)}


def people_frame(rng: np.random.Generator, num_people: int, intensity: tuple[float, float]):
    """(N, 4) points and (M, 7) standing-person boxes, at least 1.5 m apart, inside the Cube 1 footprint."""
    boxes = []
    while len(boxes) < num_people:
        x = rng.uniform(6.0, 30.0)
        dz = rng.uniform(1.5, 1.9)
        box = [x, rng.uniform(-0.4, 0.4) * x, dz / 2, rng.uniform(0.5, 0.9), rng.uniform(0.4, 0.7), dz,
               rng.uniform(-np.pi, np.pi)]
        if all(np.hypot(box[0] - b[0], box[1] - b[1]) > 1.5 for b in boxes):
            boxes.append(box)
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    clouds = []
    for box in boxes:
        local = rng.uniform(-0.45, 0.45, size=(int(rng.integers(40, 150)), 3)) * box[3:6]
        cos, sin = np.cos(box[6]), np.sin(box[6])
        world = np.column_stack([cos * local[:, 0] - sin * local[:, 1], sin * local[:, 0] + cos * local[:, 1],
                                 local[:, 2]]) + box[:3]
        clouds.append(world)
    ground = np.column_stack([rng.uniform(3.0, 40.0, 400), rng.uniform(-20.0, 20.0, 400), rng.normal(0, 0.02, 400)])
    xyz = np.concatenate(clouds + [ground])
    points = np.column_stack([xyz, rng.uniform(*intensity, len(xyz))]).astype(np.float32)
    return points, boxes


def write_domain(root: Path, name: str, frames: int, seed: int, empty_frames=()) -> None:
    """`frames` frames 000000... of domain `name` in root/name; frames in `empty_frames` have no people."""
    rng = np.random.default_rng(seed)
    layout = KittiLayout(root / name)
    for index in range(frames):
        points, boxes = people_frame(rng, 0 if index in empty_frames else int(rng.integers(1, 5)), INTENSITY[name])
        write_frame(layout, f"{index:06d}", points, ["Pedestrian"] * len(boxes), boxes, {"domain": name})


@pytest.fixture(scope="session")
def memslidar_data(tmp_path_factory) -> Path:
    """DATA_PATH with sim (12 frames), real (12, frame 000002 empty) and industrial (4) plus their infos,
    made by `memslidar create-infos --cfg cfgs/m3.yaml --set PROFILE smoke DATA_CONFIG.DATA_PATH ...`."""
    root = tmp_path_factory.mktemp("memslidar")
    write_domain(root, "sim", 12, seed=1)
    write_domain(root, "real", 12, seed=2, empty_frames=(2,))
    write_domain(root, "industrial", 4, seed=3)
    assert cli.main(["create-infos", "--cfg", str(REPO / "cfgs" / "m3.yaml"), "--set", "PROFILE", "smoke",
                     "DATA_CONFIG.DATA_PATH", str(root)]) == 0
    return root


@pytest.fixture
def make_people_frame():
    """people_frame(rng, num_people, intensity) -> (points (N, 4), boxes (M, 7))."""
    return people_frame


@pytest.fixture
def intensity_bands() -> dict:
    """{domain: (low, high)} intensity band of each generated domain."""
    return INTENSITY
