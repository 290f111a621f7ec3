"""Checkpoints both ways with real OpenPCDet: one written by OpenPCDet's own train.py (tests/assets/openpcdet) loads
and resumes here, and ours have its structure, so OpenPCDet's resume takes them."""
import pickle
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
    load_params_from_file,
    load_params_with_optimizer,
    read_checkpoint,
    save_checkpoint,
)
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train_loop import train_one_step

REPO = Path(__file__).resolve().parents[2]
# The config it was trained with (its README): cfgs/m3.yaml, smoke profile, a smaller BEV backbone.
TINY_BEV = ["PROFILE", "smoke", "MODEL.BACKBONE_2D.LAYER_NUMS", "[1, 1]", "MODEL.BACKBONE_2D.NUM_FILTERS", "[16, 32]",
            "MODEL.BACKBONE_2D.NUM_UPSAMPLE_FILTERS", "[16, 16]"]
OPENPCDET_KEYS = ["epoch", "it", "model_state", "optimizer_state", "version"]


@pytest.fixture(scope="module")
def reference(openpcdet_checkpoint) -> dict:
    return read_checkpoint(openpcdet_checkpoint)


@pytest.fixture
def cfg():
    cfg = load_config(REPO / "cfgs" / "m3.yaml", TINY_BEV)
    cfg.MODEL.BACKBONE_2D.UPSAMPLE_STRIDES = [1, 2]  # and anchors at its stride 8 (the loader checks both together)
    cfg.MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG[0].feature_map_stride = 8
    # the smoke profile of its time: OpenPCDet's two anchor rotations, boxes not folded
    cfg.MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG[0].anchor_rotations = [0, 1.57]
    steps = cfg.DATA_CONFIG.DATA_PROCESSOR
    cfg.DATA_CONFIG.DATA_PROCESSOR = [step for step in steps if step.NAME != "fold_box_headings"]
    return cfg


def _dataset(cfg) -> SyntheticPersonDataset:
    """Two synthetic frames on the config's grid."""
    voxel = next(step.VOXEL_SIZE for step in cfg.DATA_CONFIG.DATA_PROCESSOR
                 if step.NAME == "transform_points_to_voxels")
    return SyntheticPersonDataset(cfg.DATA_CONFIG.POINT_CLOUD_RANGE, voxel, num_frames=2, seed=3)


def _openpcdet_groups(model: torch.nn.Module) -> list[list[torch.nn.Parameter]]:
    """OpenPCDet's adam_onecycle groups as its .md states them: the leaf modules in order, batch norms apart."""
    leaves = [module for module in model.modules() if not list(module.children())]
    norms = (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d)
    return [[p for m in leaves if not isinstance(m, norms) for p in m.parameters()],
            [p for m in leaves if isinstance(m, norms) for p in m.parameters()]]


def test_openpcdet_checkpoint_loads_safely_and_strictly_into_its_config(openpcdet_checkpoint, reference, cfg,
                                                                        tmp_path):
    with pytest.raises(pickle.UnpicklingError, match="numpy._core.multiarray.scalar"):
        torch.load(openpcdet_checkpoint, map_location="cpu", weights_only=True)  # why an allow-list is needed
    model = build_network(cfg.MODEL, 1, _dataset(cfg))
    checkpoint = load_params_from_file(model, openpcdet_checkpoint, strict=True)
    assert (checkpoint["epoch"], checkpoint["it"], checkpoint["version"]) == (1, 7, "pcdet+0.6.0+8caccce+py0000000")
    assert list(model.state_dict()) == list(reference["model_state"])  # 115 entries, the same order
    for key, value in model.state_dict().items():
        assert torch.equal(value, reference["model_state"][key]), key
    # a file written under numpy 1.x names numpy.core.multiarray.scalar
    old_numpy = tmp_path / "numpy1.pth"
    old_numpy.write_bytes(openpcdet_checkpoint.read_bytes().replace(b"cnumpy._core.multiarray\nscalar\n",
                                                                    b"cnumpy.core.multiarray\nscalar\n"))
    assert read_checkpoint(old_numpy)["optimizer_state"]["param_groups"][0]["lr"] == pytest.approx(9.55e-5, 1e-3)


def test_resume_from_openpcdet_checkpoint_with_its_optimizer_state(openpcdet_checkpoint, reference, cfg):
    dataset = _dataset(cfg)
    model = build_network(cfg.MODEL, 1, dataset)
    optimizer = build_optimizer(model, cfg.OPTIMIZATION)
    assert load_params_with_optimizer(model, openpcdet_checkpoint, optimizer) == (7, 1)
    saved = reference["optimizer_state"]
    assert [len(group["params"]) for group in optimizer.param_groups] == [24, 36]
    for group, saved_group in zip(optimizer.param_groups, saved["param_groups"]):
        for param, index in zip(group["params"], saved_group["params"]):
            state = optimizer.state[param]
            assert state["exp_avg"].shape == param.shape
            assert torch.equal(state["exp_avg"], saved["state"][index]["exp_avg"])
            assert state["step"].item() == 7
        # the config's settings, not OpenPCDet's saved weight_decay 0 and numpy lr
        assert group["weight_decay"] == cfg.OPTIMIZATION.WEIGHT_DECAY and group["decoupled_weight_decay"]
    scheduler = build_scheduler(optimizer, 7, 2, last_epoch=6, optim_cfg=cfg.OPTIMIZATION)
    loader = DataLoader(dataset, batch_size=2, collate_fn=dataset.collate_batch)
    loss, _ = train_one_step(model, optimizer, scheduler, next(iter(loader)), 10.0, "cpu")
    assert torch.isfinite(torch.tensor(loss)) and model.global_step.item() == 8
    assert all(type(group["lr"]) is float for group in optimizer.param_groups)


