"""CenterPoint's center head: exact Gaussian targets (radius, peak, overlapping people, map edges), exact losses,
decoding that returns the boxes the targets were made of, OpenPCDet's state-dict names, and a detector that learns."""
import copy
import logging
import math

import numpy as np
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar.config import CONFIG_DIR, cfg_from_yaml_file
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.models.centernet import (
    assign_center_targets,
    decode_heatmap,
    draw_gaussian,
    gaussian_kernel,
    gaussian_radius,
)
from pcdet_memslidar.models.losses import FocalLossCenterNet, RegLossCenterNet
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch

CENTERPOINT_CFG = CONFIG_DIR / "memslidar_models" / "centerpoint_person.yaml"


@pytest.fixture(scope="module")
def center_model_cfg(small_model_cfg, small_range):
    """center_model_cfg() -> the small SECOND's MODEL with the shipped CenterPoint's NAME and head (stride 8)."""
    shipped = cfg_from_yaml_file(CENTERPOINT_CFG).MODEL

    def make() -> EasyDict:
        cfg = small_model_cfg()
        cfg.NAME, cfg.DENSE_HEAD = shipped.NAME, copy.deepcopy(shipped.DENSE_HEAD)
        cfg.DENSE_HEAD.POST_PROCESSING.POST_CENTER_LIMIT_RANGE = list(small_range)
        return cfg
    return make


def test_gaussian_radius_is_cornernets_smallest_bound():
    # 4 x 4 cells at overlap 0.5: the third bound, (-8 + sqrt(64 + 64)) / 2 = 4 sqrt(2) - 4
    radius = gaussian_radius(torch.tensor([4.0], dtype=torch.float64), torch.tensor([4.0], dtype=torch.float64), 0.5)
    assert radius.item() == pytest.approx(4 * math.sqrt(2) - 4, abs=1e-12)
    # a person at the quick stride (2 x 1.5 cells) at OpenPCDet's overlap 0.1: (-0.7 + sqrt(4.81)) / 2 = 0.7466,
    # below MIN_RADIUS 2, which is what assign_center_targets then draws
    radius = gaussian_radius(torch.tensor([2.0], dtype=torch.float64), torch.tensor([1.5], dtype=torch.float64), 0.1)
    assert radius.item() == pytest.approx((-0.7 + math.sqrt(4.81)) / 2, abs=1e-12)


def test_gaussian_kernel_values():
    kernel = gaussian_kernel(2)  # sigma = 5 / 6: exp(-d^2 / (2 sigma^2)) = exp(-0.72 d^2)
    assert kernel.shape == (5, 5) and kernel[2, 2] == 1.0
    assert kernel[2, 3] == pytest.approx(math.exp(-0.72), abs=1e-15)
    assert kernel[0, 0] == pytest.approx(math.exp(-0.72 * 8), abs=1e-15)
    assert (kernel == kernel.T).all() and (kernel == kernel[::-1]).all()


def test_peak_is_exactly_one_and_overlapping_people_keep_the_maximum():
    heatmap = torch.zeros(9, 12)
    draw_gaussian(heatmap, (5, 4), 2)
    draw_gaussian(heatmap, (7, 4), 2)
    assert heatmap[4, 5] == 1.0 and heatmap[4, 7] == 1.0  # each peak stays 1 (max, not sum)
    assert heatmap[4, 6] == pytest.approx(math.exp(-0.72), abs=1e-7)  # between them: the larger of two equal
    assert heatmap[4, 8] == pytest.approx(math.exp(-0.72), abs=1e-7)
    assert heatmap[4, 3] == pytest.approx(math.exp(-0.72 * 4), abs=1e-7)
    assert heatmap[4, 10] == 0.0 and heatmap[7, 5] == 0.0  # outside both radii
    assert int((heatmap == 1).sum()) == 2


