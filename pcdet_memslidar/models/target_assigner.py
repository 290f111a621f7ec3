"""Anchor targets by axis-aligned BEV IoU (OpenPCDet's AxisAlignedTargetAssigner, MATCH_HEIGHT False)."""
from __future__ import annotations

import math

import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import limit_period
from pcdet_memslidar.models.anchor_generator import generate_anchors
from pcdet_memslidar.models.box_coder import ResidualCoder


def nearest_bev_boxes(boxes: torch.Tensor) -> torch.Tensor:
    """(N, 7+) boxes -> (N, 4) axis-aligned BEV boxes [x1, y1, x2, y2], heading snapped to 0 or 90 deg."""
    heading = limit_period(boxes[:, 6], 0.5, math.pi).abs()
    dims = torch.where((heading < math.pi / 4)[:, None], boxes[:, [3, 4]], boxes[:, [4, 3]])
    return torch.cat([boxes[:, :2] - dims / 2, boxes[:, :2] + dims / 2], dim=1)


def nearest_bev_iou(boxes_a: torch.Tensor, boxes_b: torch.Tensor) -> torch.Tensor:
    """(N, 7+), (M, 7+) -> (N, M) IoU of the axis-aligned BEV boxes."""
    a, b = nearest_bev_boxes(boxes_a), nearest_bev_boxes(boxes_b)
    width = (torch.min(a[:, None, 2], b[None, :, 2]) - torch.max(a[:, None, 0], b[None, :, 0])).clamp_min(0)
    height = (torch.min(a[:, None, 3], b[None, :, 3]) - torch.max(a[:, None, 1], b[None, :, 1])).clamp_min(0)
    intersection = width * height
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return intersection / (area_a[:, None] + area_b[None, :] - intersection).clamp_min(1e-6)


