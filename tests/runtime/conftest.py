"""Fixtures of the runtime tests: the bundled OpenPCDet checkpoint."""
from pathlib import Path

import pytest

OPENPCDET_CHECKPOINT_SHA256 = "51537de9e6b5d19f11a802a13aab1bada356915839e8196bf4bce13beaadcab0"


@pytest.fixture(scope="session")
def openpcdet_checkpoint(bundled_asset) -> Path:
    """A checkpoint written by OpenPCDet's own train.py (tests/assets/openpcdet/README.md)."""
    return bundled_asset("tests/assets/openpcdet/openpcdet_checkpoint_tiny.pth", OPENPCDET_CHECKPOINT_SHA256)
