"""Checkpoints that must be refused, each with its own reason: damaged, diverged, trained on another grid, or not a
checkpoint at all."""
import argparse
import logging

import pytest
import torch

from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, load_params_from_file, read_checkpoint, save_checkpoint

SHIFTED_RANGE = [2.56, -5.12, -0.5, 12.8, 5.12, 3.5]  # the same 128 x 128 x 40 cells as small_range, elsewhere


@pytest.fixture
def model_on_grid(small_model_cfg, small_range, person_voxel):
    """model_on_grid(point_cloud_range=small_range, profile=None) -> the small SECOND for that grid and profile."""
    def make(point_cloud_range=small_range, profile=None):
        model = build_network(small_model_cfg(), 1,
                              SyntheticPersonDataset(point_cloud_range, person_voxel, num_frames=1))
        model.profile = profile
        return model
    return make


def test_a_checkpoint_of_another_grid_is_refused_naming_both_grids(tmp_path, caplog, model_on_grid, small_range):
    path = save_checkpoint(checkpoint_state(model_on_grid(profile="quick")), tmp_path / "quick.pth")
    expected = (r"quick.pth: was trained on profile 'quick', POINT_CLOUD_RANGE \[0.0, -5.12, -0.5, 10.24, 5.12, 3.5\], "
                r"VOXEL_SIZE \[0.08, 0.08, 0.1\], but this config has profile 'paper', POINT_CLOUD_RANGE \[2.56, "
                r"-5.12, -0.5, 12.8, 5.12, 3.5\], VOXEL_SIZE \[0.08, 0.08, 0.1\]: its weights do not fit these voxels "
                r"and anchors. Use the config it was trained with \(--set PROFILE quick\)")
    with pytest.raises(DataFormatError, match=expected):
        load_params_from_file(model_on_grid(SHIFTED_RANGE, profile="paper"), path, strict=True)
    load_params_from_file(model_on_grid(small_range, profile="paper"), path, strict=True)  # same grid: fine
    with caplog.at_level(logging.WARNING):  # --pretrained_model takes what fits, with a warning
        load_params_from_file(model_on_grid(SHIFTED_RANGE), path, logging.getLogger("pretrained"))
    assert "was trained on profile 'quick'" in caplog.text


def test_nan_weights_are_refused_naming_the_tensor(tmp_path, model_on_grid):
    model = model_on_grid()
    with torch.no_grad():
        model.backbone_2d.blocks[0][1].weight[0, 0, 0, 0] = float("nan")
    path = save_checkpoint(checkpoint_state(model), tmp_path / "diverged.pth")
    with pytest.raises(DataFormatError, match=r"diverged.pth: weight 'backbone_2d.blocks.0.1.weight' \(32, 256, 3, 3\) "
                                              r"has NaN or infinite values: the training diverged"):
        load_params_from_file(model_on_grid(), path, strict=True)


def test_a_bit_flip_in_the_weights_is_detected(tmp_path, model_on_grid):
    model = model_on_grid()
    path = save_checkpoint(checkpoint_state(model), tmp_path / "flipped.pth")
    data = bytearray(path.read_bytes())
    weight = model.backbone_2d.blocks[0][1].weight.detach().numpy().tobytes()
    offset = bytes(data).find(weight)
    assert offset > 0
    data[offset + len(weight) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match="flipped.pth: 'model_state' differs from the sha256 stored when it was "
                                              "saved: the file was damaged since"):
        load_params_from_file(model_on_grid(), path, strict=True)


def _saved(tmp_path, name, obj, **kwargs):
    path = tmp_path / name
    torch.save(obj, path, **kwargs)
    return path


def test_each_unreadable_checkpoint_gets_its_own_reason(tmp_path, model_on_grid):
    good = save_checkpoint(checkpoint_state(model_on_grid()), tmp_path / "good.pth").read_bytes()
    legacy = _saved(tmp_path, "legacy.pth", {"model_state": {"w": torch.zeros(1000)}},
                    _use_new_zipfile_serialization=False).read_bytes()
    weights = {"w": torch.zeros(3)}
    (tmp_path / "empty.pth").write_bytes(b"")
    (tmp_path / "notes.pth").write_text("these are not weights\n")
    (tmp_path / "half.pth").write_bytes(good[:len(good) // 2])
    (tmp_path / "half_legacy.pth").write_bytes(legacy[:len(legacy) // 2])
    (tmp_path / "run").mkdir()
    cases = {
        "missing.pth": "missing.pth: checkpoint not found: pass an existing .pth file",
        "run": "run: is a folder, not a checkpoint: pass a .pth file",
        "empty.pth": r"empty.pth: is empty \(0 bytes\): its saving was interrupted",
        "notes.pth": "notes.pth: is not a PyTorch checkpoint .* neither torch.save's zip nor its legacy pickle format",
        "half.pth": "half.pth: cannot be read: truncated, corrupt or not written by torch.save .*failed finding "
                    "central directory",
        "half_legacy.pth": "half_legacy.pth: cannot be read: truncated, corrupt or not written by torch.save",
        _saved(tmp_path, "object.pth", {"model_state": weights, "args": argparse.Namespace(lr=1)}).name:
            r"object.pth: holds an object of type argparse.Namespace, which a safe load \(weights_only\) does not",
        _saved(tmp_path, "other.pth", {"state_dict": weights}).name:
            r"other.pth: has no 'model_state' \(it holds keys \['state_dict'\]\): not an OpenPCDet",
        _saved(tmp_path, "bare.pth", weights).name:
            r"bare.pth: is a bare state_dict, not a checkpoint: save it as torch.save\(\{'model_state'",
        _saved(tmp_path, "scalars.pth", {"model_state": {"w": 1.0}}).name:
            "scalars.pth: 'model_state' is not a dict of tensors",
    }
    for name, expected in cases.items():
        with pytest.raises(DataFormatError, match=expected) as error:
            read_checkpoint(tmp_path / name)
        assert "plain Python scalars" not in str(error.value), name