class AxisAlignedTargetAssigner:
    """Per anchor: class label (-1 ignored, 0 background, k class id), box residual targets, regression weight."""

    def __init__(self, model_cfg, class_names, box_coder: ResidualCoder):
        if model_cfg.get("MATCH_HEIGHT", False):
            raise ConfigError("TARGET_ASSIGNER_CONFIG.MATCH_HEIGHT True is not supported: use False")
        pos_fraction = model_cfg.get("POS_FRACTION", -1.0)
        if pos_fraction is not None and pos_fraction >= 0:
            raise ConfigError("TARGET_ASSIGNER_CONFIG.POS_FRACTION >= 0 (sampling) is not supported: use -1.0")
        if model_cfg.get("NORM_BY_NUM_EXAMPLES", False):
            raise ConfigError("TARGET_ASSIGNER_CONFIG.NORM_BY_NUM_EXAMPLES True is not supported: use False")
        self.box_coder = box_coder
        self.class_names = list(class_names)
        self.anchor_class_names: list[str] = []
        self.thresholds: list[tuple[float, float]] = []

    def add_anchor_class(self, config) -> None:
        """Register one ANCHOR_GENERATOR_CONFIG entry (class_name, matched/unmatched thresholds), in order."""
        self.anchor_class_names.append(config["class_name"])
        self.thresholds.append((config["matched_threshold"], config["unmatched_threshold"]))

    def assign_targets(self, all_anchors: list[torch.Tensor], gt_boxes_with_classes: torch.Tensor) -> dict:
        """all_anchors: per class (Z, H, W, S, R, 7); gt_boxes_with_classes (B, M, 8), class id 1-based in the
        last column, all-zero rows are padding. Returns box_cls_labels (B, A), box_reg_targets (B, A, code),
        reg_weights (B, A) with A anchors in the order (Z, H, W, classes x sizes x rotations)."""
        code_size = self.box_coder.code_size
        labels_batch, targets_batch, weights_batch = [], [], []
        for frame_boxes in gt_boxes_with_classes:
            valid = (frame_boxes[:, :-1].abs().sum(dim=1) > 0) & (frame_boxes[:, -1] > 0)
            gt_boxes, gt_classes = frame_boxes[valid, :-1], frame_boxes[valid, -1].long()
            labels, targets, weights = [], [], []
            for class_name, (matched, unmatched), anchors in zip(self.anchor_class_names, self.thresholds,
                                                                  all_anchors):
                map_shape = anchors.shape[:3]
                mask = torch.tensor([self.class_names[c - 1] == class_name for c in gt_classes.tolist()],
                                    dtype=torch.bool, device=gt_boxes.device)
                cls, reg, weight = self.assign_targets_single(anchors.view(-1, anchors.shape[-1]), gt_boxes[mask],
                                                              gt_classes[mask], matched, unmatched)
                labels.append(cls.view(*map_shape, -1))
                targets.append(reg.view(*map_shape, -1, code_size))
                weights.append(weight.view(*map_shape, -1))
            labels_batch.append(torch.cat(labels, dim=-1).view(-1))
            targets_batch.append(torch.cat(targets, dim=-2).view(-1, code_size))
            weights_batch.append(torch.cat(weights, dim=-1).view(-1))
        return {"box_cls_labels": torch.stack(labels_batch), "box_reg_targets": torch.stack(targets_batch),
                "reg_weights": torch.stack(weights_batch)}

    def assign_targets_single(self, anchors, gt_boxes, gt_classes, matched_threshold, unmatched_threshold):
        """anchors (A, 7), gt_boxes (G, 7), gt_classes (G,) -> labels (A,) long, targets (A, code), weights (A,).

        Positive: IoU >= matched, or the best anchor of a box (ties included); background: IoU < unmatched."""
        num_anchors = anchors.shape[0]
        labels = anchors.new_zeros(num_anchors, dtype=torch.long)
        targets = anchors.new_zeros(num_anchors, self.box_coder.code_size)
        if len(gt_boxes) == 0 or num_anchors == 0:
            return labels, targets, anchors.new_zeros(num_anchors)
        labels -= 1
        overlaps = nearest_bev_iou(anchors, gt_boxes)  # (A, G)
        anchor_to_gt_max, anchor_to_gt = overlaps.max(dim=1)
        gt_to_anchor_max = overlaps.max(dim=0).values
        gt_to_anchor_max[gt_to_anchor_max == 0] = -1  # a box that overlaps no anchor forces nothing
        best_for_gt = (overlaps == gt_to_anchor_max[None, :]).any(dim=1)
        labels[anchor_to_gt_max < unmatched_threshold] = 0
        positive = (anchor_to_gt_max >= matched_threshold) | best_for_gt
        labels[positive] = gt_classes[anchor_to_gt[positive]]
        targets[positive] = self.box_coder.encode_torch(gt_boxes[anchor_to_gt[positive]], anchors[positive])
        return labels, targets, positive.to(anchors.dtype)


def matched_share(anchor_configs, grid_size, point_cloud_range, gt_boxes: torch.Tensor) -> dict[str, float]:
    """{class name: share of `gt_boxes` (M, 7) that have an anchor of that class at axis-aligned BEV IoU >= its
    matched_threshold}: the people that get a matched anchor rather than only a forced best one. A grid and head
    whose anchors lie too far apart for this (e.g. every 1.28 m for a 0.8 x 0.6 m person) barely learns to place
    boxes at IoU 0.5. The boxes are compared with every class's anchors (one class here: the person)."""
    if len(gt_boxes) == 0:
        raise ValueError("matched_share needs at least one box")
    anchors, _ = generate_anchors(anchor_configs, grid_size, point_cloud_range)
    shares = {}
    for config, class_anchors in zip(anchor_configs, anchors):
        best = nearest_bev_iou(class_anchors.view(-1, class_anchors.shape[-1]), gt_boxes.float()).max(dim=0).values
        shares[config["class_name"]] = float((best >= config["matched_threshold"]).float().mean())
    return shares