def test_a_person_at_the_map_corner_is_clipped_not_lost():
    heatmap = torch.zeros(6, 6)
    draw_gaussian(heatmap, (0, 0), 2)
    assert heatmap[0, 0] == 1.0 and heatmap[2, 2] == pytest.approx(math.exp(-0.72 * 8), abs=1e-7)
    assert int((heatmap > 0).sum()) == 9  # the 3 x 3 quarter of the 5 x 5 kernel inside the map


def test_targets_of_one_person_and_of_two_in_one_cell():
    pc_range, voxel, stride = [0.0, -4.0, -1.0, 8.0, 4.0, 3.0], [0.1, 0.1, 0.1], 4  # 20 x 20 cells of 0.4 m
    boxes = torch.tensor([[1.3, -0.5, 0.9, 0.8, 0.6, 1.8, 0.3, 1],
                          [1.35, -0.45, 0.85, 0.7, 0.5, 1.7, -0.2, 1],  # the same cell as the first
                          [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0]])  # padding: skipped
    heatmap, target, inds, mask = assign_center_targets(boxes, 1, (20, 20), pc_range, voxel, stride, 4, 0.1, 2)
    # x 1.3 m -> 3.25 cells (column 3, offset 0.25); y -0.5 m -> 8.75 cells (row 8, offset 0.75)
    assert inds.tolist() == [8 * 20 + 3, 8 * 20 + 3, 0, 0] and mask.tolist() == [1, 1, 0, 0]
    assert heatmap[0, 8, 3] == 1.0 and int((heatmap == 1).sum()) == 1
    expected = [0.25, 0.75, 0.9, math.log(0.8), math.log(0.6), math.log(1.8), math.cos(0.3), math.sin(0.3)]
    assert target[0].tolist() == pytest.approx(expected, abs=1e-6)
    assert target[1, :2].tolist() == pytest.approx([0.375, 0.875], abs=1e-6)
    assert (target[2:] == 0).all()


def test_decoding_returns_the_boxes_the_targets_were_made_of():
    pc_range, voxel, stride = [0.0, -4.0, -1.0, 8.0, 4.0, 3.0], [0.1, 0.1, 0.1], 4
    boxes = torch.tensor([[1.3, -0.5, 0.9, 0.8, 0.6, 1.8, 0.3, 1], [6.1, 2.2, 0.8, 0.7, 0.5, 1.6, -2.9, 1]])
    heatmap, target, inds, mask = assign_center_targets(boxes, 1, (20, 20), pc_range, voxel, stride, 8, 0.1, 2)
    maps = torch.zeros(1, 8, 20, 20)  # the code written at its centre cells: what a perfect head outputs
    maps.view(1, 8, -1)[0, :, inds[mask > 0]] = target[mask > 0].T
    decoded = decode_heatmap(heatmap[None], maps[:, 0:2], maps[:, 2:3], maps[:, 3:6].exp(), maps[:, 6:8], pc_range,
                             voxel, stride, 500, 0.99, pc_range)[0]
    assert decoded["pred_scores"].tolist() == [1.0, 1.0] and decoded["pred_labels"].tolist() == [0, 0]
    order = decoded["pred_boxes"][:, 0].argsort()
    assert decoded["pred_boxes"][order].numpy() == pytest.approx(boxes[:, :7].numpy(), abs=1e-5)


def test_heatmap_focal_loss_and_centre_l1_exact():
    probability = torch.tensor([0.9, 0.2, 0.3]).view(1, 1, 1, 3)
    target = torch.tensor([1.0, 0.5, 0.0]).view(1, 1, 1, 3)
    # one peak: -(log 0.9 x 0.1^2 + log 0.8 x 0.2^2 x 0.5^4 + log 0.7 x 0.3^2 x 1) / 1
    expected = -(math.log(0.9) * 0.01 + math.log(0.8) * 0.04 * 0.0625 + math.log(0.7) * 0.09)
    assert FocalLossCenterNet()(probability, target).item() == pytest.approx(expected, rel=1e-6)
    no_peak = FocalLossCenterNet()(probability, torch.zeros_like(target)).item()  # not divided by 0 peaks
    assert no_peak == pytest.approx(-(math.log(0.1) * 0.81 + math.log(0.8) * 0.04 + math.log(0.7) * 0.09), rel=1e-6)

    output = torch.arange(8.0).view(1, 2, 2, 2)  # code of 2 channels on a 2 x 2 map
    inds, mask = torch.tensor([[3, 0, 1]]), torch.tensor([[1, 1, 0]])
    target = torch.tensor([[[2.0, 7.0], [1.0, 4.0], [9.0, 9.0]]])  # cells 3 -> (3, 7), 0 -> (0, 4); third masked
    loss = RegLossCenterNet()(output, mask, inds, target)
    assert loss.tolist() == pytest.approx([(1 + 1) / 2, (0 + 0) / 2])


