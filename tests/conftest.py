"""Test-wide settings: torch uses the cores the machine has (CI: 2), so thread bugs show up as they would for users."""
import hashlib
from pathlib import Path

import pytest

REAL_RECORDING = Path(__file__).resolve().parent / "assets" / "blickfeld" / "cube1_sample_2020.bfpc"
REAL_RECORDING_SHA256 = "f2fafd8bf6d63a6e579a8c510985f12c81feed00e783c2edcc6f54ab13a0f492"  # Blickfeld's dump.bfpc


@pytest.fixture(scope="session")
def real_recording() -> Path:
    """The real Cube 1 recording bundled in tests/assets/blickfeld (a copy of ../shared/data/blickfeld's)."""
    assert REAL_RECORDING.is_file(), f"missing {REAL_RECORDING}: restore it from git"
    digest = hashlib.sha256(REAL_RECORDING.read_bytes()).hexdigest()
    assert digest == REAL_RECORDING_SHA256, f"{REAL_RECORDING} changed (sha256 {digest}): restore it from git"
    return REAL_RECORDING
