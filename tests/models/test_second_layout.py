"""SECOND's structure: OpenPCDet's state dict entry by entry, strict loading, anchors, grid checks."""
from pathlib import Path

import pytest
import torch

from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network, load_data_to_device

# Measured from OpenPCDet (commit 8cacccec) on CPU for the person config; the .tsv file beside this test.
REFERENCE = Path(__file__).with_name("openpcdet_second_person_state_dict.tsv")


@pytest.fixture(scope="module")
def person_model(second_model_cfg, fake_dataset):
    torch.manual_seed(0)
    return build_network(second_model_cfg(), num_class=1, dataset=fake_dataset())


def _reference_rows():
    rows = [line.split("\t") for line in REFERENCE.read_text().splitlines() if not line.startswith("#")]
    return [(key, [int(v) for v in shape.strip("[]").split(",") if v.strip()], dtype) for key, shape, dtype in rows]


def test_state_dict_matches_openpcdet_entry_by_entry(person_model):
    state = person_model.state_dict()
    reference = _reference_rows()
    assert len(state) == len(reference) == 163
    for (key, tensor), (ref_key, ref_shape, ref_dtype) in zip(state.items(), reference):
        assert key == ref_key
        assert list(tensor.shape) == ref_shape, key
        assert str(tensor.dtype).removeprefix("torch.") == ref_dtype, key
    assert sum(p.numel() for p in person_model.parameters()) == 5_298_900


def test_anchor_count_and_placement_follow_the_point_cloud_range(person_model, person_range):
    head = person_model.dense_head
    anchors = head.anchors[0]
    assert tuple(anchors.shape) == (1, 64, 64, 1, 2, 7)  # 512 / 8 cells, 2 rotations
    flat = head.flat_anchors()
    assert flat.shape == (8192, 7)
    x0, y0, _, x1, y1, _ = person_range
    assert flat[:, 0].min().item() == pytest.approx(x0) and flat[:, 0].max().item() == pytest.approx(x1, abs=1e-4)
    assert flat[:, 1].min().item() == pytest.approx(y0) and flat[:, 1].max().item() == pytest.approx(y1, abs=1e-4)
    assert torch.allclose(flat[:, 2], torch.full((8192,), 0.0 + 1.73 / 2))  # bottom 0 -> centre
    assert torch.equal(flat[:2, 6], torch.tensor([0.0, 1.57]))
    # x varies fastest after the per-location anchors: consecutive locations step along x by range / (64 - 1)
    assert flat[2, 0].item() == pytest.approx((x1 - x0) / 63, abs=1e-5)
    assert flat[2, 1].item() == pytest.approx(y0)
    # anchors are not part of the state dict but follow the module's device / dtype
    assert not any("anchor" in key for key in person_model.state_dict())
    assert head.to(torch.float64).flat_anchors().dtype == torch.float64
    head.to(torch.float32)


def test_checkpoint_loads_strictly_both_ways(person_model, second_model_cfg, fake_dataset):
    other = build_network(second_model_cfg(), num_class=1, dataset=fake_dataset())
    other.load_state_dict(person_model.state_dict(), strict=True)
    person_model.load_state_dict(other.state_dict(), strict=True)
    for (key, a), b in zip(person_model.state_dict().items(), other.state_dict().values()):
        assert torch.equal(a, b), key


@pytest.mark.parametrize("pc_range, voxel, message", [
    ([0.0, -20.48, -0.5, 40.88, 20.48, 3.5], [0.08, 0.08, 0.1], "multiples of 16"),  # 511 x cells
    ([0.0, -20.48, -0.5, 40.96, 20.48, 3.0], [0.08, 0.08, 0.1], "NUM_BEV_FEATURES"),  # 35 z cells
])
def test_grids_that_do_not_fit_are_refused_with_the_fix(pc_range, voxel, message, second_model_cfg, fake_dataset):
    with pytest.raises(ConfigError, match=message):
        build_network(second_model_cfg(), num_class=1, dataset=fake_dataset(pc_range, voxel))


def _one_level_stride_4_head(small_model_cfg):
    cfg = small_model_cfg()
    cfg.BACKBONE_2D.update(LAYER_NUMS=[1], LAYER_STRIDES=[1], NUM_FILTERS=[32], UPSAMPLE_STRIDES=[2],
                           NUM_UPSAMPLE_FILTERS=[64])
    cfg.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG[0].feature_map_stride = 4
    return cfg


@pytest.mark.parametrize("model_cfg, pc_range, grid", [
    ("small_model_cfg", [0.0, -5.12, -0.5, 10.24, 5.12, 4.2], [128, 128, 47]),  # the former loader rule: 40 z only
    ("small_model_cfg", [0.0, -5.12, -0.5, 10.24, 5.12, 5.0], [128, 128, 55]),
    ("one_level_stride_4_head", [0.0, -4.8, -0.5, 9.6, 4.8, 3.5], [120, 120, 40]),  # the former rule: x, y 16 x n
])
def test_grids_the_rule_takes_run_and_the_bev_map_has_the_anchors_size(model_cfg, pc_range, grid, small_model_cfg,
                                                                       person_voxel):
    frames = SyntheticPersonDataset(pc_range, person_voxel, num_frames=2, seed=1)
    assert frames.grid_size.tolist() == grid
    torch.manual_seed(0)
    cfg = _one_level_stride_4_head(small_model_cfg) if model_cfg == "one_level_stride_4_head" else small_model_cfg()
    model = build_network(cfg, num_class=1, dataset=frames).train()
    ret, _, _ = model(load_data_to_device(frames.collate_batch([frames[0], frames[1]]), "cpu"))
    assert torch.isfinite(ret["loss"])
    cls_preds = model.dense_head.forward_ret_dict["cls_preds"]  # (B, H, W, anchors per location)
    assert tuple(cls_preds.shape[1:3]) == tuple(model.dense_head.anchors[0].shape[1:3])


def test_unknown_module_name_is_refused(second_model_cfg, fake_dataset):
    cfg = second_model_cfg()
    cfg.BACKBONE_2D.NAME = "NoSuchBackbone"
    with pytest.raises(ConfigError, match="BaseBEVBackbone"):
        build_network(cfg, num_class=1, dataset=fake_dataset())