def test_state_dict_has_openpcdets_centerpoint_names(center_model_cfg, fake_dataset, small_range, person_voxel):
    model = build_network(center_model_cfg(), 1, fake_dataset(small_range, person_voxel))
    head = {key[len("dense_head."):]: tuple(value.shape) for key, value in model.state_dict().items()
            if key.startswith("dense_head.")}
    batch_norm = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    expected = {"shared_conv.0.weight": (64, 128, 3, 3), "shared_conv.0.bias": (64,)}
    expected |= {f"shared_conv.1.{name}": () if name == "num_batches_tracked" else (64,) for name in batch_norm}
    for branch, channels in {"center": 2, "center_z": 1, "dim": 3, "rot": 2, "hm": 1}.items():
        expected[f"heads_list.0.{branch}.0.0.weight"] = (64, 64, 3, 3)
        expected[f"heads_list.0.{branch}.0.0.bias"] = (64,)  # USE_BIAS_BEFORE_NORM: True
        expected |= {f"heads_list.0.{branch}.0.1.{name}": () if name == "num_batches_tracked" else (64,)
                     for name in batch_norm}
        expected[f"heads_list.0.{branch}.1.weight"] = (channels, 64, 3, 3)
        expected[f"heads_list.0.{branch}.1.bias"] = (channels,)
    assert head == expected
    assert model.dense_head.heads_list[0].hm[-1].bias.tolist() == pytest.approx([-2.19])
    body = {key for key in model.state_dict() if not key.startswith("dense_head.")}
    second = build_network(EasyDict(center_model_cfg() | {"NAME": "SECONDNet", "DENSE_HEAD": _anchor_head()}), 1,
                           fake_dataset(small_range, person_voxel))
    assert body == {key for key in second.state_dict() if not key.startswith("dense_head.")}


def _anchor_head() -> EasyDict:
    return cfg_from_yaml_file(CONFIG_DIR / "memslidar_models" / "second_person.yaml").MODEL.DENSE_HEAD


@pytest.mark.parametrize("change, message", [
    (("TARGET_ASSIGNER_CONFIG", "FEATURE_MAP_STRIDE", 4), "FEATURE_MAP_STRIDE is 4 but BACKBONE_2D"),
    (("SEPARATE_HEAD_CFG", "HEAD_ORDER", ["center", "center_z", "dim", "rot", "vel"]), "no velocity or IoU branch"),
    (("POST_PROCESSING", "NMS_CONFIG", {"NMS_TYPE": "circle_nms"}), "circle_nms is not supported"),
])
def test_settings_the_head_does_not_take_are_refused(change, message, center_model_cfg, fake_dataset, small_range,
                                                     person_voxel):
    cfg = center_model_cfg()
    block, key, value = change
    cfg.DENSE_HEAD[block][key] = value
    with pytest.raises(ConfigError, match=message):
        build_network(cfg, 1, fake_dataset(small_range, person_voxel))
    with pytest.raises(ConfigError, match="MODEL.NAME CenterPoint takes DENSE_HEAD.NAME CenterHead"):
        build_network(EasyDict(center_model_cfg() | {"DENSE_HEAD": _anchor_head()}), 1,
                      fake_dataset(small_range, person_voxel))


