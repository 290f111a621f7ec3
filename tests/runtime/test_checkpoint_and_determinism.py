"""Checkpoints (OpenPCDet format, weights_only=True), identical results for fixed seeds, exact resume."""
import logging
from pathlib import Path

import pytest
import torch
from torch.utils.data import DataLoader

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import (
    checkpoint_state,
    list_checkpoints,
    load_params_from_file,
    load_params_with_optimizer,
    save_checkpoint,
)
from pcdet_memslidar.runtime.common import set_random_seed
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train import train as train_run
from pcdet_memslidar.runtime.train_loop import train_model

EPOCHS = 2
CFGS = Path(__file__).resolve().parents[2] / "cfgs"


@pytest.fixture(scope="module")
def dataset(small_range, person_voxel):
    return SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=7)


@pytest.fixture(scope="module")
def train(small_model_cfg, small_optim_cfg):
    """train(dataset, out_dir, epochs=EPOCHS, ckpt=None) -> (model, optimizer): the small SECOND trained under seed
    666 to `epochs`, resumed from `ckpt` if given."""
    def setup(dataset, start_iter=0, ckpt=None):
        set_random_seed(666)
        model = build_network(small_model_cfg(), num_class=1, dataset=dataset)
        optim_cfg = small_optim_cfg()
        optimizer = build_optimizer(model, optim_cfg)
        start_epoch = 0
        if ckpt is not None:
            start_iter, start_epoch = load_params_with_optimizer(model, ckpt, optimizer)
        loader = DataLoader(dataset, batch_size=2, shuffle=False, collate_fn=dataset.collate_batch)
        scheduler = build_scheduler(optimizer, len(loader), EPOCHS, start_iter - 1, optim_cfg)
        return model, optimizer, scheduler, loader, optim_cfg, start_epoch, start_iter

    def run(dataset, out_dir, epochs=EPOCHS, ckpt=None):
        model, optimizer, scheduler, loader, optim_cfg, start_epoch, start_iter = setup(dataset, ckpt=ckpt)
        train_model(model, optimizer, loader, scheduler, optim_cfg, start_epoch, epochs, start_iter, 0, None, out_dir,
                    "cpu", use_tqdm_to_record=True)
        return model, optimizer
    return run


@pytest.mark.slow
def test_fixed_seed_gives_identical_weights_twice_and_resume_is_exact(dataset, tmp_path, train):
    first, _ = train(dataset, tmp_path / "a")
    second, _ = train(dataset, tmp_path / "b")
    for (key, a), b in zip(first.state_dict().items(), second.state_dict().values()):
        assert torch.equal(a, b), key
    # stop after epoch 1, resume from its checkpoint: the same weights as the uninterrupted run
    train(dataset, tmp_path / "c", epochs=1)
    assert [p.name for p in list_checkpoints(tmp_path / "c")] == ["checkpoint_epoch_1.pth"]
    resumed, _ = train(dataset, tmp_path / "c", ckpt=tmp_path / "c" / "checkpoint_epoch_1.pth")
    assert resumed.global_step.item() == first.global_step.item() == 4
    for (key, a), b in zip(first.state_dict().items(), resumed.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), rtol=0, atol=1e-6), key


def test_checkpoint_round_trip_with_weights_only(dataset, tmp_path, train, small_model_cfg, small_optim_cfg,
                                                 small_range, person_voxel):
    model, optimizer = train(dataset, tmp_path, epochs=1)
    path = save_checkpoint(checkpoint_state(model, optimizer, epoch=1, it=2), tmp_path / "round_trip")
    raw = torch.load(path, weights_only=True)
    assert list(raw) == ["epoch", "it", "model_state", "optimizer_state", "version", "memslidar"]
    assert raw["memslidar"]["point_cloud_range"] == small_range and raw["memslidar"]["voxel_size"] == person_voxel
    assert type(raw["epoch"]) is int and type(raw["it"]) is int and isinstance(raw["version"], str)
    assert all(not isinstance(v, torch.Tensor) or v.device.type == "cpu" for v in raw["model_state"].values())
    fresh = build_network(small_model_cfg(), num_class=1, dataset=dataset)
    load_params_from_file(fresh, path, strict=True)
    for (key, a), b in zip(model.state_dict().items(), fresh.state_dict().values()):
        assert torch.equal(a, b), key
    fresh_optimizer = build_optimizer(fresh, small_optim_cfg())
    assert load_params_with_optimizer(fresh, path, fresh_optimizer) == (2, 1)
    assert fresh_optimizer.state_dict()["state"][0]["exp_avg"].equal(optimizer.state_dict()["state"][0]["exp_avg"])


def test_a_mismatching_checkpoint_is_refused_with_the_file_name(dataset, tmp_path, small_model_cfg):
    path = save_checkpoint(checkpoint_state(build_network(small_model_cfg(), 1, dataset)), tmp_path / "small.pth")
    wide = small_model_cfg()
    wide.BACKBONE_2D.NUM_FILTERS = [64, 64]
    expected = (r"small.pth: does not fit the model of this config: 12 weights of another shape, checkpoint vs model "
                r"\(backbone_2d.blocks.0.1.weight \(32, 256, 3, 3\) vs \(64, 256, 3, 3\), .*Use the config \(MODEL "
                r"section and PROFILE\)")
    with pytest.raises(DataFormatError, match=expected):
        load_params_from_file(build_network(wide, 1, dataset), path, strict=True)
    with pytest.raises(DataFormatError, match="not found"):
        load_params_from_file(build_network(wide, 1, dataset), tmp_path / "missing.pth")


@pytest.mark.slow
def test_validation_between_epochs_does_not_change_the_training(memslidar_data, tmp_path):
    """Iterating the validation loader draws a base seed from torch's global RNG; without a fork of it, the epochs
    after a validation would see other augmentations, and a sweep (validated at the end) would not give the
    weights that reproduce (validated every epoch) gives for the same config and seed."""
    cfg = load_config(CFGS / "m3.yaml", ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(memslidar_data),
                                         "OPTIMIZATION.NUM_EPOCHS", str(EPOCHS)])
    logger = logging.getLogger(__name__)
    states = [torch.load(train_run(cfg, tmp_path / f"val_{interval}", logger, seed=0, val_interval=interval),
                         weights_only=True)["model_state"] for interval in (0, 1)]
    assert states[0].keys() == states[1].keys()
    assert all(torch.equal(states[0][key], states[1][key]) for key in states[0])