def test_our_checkpoint_has_openpcdet_structure_and_its_resume_accepts_it(reference, cfg, tmp_path):
    dataset = _dataset(cfg)
    model = build_network(cfg.MODEL, 1, dataset)
    optimizer = build_optimizer(model, cfg.OPTIMIZATION)
    scheduler = build_scheduler(optimizer, 1, 1, last_epoch=-1, optim_cfg=cfg.OPTIMIZATION)
    loader = DataLoader(dataset, batch_size=2, collate_fn=dataset.collate_batch)
    train_one_step(model, optimizer, scheduler, next(iter(loader)), 10.0, "cpu")
    path = save_checkpoint(checkpoint_state(model, optimizer, epoch=1, it=1), tmp_path / "checkpoint_epoch_1.pth")

    ours = torch.load(path, map_location="cpu", weights_only=True)  # plain values: no allow-list needed
    assert list(ours)[:5] == OPENPCDET_KEYS  # then our 'memslidar' record, which OpenPCDet does not read
    assert [(k, v.shape, v.dtype) for k, v in ours["model_state"].items()] == \
        [(k, v.shape, v.dtype) for k, v in reference["model_state"].items()]
    ours_groups, ref_groups = ours["optimizer_state"]["param_groups"], reference["optimizer_state"]["param_groups"]
    assert [g["params"] for g in ours_groups] == [g["params"] for g in ref_groups]  # ids 0-23, then 24-59
    assert all(set(ref) <= set(group) for ref, group in zip(ref_groups, ours_groups))
    for index, state in reference["optimizer_state"]["state"].items():
        assert ours["optimizer_state"]["state"][index]["exp_avg"].shape == state["exp_avg"].shape, index

    # OpenPCDet's resume: its Adam over its own groups loads our optimizer state
    fresh = build_network(cfg.MODEL, 1, dataset)
    fresh.load_state_dict(ours["model_state"], strict=True)
    adam = torch.optim.Adam([{"params": group} for group in _openpcdet_groups(fresh)], lr=0.003, betas=(0.9, 0.99))
    adam.load_state_dict(ours["optimizer_state"])
    for group in adam.param_groups:
        for param in group["params"]:
            assert adam.state[param]["exp_avg"].shape == param.shape


@pytest.mark.slow
def test_a_centerpoint_checkpoint_round_trips_and_a_second_one_is_refused_by_it(tmp_path):
    center_cfg = load_config(REPO / "cfgs" / "centerpoint" / "m3.yaml", ["PROFILE", "smoke"])
    dataset = _dataset(center_cfg)
    model = build_network(center_cfg.MODEL, 1, dataset)
    optimizer = build_optimizer(model, center_cfg.OPTIMIZATION)
    scheduler = build_scheduler(optimizer, 1, 1, last_epoch=-1, optim_cfg=center_cfg.OPTIMIZATION)
    train_one_step(model, optimizer, scheduler, next(iter(DataLoader(dataset, batch_size=2,
                                                                      collate_fn=dataset.collate_batch))), 10.0, "cpu")
    path = save_checkpoint(checkpoint_state(model, optimizer, epoch=1, it=1), tmp_path / "checkpoint_epoch_1.pth")
    ours = torch.load(path, map_location="cpu", weights_only=True)
    assert list(ours)[:5] == OPENPCDET_KEYS
    fresh = build_network(center_cfg.MODEL, 1, dataset)
    load_params_from_file(fresh, path, strict=True)
    assert all(torch.equal(a, b) for a, b in zip(fresh.state_dict().values(), model.state_dict().values()))
    adam = torch.optim.Adam([{"params": group} for group in _openpcdet_groups(fresh)], lr=0.003, betas=(0.9, 0.99))
    adam.load_state_dict(ours["optimizer_state"])  # OpenPCDet's resume takes it

    second_cfg = load_config(REPO / "cfgs" / "m3.yaml", ["PROFILE", "smoke"])
    second = build_network(second_cfg.MODEL, 1, dataset)
    second_path = save_checkpoint(checkpoint_state(second, None, epoch=1, it=1), tmp_path / "second.pth")
    with pytest.raises(DataFormatError, match=r"does not fit the model of this config: .*dense_head.*Use the config"):
        load_params_from_file(fresh, second_path, strict=True)
