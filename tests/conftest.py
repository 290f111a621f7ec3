"""Test-wide fixtures: the bundled assets (checked by sha256) and a full disk. Torch keeps its default threads (the
machine's cores; CI: 2), so thread bugs show up as they would for users."""
import errno
import hashlib
import io
import os
from pathlib import Path

import pytest

from pcdet_memslidar.utils import atomic

ASSETS = Path(__file__).resolve().parent / "assets"
REAL_RECORDING = ASSETS / "blickfeld" / "cube1_sample_2020.bfpc"
REAL_RECORDING_SHA256 = "f2fafd8bf6d63a6e579a8c510985f12c81feed00e783c2edcc6f54ab13a0f492"  # Blickfeld's dump.bfpc
OPENPCDET_CHECKPOINT = ASSETS / "openpcdet" / "openpcdet_checkpoint_tiny.pth"
OPENPCDET_CHECKPOINT_SHA256 = "51537de9e6b5d19f11a802a13aab1bada356915839e8196bf4bce13beaadcab0"


def bundled_asset(path: Path, sha256: str) -> Path:
    """`path`, after checking that it is there and unchanged (its README says where it came from)."""
    assert path.is_file(), f"missing {path}: restore it from git"
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert digest == sha256, f"{path} changed (sha256 {digest}): restore it from git"
    return path


@pytest.fixture(scope="session")
def real_recording() -> Path:
    """The real Cube 1 recording bundled in tests/assets/blickfeld (a copy of ../shared/data/blickfeld's)."""
    return bundled_asset(REAL_RECORDING, REAL_RECORDING_SHA256)


@pytest.fixture(scope="session")
def openpcdet_checkpoint() -> Path:
    """A checkpoint written by OpenPCDet's own train.py (tests/assets/openpcdet/README.md)."""
    return bundled_asset(OPENPCDET_CHECKPOINT, OPENPCDET_CHECKPOINT_SHA256)


@pytest.fixture
def full_disk(monkeypatch):
    """Every atomic write fails in write() with ENOSPC and no file name, as a full disk reports it."""
    class FullDisk(io.RawIOBase):
        def writable(self):
            return True

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "open", lambda descriptor, mode: os.close(descriptor) or FullDisk(), raising=False)
