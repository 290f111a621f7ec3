"""Numerical hard cases of the SECOND head: saturated logits, extreme residuals, headings near +-pi."""
import math

import pytest
import torch

from pcdet_memslidar.models import build_network
from pcdet_memslidar.models.box_coder import LOG_SIZE_CLIP, ResidualCoder
from pcdet_memslidar.models.losses import SigmoidFocalClassificationLoss, add_sin_difference, direction_targets
from pcdet_memslidar.models.target_assigner import nearest_bev_iou

ANCHOR = torch.tensor([[5.0, 1.0, 0.865, 0.8, 0.6, 1.73, 0.0]])


def test_focal_loss_is_finite_for_saturated_logits():
    logits = torch.tensor([[[100.0], [-100.0], [100.0], [-100.0]]], requires_grad=True)
    targets = torch.tensor([[[1.0], [0.0], [0.0], [1.0]]])
    loss = SigmoidFocalClassificationLoss()(logits, targets, torch.ones(1, 4))
    loss.sum().backward()
    assert torch.isfinite(loss).all() and torch.isfinite(logits.grad).all()
    # right and confident: ~0; wrong and confident: alpha-weighted BCE of 100 (focal weight 1)
    assert loss[0, 0, 0].item() == pytest.approx(0.0, abs=1e-30)
    assert loss[0, 2, 0].item() == pytest.approx(0.75 * 100.0, rel=1e-6)
    assert loss[0, 3, 0].item() == pytest.approx(0.25 * 100.0, rel=1e-6)


def test_decoding_extreme_residuals_stays_finite_with_clamped_sizes():
    coder = ResidualCoder()
    residuals = torch.tensor([[1e6, -1e6, 1e6, 1e6, -1e6, 88.0, 1e6]])
    boxes = coder.decode_torch(residuals, ANCHOR)
    assert torch.isfinite(boxes).all()
    assert boxes[0, 3].item() == pytest.approx(0.8 * math.exp(LOG_SIZE_CLIP), rel=1e-5)
    assert boxes[0, 4].item() == pytest.approx(0.6 * math.exp(-LOG_SIZE_CLIP), rel=1e-5)


def test_encode_decode_round_trip_with_headings_near_pi():
    coder = ResidualCoder()
    for heading in (math.pi - 1e-6, -math.pi + 1e-6, math.pi, -math.pi):
        box = torch.tensor([[5.3, 0.7, 0.9, 0.6, 0.5, 1.8, heading]], dtype=torch.float64)
        decoded = coder.decode_torch(coder.encode_torch(box, ANCHOR.double()), ANCHOR.double())
        assert torch.allclose(decoded, box, atol=1e-9)


def test_sin_difference_ignores_a_flip_by_pi_and_direction_bins_tell_it_apart():
    prediction = torch.tensor([[[0, 0, 0, 0, 0, 0, math.pi - 1e-4]]])
    target = torch.tensor([[[0, 0, 0, 0, 0, 0, -math.pi + 1e-4]]])
    pred_sin, target_sin = add_sin_difference(prediction, target)
    assert abs((pred_sin - target_sin)[0, 0, 6].item()) < 1e-3  # sin(2pi - 2e-4)
    headings = torch.tensor([math.pi - 1e-4, -math.pi + 1e-4, 0.0])
    targets = torch.zeros(1, 3, 7)
    targets[..., 6] = headings
    bins = direction_targets(torch.zeros(1, 3, 7), targets, 0.78539, 2)
    assert bins.argmax(-1).tolist() == [[0, 0, 1]]  # +-pi: one direction; 0: the opposite bin


def test_predicted_heading_near_pi_decodes_to_the_same_direction(small_model_cfg, fake_dataset, small_range):
    model = build_network(small_model_cfg(), 1, fake_dataset(small_range)).eval()
    head = model.dense_head
    anchors = head.flat_anchors()
    for target in (math.pi - 1e-3, -math.pi + 1e-3):
        residual = torch.zeros(1, anchors.shape[0], 7)
        residual[..., 6] = target - anchors[:, 6]
        direction = torch.zeros(1, anchors.shape[0], 2)
        bin_index = direction_targets(anchors[None], residual, head.model_cfg.DIR_OFFSET, 2).argmax(-1)
        direction.scatter_(-1, bin_index[..., None], 5.0)
        _, boxes = head.generate_predicted_boxes(1, torch.zeros(1, anchors.shape[0], 1), residual, direction)
        wrapped = torch.remainder(boxes[0, :, 6] - target + math.pi, 2 * math.pi) - math.pi
        assert wrapped.abs().max().item() < 1e-4


def test_nearest_bev_iou_snaps_heading_to_axis():
    box = torch.tensor([[0.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0]])
    turned = torch.tensor([[0.0, 0.0, 0.0, 1.0, 2.0, 1.0, math.pi / 2]])
    near_pi = torch.tensor([[0.0, 0.0, 0.0, 2.0, 1.0, 1.0, -math.pi + 0.1]])
    assert nearest_bev_iou(box, turned).item() == pytest.approx(1.0)
    assert nearest_bev_iou(box, near_pi).item() == pytest.approx(1.0)
    assert nearest_bev_iou(box, box[:, [0, 1, 2, 4, 3, 5, 6]]).item() == pytest.approx(1 / 3)


def test_post_processing_drops_boxes_no_person_can_have(small_model_cfg):
    """Saturated size regressions (50 m long, 2 cm thin, NaN, inf) never become detections; a person does.
    Limits are the anchor [0.8, 0.6, 1.73] times SIZE_RATIO_RANGE [0.3, 2.0], bounds included."""
    from pcdet_memslidar.models.post_processing import post_processing, size_limits
    cfg = small_model_cfg()
    limits = size_limits(cfg.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG, ["Pedestrian"], [0.3, 2.0])
    anchor = torch.tensor([0.8, 0.6, 1.73])
    assert torch.equal(limits, torch.stack([anchor * 0.3, anchor * 2.0])[None])
    boxes = torch.tensor([
        [5.0, 0.0, 0.85, 0.7, 0.5, 1.7, 0.0],        # a person
        [10.0, 0.0, 0.85, 50.0, 0.5, 1.7, 0.0],      # 50 m long
        [15.0, 0.0, 0.85, 0.7, 0.02, 1.7, 0.0],      # 2 cm thin
        [20.0, 0.0, 0.85, 0.7, 0.5, float("nan"), 0.0],
        [25.0, 0.0, 0.85, float("inf"), 0.5, 1.7, 0.0],
        [30.0, 0.0, 0.85, 0.0, 0.0, 0.0, 0.0],       # sizes set to the limits below: kept
    ])
    boxes[5, 3:6] = torch.stack([anchor[0] * 2.0, anchor[1] * 0.3, anchor[2] * 2.0])
    batch = {"batch_size": 1, "batch_box_preds": boxes[None], "batch_cls_preds": torch.full((1, 6, 1), 5.0),
             "cls_preds_normalized": False}
    pred_dicts = post_processing(batch, cfg.POST_PROCESSING, limits)
    kept = sorted(pred_dicts[0]["pred_boxes"][:, 0].tolist())
    assert kept == [5.0, 30.0]
    unfiltered = post_processing(batch, cfg.POST_PROCESSING)
    assert len(unfiltered[0]["pred_boxes"]) >= 3  # without limits the saturated boxes come through
    with pytest.raises(Exception, match="SIZE_RATIO_RANGE"):
        size_limits(cfg.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG, ["Pedestrian"], [1.5, 2.0])
