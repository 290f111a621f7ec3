"""SECOND learns: every parameter gets a gradient, empty frames are handled, a few frames are overfitted (and found
as well in bf16 inference), and a GPU gives the CPU's loss and gradients."""
import copy
import logging
import pickle

import numpy as np
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch


@pytest.fixture(scope="module")
def frames(small_range, person_voxel):
    return SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=3, empty_frames=(2,),
                                  no_box_frames=(3,))


@pytest.fixture(scope="module")
def seeded_model(small_model_cfg):
    """seeded_model(dataset, seed=0) -> the small SECOND for `dataset`, initialised under `seed`."""
    def make(dataset, seed=0):
        torch.manual_seed(seed)
        return build_network(small_model_cfg(), num_class=1, dataset=dataset)
    return make


def test_every_parameter_gets_a_finite_gradient_with_empty_and_boxless_frames(frames, seeded_model):
    model = seeded_model(frames).train()
    batch = load_data_to_device(frames.collate_batch([frames[i] for i in range(4)]), "cpu")
    assert (batch["voxel_coords"][:, 0] == 2).sum() == 0  # frame 2 has no points
    assert batch["gt_boxes"][3].abs().sum() == 0  # frame 3 has no boxes
    ret, tb_dict, _ = model(batch)
    ret["loss"].backward()
    assert torch.isfinite(ret["loss"]) and set(tb_dict) >= {"rpn_loss_cls", "rpn_loss_loc", "rpn_loss_dir"}
    for name, parameter in model.named_parameters():
        assert parameter.grad is not None, name
        assert torch.isfinite(parameter.grad).all(), name
        assert parameter.grad.abs().sum() > 0, name


def test_inference_on_empty_and_boxless_frames(frames, seeded_model):
    model = seeded_model(frames).eval()
    with torch.no_grad():
        preds, recall = model(load_data_to_device(frames.collate_batch([frames[i] for i in range(4)]), "cpu"))
        alone, _ = model(load_data_to_device(frames.collate_batch([frames[2]]), "cpu"))  # no voxel in the batch
    assert len(preds) == 4 and len(alone) == 1
    for pred in preds + alone:
        assert pred["pred_boxes"].shape[1] == 7 and len(pred["pred_scores"]) == len(pred["pred_labels"])
        assert torch.isfinite(pred["pred_boxes"]).all()
    assert recall["gt"] == sum(len(frames.frames[i]["gt_boxes"]) for i in range(4))


@pytest.mark.slow
def test_overfits_a_handful_of_frames_to_ap_above_0_9(tmp_path, seeded_model, small_model_cfg, overfit, small_range,
                                                     person_voxel):
    dataset = SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=0)
    model = seeded_model(dataset)
    epochs = 30
    one_by_one = overfit(model, dataset, epochs, tmp_path)
    cfg = EasyDict(MODEL=small_model_cfg())
    result = eval_one_epoch(cfg, model, one_by_one, epochs, logging.getLogger("test"), "cpu", result_dir=tmp_path)
    assert result["AP3D_R40"] >= 0.9 and result["APBEV_R40"] >= 0.9, result
    assert result["infer_time_ms"] > 0 and (tmp_path / "result.pkl").is_file()
    assert np.isclose(result["recall/rcnn_0.5"], 1.0)

    # bf16 in the BEV backbone and head: the same people found, boxes within 2 cm (4 mm measured), the AP kept
    model.set_precision("bf16")
    bf16 = eval_one_epoch(cfg, model, one_by_one, epochs, logging.getLogger("test"), "cpu",
                          result_dir=tmp_path / "bf16")
    assert bf16["AP3D_R40"] >= 0.9 and np.isclose(bf16["recall/rcnn_0.5"], 1.0), bf16
    shifts = []  # per confident fp32 box: the nearest bf16 box's largest parameter difference
    for fp32_frame, bf16_frame in zip(*(pickle.loads((folder / "result.pkl").read_bytes())
                                        for folder in (tmp_path, tmp_path / "bf16"))):
        for box in fp32_frame["boxes_lidar"][fp32_frame["score"] >= 0.5]:
            shifts.append(np.abs(bf16_frame["boxes_lidar"] - box).max(axis=1).min())
    assert len(shifts) >= 4 and 0 < max(shifts) <= 0.02, shifts  # > 0: bf16 did run
    with pytest.raises(ConfigError, match="precision 'fp16'"):
        model.set_precision("fp16")


