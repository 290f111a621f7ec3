"""Fixtures of the io tests (importer, ground, recordings): frames scanned at a known mount, and the memory a
recording's frames take to read."""
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.formats import list_frames
from pcdet_memslidar.sim.pattern import get_pattern


def _scan_room(mount: Mount, seed: int) -> np.ndarray:
    """(K, 4) points in the sensor frame: the cube1_2020 pattern cast from `mount` at a floor (z = 0), a wall at
    x = 12 m and two person-sized boxes, with 0.8 cm Gaussian range noise; rays beyond 40 m give no return."""
    directions, _, _ = get_pattern("cube1_2020").pulses()
    ray = mount.directions_to_ground(directions)
    origin = mount.origin
    with np.errstate(divide="ignore", invalid="ignore"):
        hits = [np.where(ray[:, 2] < 0, -origin[2] / ray[:, 2], np.inf),  # floor
                np.where(ray[:, 0] > 0, 12.0 / ray[:, 0], np.inf)]  # wall
        for low, high in (([5.0, -1.0, 0.0], [5.5, -0.5, 1.8]), ([8.0, 1.0, 0.0], [8.6, 1.6, 1.7])):
            t_low, t_high = (np.array(low) - origin) / ray, (np.array(high) - origin) / ray
            enter, leave = np.minimum(t_low, t_high).max(axis=1), np.maximum(t_low, t_high).min(axis=1)
            hits.append(np.where((enter <= leave) & (enter > 0), enter, np.inf))
    distance = np.min(hits, axis=0)
    keep = distance < 40.0
    distance = distance[keep] + np.random.default_rng(seed).normal(0.0, 0.008, keep.sum())
    return np.concatenate([directions[keep] * distance[:, None], np.full((keep.sum(), 1), 100.0)], axis=1)


@pytest.fixture
def scan_room():
    """scan_room(mount, seed) -> (K, 4) points of a room scanned from `mount`, in the sensor frame."""
    return _scan_room


def _peak_bytes(fmt: str, path: Path) -> int:
    """The most memory (traced by Python) held while listing the recording `path` of format `fmt` and then loading
    its frames in order, after a first frame read untraced (what a first read compiles or caches does not count)."""
    list_frames(fmt, path)[0].load()
    tracemalloc.start()
    try:
        for frame in list_frames(fmt, path):
            frame.load()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.fixture
def peak_bytes():
    """peak_bytes(fmt, path) -> the most memory [bytes] held while reading every frame of a recording."""
    return _peak_bytes
