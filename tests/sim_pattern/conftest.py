"""Shared fixture of the simulator-pattern tests: the real Cube 1 recording, decoded once."""
import pytest

from pcdet_memslidar.io.bfpc import read_bfpc


@pytest.fixture(scope="session")
def real_bfpc(real_recording):
    return read_bfpc(real_recording)