def test_bf16_training_runs_the_bev_part_in_bf16_and_keeps_loss_and_weights_fp32(frames, seeded_model):
    """set_precision('bf16', training=True): the BEV backbone and head compute in bfloat16, their outputs come back
    in fp32 for the loss, which is within 2 % of the fp32 loss; every gradient is fp32 and finite; inference keeps
    its own precision."""
    batch = frames.collate_batch([frames[i] for i in range(2)])
    losses, dtypes = {}, {}
    for precision in ("fp32", "bf16"):
        model = seeded_model(frames).train()
        model.set_precision(precision, training=True)
        handle = model.backbone_2d.blocks[0].register_forward_hook(
            lambda module, args, out, key=precision: None if dtypes.setdefault(key, out.dtype) else None)
        ret, _, _ = model(load_data_to_device(dict(batch), "cpu"))
        handle.remove()
        ret["loss"].backward()
        losses[precision] = ret["loss"]
        assert model.precision == "fp32" and model.train_precision == precision
        assert all(value.dtype == torch.float32 for value in model.dense_head.forward_ret_dict.values()
                   if value.is_floating_point())
        for name, parameter in model.named_parameters():
            assert parameter.dtype == parameter.grad.dtype == torch.float32, name
            assert torch.isfinite(parameter.grad).all(), name
    assert dtypes == {"fp32": torch.float32, "bf16": torch.bfloat16}
    assert losses["bf16"].dtype == torch.float32
    assert losses["bf16"].item() != losses["fp32"].item()
    assert abs(losses["bf16"].item() - losses["fp32"].item()) <= 0.02 * losses["fp32"].item()


@pytest.mark.parametrize("has_bf16, expected", [(True, "bf16"), (False, "fp32")])
def test_use_amp_on_the_cpu_trains_the_bev_part_in_bf16_only_where_the_cpu_has_bf16_units(
        tmp_path, frames, seeded_model, small_optim_cfg, monkeypatch, caplog, has_bf16, expected):
    from torch.utils.data import DataLoader

    from pcdet_memslidar.runtime import train_loop
    from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler

    monkeypatch.setattr(train_loop, "cpu_has_bf16", lambda: has_bf16)
    model = seeded_model(frames)
    optim_cfg = EasyDict(small_optim_cfg() | {"USE_AMP": True})
    loader = DataLoader(frames, batch_size=2, shuffle=False, collate_fn=frames.collate_batch)
    optimizer = build_optimizer(model, optim_cfg)
    scheduler = build_scheduler(optimizer, len(loader), 1, -1, optim_cfg)
    with caplog.at_level(logging.INFO):
        train_loop.train_model(model, optimizer, loader, scheduler, optim_cfg, 0, 1, 0, 0, None, tmp_path, "cpu",
                               use_tqdm_to_record=True, logger=logging.getLogger("test"))
    assert model.train_precision == expected and model.precision == "fp32"
    assert ("this CPU has no bfloat16 units" in caplog.text) == (not has_bf16)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_training_step_and_inference_on_the_gpu_match_the_cpu(frames, seeded_model):
    """spconv's CUDA kernels against its CPU path (empty and boxless frames included): the same loss, gradients
    pointing the same way (the GPU's convolutions may run in TF32), boxes on the GPU."""
    model = seeded_model(frames).train()
    gpu = copy.deepcopy(model).cuda()
    batch = frames.collate_batch([frames[i] for i in range(4)])
    cpu_loss = model(load_data_to_device(copy.deepcopy(batch), "cpu"))[0]["loss"]
    gpu_loss = gpu(load_data_to_device(copy.deepcopy(batch), "cuda"))[0]["loss"]
    assert gpu_loss.item() == pytest.approx(cpu_loss.item(), rel=1e-3)
    cpu_loss.backward()
    gpu_loss.backward()
    for (name, on_cpu), on_gpu in zip(model.named_parameters(), gpu.parameters()):
        cosine = torch.nn.functional.cosine_similarity(on_cpu.grad.flatten(), on_gpu.grad.cpu().flatten(), dim=0)
        assert cosine > 0.999, (name, cosine.item())
    with torch.no_grad():
        preds, _ = gpu.eval()(load_data_to_device(copy.deepcopy(batch), "cuda"))
    assert preds[0]["pred_boxes"].device.type == "cuda" and preds[0]["pred_boxes"].shape[1] == 7