def test_every_parameter_gets_a_finite_gradient_with_empty_and_boxless_frames(center_model_cfg, small_range,
                                                                             person_voxel):
    frames = SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=3, empty_frames=(2,),
                                    no_box_frames=(3,))
    torch.manual_seed(0)
    model = build_network(center_model_cfg(), 1, frames).train()
    ret, tb_dict, _ = model(load_data_to_device(frames.collate_batch([frames[i] for i in range(4)]), "cpu"))
    ret["loss"].backward()
    assert torch.isfinite(ret["loss"]) and set(tb_dict) >= {"hm_loss_head_0", "loc_loss_head_0", "rpn_loss"}
    for name, parameter in model.named_parameters():
        assert parameter.grad is not None and torch.isfinite(parameter.grad).all(), name
        assert parameter.grad.abs().sum() > 0, name
    model.eval()
    with torch.no_grad():
        alone, recall = model(load_data_to_device(frames.collate_batch([frames[2]]), "cpu"))  # no voxel at all
    assert alone[0]["pred_boxes"].shape[1] == 7 and recall["gt"] == len(frames.frames[2]["gt_boxes"]) > 0


@pytest.mark.slow
def test_overfits_a_handful_of_frames_in_fp32_and_bf16(tmp_path, center_model_cfg, overfit, small_range,
                                                      person_voxel):
    dataset = SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=0)
    torch.manual_seed(0)
    model = build_network(center_model_cfg(), 1, dataset)
    epochs = 80  # 40 reached AP 1.0 for 2 of 4 seeds (one person of 6 missed otherwise), 80 for 6 of 6
    one_by_one = overfit(model, dataset, epochs, tmp_path)
    cfg = EasyDict(MODEL=center_model_cfg())
    result = eval_one_epoch(cfg, model, one_by_one, epochs, logging.getLogger("test"), "cpu", result_dir=tmp_path)
    assert result["AP3D_R40"] >= 0.9 and np.isclose(result["recall/rcnn_0.5"], 1.0), result
    model.set_precision("bf16")
    bf16 = eval_one_epoch(cfg, model, one_by_one, epochs, logging.getLogger("test"), "cpu",
                          result_dir=tmp_path / "bf16")
    assert bf16["AP3D_R40"] >= 0.9, bf16
    model.set_precision("fp32")
    model.box_from_points = (5, 0.1, 0.0, None, None)  # POST_PROCESSING.BOX_FROM_POINTS, applied by the template
    model.eval()
    with torch.no_grad():
        pred_dicts, _ = model(load_data_to_device(next(iter(one_by_one)), "cpu"))
    boxes = pred_dicts[0]["pred_boxes"]
    assert len(boxes) and (boxes[:, 3] >= boxes[:, 4]).all()
    oriented = eval_one_epoch(cfg, model, one_by_one, epochs, logging.getLogger("test"), "cpu",
                              result_dir=tmp_path / "oriented")
    assert oriented["AP3D_R40"] >= 0.9, oriented  # boxes filled with points: their main axis is the long side


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_training_step_and_inference_on_the_gpu_match_the_cpu(center_model_cfg, small_range, person_voxel):
    frames = SyntheticPersonDataset(small_range, person_voxel, num_frames=2, seed=5)
    torch.manual_seed(0)
    model = build_network(center_model_cfg(), 1, frames)
    gpu = copy.deepcopy(model).cuda()
    batch = frames.collate_batch([frames[0], frames[1]])
    cpu_loss = model.train()(load_data_to_device(copy.deepcopy(batch), "cpu"))[0]["loss"]
    gpu_loss = gpu.train()(load_data_to_device(copy.deepcopy(batch), "cuda"))[0]["loss"]
    assert gpu_loss.item() == pytest.approx(cpu_loss.item(), rel=1e-3)
    with torch.no_grad():
        preds, _ = gpu.eval()(load_data_to_device(copy.deepcopy(batch), "cuda"))
    assert preds[0]["pred_boxes"].device.type == "cuda" and preds[0]["pred_boxes"].shape[1] == 7
