"""Test-wide settings: torch uses the cores the machine has (CI: 2), so thread bugs show up as they would for users."""
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REAL_RECORDING = SHARED / "data" / "blickfeld" / "cube1_sample_2020.bfpc"


@pytest.fixture(scope="session")
def real_recording() -> Path:
    """The real Cube 1 recording of ../shared/data/blickfeld (present beside every clone, CI included)."""
    assert REAL_RECORDING.is_file(), f"missing {REAL_RECORDING}: the repository expects ../shared beside the clone"
    return REAL_RECORDING
