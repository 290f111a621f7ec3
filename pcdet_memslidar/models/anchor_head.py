"""Single-stage anchor head of SECOND (OpenPCDet's AnchorHeadSingle with AnchorHeadTemplate's losses)."""
from __future__ import annotations

import math

import torch
from torch import nn

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import limit_period
from pcdet_memslidar.models.anchor_generator import generate_anchors
from pcdet_memslidar.models.box_coder import ResidualCoder
from pcdet_memslidar.models.losses import (
    SigmoidFocalClassificationLoss,
    WeightedCrossEntropyLoss,
    WeightedSmoothL1Loss,
    add_sin_difference,
    direction_targets,
)
from pcdet_memslidar.models.target_assigner import AxisAlignedTargetAssigner


class AnchorHeadSingle(nn.Module):
    """1x1 convs on the BEV map: class logits, box residuals and direction-bin logits per anchor.

    Anchors are non-persistent buffers (they follow .to(device) and stay out of the state dict, as in OpenPCDet).
    """

    short_name = "anchor"  # `memslidar reproduce --heads` and run ids; MODEL from model_config (register_dense_head)
    model_config = "memslidar_models/second_person.yaml"

    def __init__(self, model_cfg, input_channels: int, num_class: int, class_names, grid_size, point_cloud_range,
                 predict_boxes_when_training: bool = False, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_class = num_class
        self.predict_boxes_when_training = predict_boxes_when_training
        if model_cfg.get("USE_MULTIHEAD", False):
            raise ConfigError("DENSE_HEAD.USE_MULTIHEAD is not supported by AnchorHeadSingle: set it False")
        assigner_cfg = model_cfg.TARGET_ASSIGNER_CONFIG
        if assigner_cfg.get("NAME", "AxisAlignedTargetAssigner") != "AxisAlignedTargetAssigner" or \
                assigner_cfg.get("BOX_CODER", "ResidualCoder") != "ResidualCoder":
            raise ConfigError("TARGET_ASSIGNER_CONFIG: only AxisAlignedTargetAssigner with ResidualCoder is supported")
        self.box_coder = ResidualCoder(**assigner_cfg.get("BOX_CODER_CONFIG", {}))
        self.target_assigner = AxisAlignedTargetAssigner(assigner_cfg, class_names, self.box_coder)
        anchors, per_location = generate_anchors(model_cfg.ANCHOR_GENERATOR_CONFIG, grid_size, point_cloud_range)
        for config in model_cfg.ANCHOR_GENERATOR_CONFIG:
            self.target_assigner.add_anchor_class(config)
        for index, class_anchors in enumerate(anchors):
            self.register_buffer(f"anchors_{index}", class_anchors, persistent=False)
        self.num_anchor_classes = len(anchors)
        self.num_anchors_per_location = sum(per_location)

        code_size = self.box_coder.code_size
        self.conv_cls = nn.Conv2d(input_channels, self.num_anchors_per_location * num_class, kernel_size=1)
        self.conv_box = nn.Conv2d(input_channels, self.num_anchors_per_location * code_size, kernel_size=1)
        self.conv_dir_cls = (nn.Conv2d(input_channels, self.num_anchors_per_location * model_cfg.NUM_DIR_BINS, 1)
                             if model_cfg.get("USE_DIRECTION_CLASSIFIER", False) else None)
        self.cls_loss_func = SigmoidFocalClassificationLoss(alpha=0.25, gamma=2.0)
        self.reg_loss_func = WeightedSmoothL1Loss(code_weights=model_cfg.LOSS_CONFIG.LOSS_WEIGHTS.get("code_weights"))
        self.dir_loss_func = WeightedCrossEntropyLoss()
        self.forward_ret_dict: dict = {}
        self.init_weights()

    @property
    def anchors(self) -> list[torch.Tensor]:
        """Per anchor class (Z, H, W, sizes, rotations, 7) boxes."""
        return [getattr(self, f"anchors_{index}") for index in range(self.num_anchor_classes)]

    def flat_anchors(self) -> torch.Tensor:
        """(A, 7) anchors in the order of the head's outputs."""
        return torch.cat(self.anchors, dim=-3).view(-1, self.box_coder.code_size)

    def init_weights(self) -> None:
        prior = 0.01  # initial foreground probability
        nn.init.constant_(self.conv_cls.bias, -math.log((1 - prior) / prior))
        nn.init.normal_(self.conv_box.weight, mean=0, std=0.001)

    def forward(self, data_dict: dict) -> dict:
        """spatial_features_2d (B, C, H, W) -> in training the targets for get_loss; otherwise (or when
        predict_boxes_when_training) batch_cls_preds (B, A, num_class) logits and batch_box_preds (B, A, 7)."""
        features = data_dict["spatial_features_2d"]
        cls_preds = self.conv_cls(features).permute(0, 2, 3, 1).contiguous()
        box_preds = self.conv_box(features).permute(0, 2, 3, 1).contiguous()
        dir_cls_preds = (self.conv_dir_cls(features).permute(0, 2, 3, 1).contiguous()
                         if self.conv_dir_cls is not None else None)
        self.forward_ret_dict = {"cls_preds": cls_preds, "box_preds": box_preds, "dir_cls_preds": dir_cls_preds}
        if self.training:
            self.forward_ret_dict.update(self.target_assigner.assign_targets(self.anchors, data_dict["gt_boxes"]))
        if not self.training or self.predict_boxes_when_training:
            batch_cls_preds, batch_box_preds = self.generate_predicted_boxes(
                data_dict["batch_size"], cls_preds, box_preds, dir_cls_preds)
            data_dict.update(batch_cls_preds=batch_cls_preds, batch_box_preds=batch_box_preds,
                             cls_preds_normalized=False)
        return data_dict

    def generate_predicted_boxes(self, batch_size: int, cls_preds, box_preds, dir_cls_preds=None):
        """Decode head outputs -> (B, A, num_class) logits, (B, A, 7) boxes with heading from the direction bin."""
        anchors = self.flat_anchors()
        num_anchors = anchors.shape[0]
        batch_cls_preds = cls_preds.view(batch_size, num_anchors, -1).float()  # fp32 from here (bf16 inference)
        batch_box_preds = self.box_coder.decode_torch(box_preds.view(batch_size, num_anchors, -1).float(),
                                                      anchors.unsqueeze(0).expand(batch_size, -1, -1))
        if dir_cls_preds is not None:
            cfg = self.model_cfg
            dir_labels = dir_cls_preds.view(batch_size, num_anchors, -1).argmax(dim=-1)
            period = 2 * math.pi / cfg.NUM_DIR_BINS
            heading = limit_period(batch_box_preds[..., 6] - cfg.DIR_OFFSET, cfg.DIR_LIMIT_OFFSET, period)
            heading = heading + cfg.DIR_OFFSET + period * dir_labels.to(batch_box_preds.dtype)
            batch_box_preds = torch.cat([batch_box_preds[..., :6], heading.unsqueeze(-1), batch_box_preds[..., 7:]],
                                        dim=-1)
        return batch_cls_preds, batch_box_preds

    def get_loss(self) -> tuple[torch.Tensor, dict]:
        """Focal classification + smooth-L1 box (sin-difference heading) + direction losses, per frame mean."""
        cls_loss, tb_dict = self.get_cls_layer_loss()
        box_loss, tb_box = self.get_box_reg_layer_loss()
        tb_dict.update(tb_box)
        rpn_loss = cls_loss + box_loss
        tb_dict["rpn_loss"] = rpn_loss.item()
        return rpn_loss, tb_dict

    def get_cls_layer_loss(self) -> tuple[torch.Tensor, dict]:
        cls_preds = self.forward_ret_dict["cls_preds"]
        labels = self.forward_ret_dict["box_cls_labels"]
        batch_size = cls_preds.shape[0]
        positives, negatives = labels > 0, labels == 0
        normalizer = positives.sum(1, keepdim=True).float().clamp_min(1.0)
        cls_weights = (positives | negatives).float() / normalizer
        targets = labels.clamp_min(0)
        if self.num_class == 1:
            targets = (targets > 0).long()
        one_hot = torch.nn.functional.one_hot(targets, self.num_class + 1)[..., 1:].to(cls_preds.dtype)
        cls_loss = self.cls_loss_func(cls_preds.view(batch_size, -1, self.num_class), one_hot, cls_weights)
        cls_loss = cls_loss.sum() / batch_size * self.model_cfg.LOSS_CONFIG.LOSS_WEIGHTS["cls_weight"]
        return cls_loss, {"rpn_loss_cls": cls_loss.item()}

    def get_box_reg_layer_loss(self) -> tuple[torch.Tensor, dict]:
        box_preds = self.forward_ret_dict["box_preds"]
        dir_cls_preds = self.forward_ret_dict["dir_cls_preds"]
        reg_targets = self.forward_ret_dict["box_reg_targets"]
        labels = self.forward_ret_dict["box_cls_labels"]
        batch_size = box_preds.shape[0]
        weights_cfg = self.model_cfg.LOSS_CONFIG.LOSS_WEIGHTS
        positives = labels > 0
        reg_weights = positives.float() / positives.sum(1, keepdim=True).float().clamp_min(1.0)
        box_preds = box_preds.view(batch_size, -1, self.box_coder.code_size)
        box_preds_sin, targets_sin = add_sin_difference(box_preds, reg_targets)
        loc_loss = self.reg_loss_func(box_preds_sin, targets_sin, reg_weights)
        loc_loss = loc_loss.sum() / batch_size * weights_cfg["loc_weight"]
        tb_dict = {"rpn_loss_loc": loc_loss.item()}
        if dir_cls_preds is None:
            return loc_loss, tb_dict
        anchors = self.flat_anchors().unsqueeze(0).expand(batch_size, -1, -1)
        dir_targets = direction_targets(anchors, reg_targets, self.model_cfg.DIR_OFFSET, self.model_cfg.NUM_DIR_BINS)
        dir_logits = dir_cls_preds.view(batch_size, -1, self.model_cfg.NUM_DIR_BINS)
        dir_weights = positives.to(dir_logits.dtype)
        dir_weights = dir_weights / dir_weights.sum(-1, keepdim=True).clamp_min(1.0)
        dir_loss = self.dir_loss_func(dir_logits, dir_targets, dir_weights)
        dir_loss = dir_loss.sum() / batch_size * weights_cfg["dir_weight"]
        tb_dict["rpn_loss_dir"] = dir_loss.item()
        return loc_loss + dir_loss, tb_dict
