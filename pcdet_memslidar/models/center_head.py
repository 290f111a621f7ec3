"""Center head of CenterPoint (OpenPCDet's CenterHead and SeparateHead, its module names and config keys).

A shared 3x3 conv, then per group of classes (CLASS_NAMES_EACH_HEAD) a SeparateHead: a heatmap of object centres
('hm', one channel per class) and regressions at the centre cells (SEPARATE_HEAD_CFG: 'center' offset in the
cell, 'center_z' [m], 'dim' log size, 'rot' cos and sin of the heading). Targets and decoding: models.centernet.
"""
from __future__ import annotations

import copy

import torch
from torch import nn

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models.centernet import assign_center_targets, decode_heatmap
from pcdet_memslidar.models.losses import FocalLossCenterNet, RegLossCenterNet
from pcdet_memslidar.models.post_processing import class_agnostic_nms

HEAD_ORDER = ["center", "center_z", "dim", "rot"]  # the regression code: 2 + 1 + 3 + 2 = 8 channels
HEATMAP_PRIOR_BIAS = -2.19  # initial heatmap logit: sigmoid(-2.19) = 0.1


class SeparateHead(nn.Module):
    """One conv branch per output: (num_conv - 1) x [3x3 conv, BN, ReLU], then a 3x3 conv to out_channels."""

    def __init__(self, input_channels: int, sep_head_dict: dict, init_bias: float = HEATMAP_PRIOR_BIAS,
                 use_bias: bool = False):
        super().__init__()
        self.sep_head_dict = sep_head_dict
        for name, spec in sep_head_dict.items():
            layers = [nn.Sequential(nn.Conv2d(input_channels, input_channels, 3, padding=1, bias=use_bias),
                                    nn.BatchNorm2d(input_channels), nn.ReLU())
                      for _ in range(spec["num_conv"] - 1)]
            branch = nn.Sequential(*layers, nn.Conv2d(input_channels, spec["out_channels"], 3, padding=1))
            if name == "hm":
                nn.init.constant_(branch[-1].bias, init_bias)
            else:
                for module in branch.modules():
                    if isinstance(module, nn.Conv2d):
                        nn.init.kaiming_normal_(module.weight)
                        if module.bias is not None:
                            nn.init.zeros_(module.bias)
            self.add_module(name, branch)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """x (B, C, H, W) -> {name: (B, out_channels, H, W)}."""
        return {name: getattr(self, name)(x) for name in self.sep_head_dict}


class CenterHead(nn.Module):
    """Heatmap + regression head; forward(batch_dict) adds in eval 'final_box_dicts' (per frame pred_boxes (K, 7),
    pred_scores (K,), pred_labels (K,) 1-based); in training it keeps the targets for get_loss."""

    short_name = "center"  # `memslidar reproduce --heads` and run ids; MODEL from model_config (register_dense_head)
    model_config = "memslidar_models/centerpoint_person.yaml"

    def __init__(self, model_cfg, input_channels: int, num_class: int, class_names, grid_size, point_cloud_range,
                 voxel_size, predict_boxes_when_training: bool = False, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_class = num_class
        self.grid_size = grid_size
        self.point_cloud_range = [float(value) for value in point_cloud_range]
        self.voxel_size = [float(value) for value in voxel_size]
        self.class_names = list(class_names)
        self.feature_map_stride = model_cfg.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE
        self._check(model_cfg)
        self.class_names_each_head = [[name for name in names if name in self.class_names]
                                      for names in model_cfg.CLASS_NAMES_EACH_HEAD]
        self.class_id_mapping_each_head = [[self.class_names.index(name) for name in names]
                                           for names in self.class_names_each_head]
        if sorted(sum(self.class_id_mapping_each_head, [])) != list(range(len(self.class_names))):
            raise ConfigError(f"DENSE_HEAD.CLASS_NAMES_EACH_HEAD {list(model_cfg.CLASS_NAMES_EACH_HEAD)} must name "
                              f"each of CLASS_NAMES {self.class_names} once")
        channels = model_cfg.SHARED_CONV_CHANNEL
        use_bias = model_cfg.get("USE_BIAS_BEFORE_NORM", False)
        self.shared_conv = nn.Sequential(nn.Conv2d(input_channels, channels, 3, padding=1, bias=use_bias),
                                         nn.BatchNorm2d(channels), nn.ReLU())
        self.separate_head_cfg = model_cfg.SEPARATE_HEAD_CFG
        self.heads_list = nn.ModuleList()
        for names in self.class_names_each_head:
            head_dict = copy.deepcopy(dict(self.separate_head_cfg.HEAD_DICT))
            head_dict["hm"] = {"out_channels": len(names), "num_conv": model_cfg.NUM_HM_CONV}
            self.heads_list.append(SeparateHead(channels, head_dict, HEATMAP_PRIOR_BIAS, use_bias))
        self.predict_boxes_when_training = predict_boxes_when_training
        self.hm_loss_func = FocalLossCenterNet()
        self.reg_loss_func = RegLossCenterNet()
        self.forward_ret_dict: dict = {}

    @staticmethod
    def _check(model_cfg) -> None:
        """ConfigError for settings this head does not implement (velocity, IoU branches, circle NMS)."""
        order = list(model_cfg.SEPARATE_HEAD_CFG.HEAD_ORDER)
        if order != HEAD_ORDER or sorted(model_cfg.SEPARATE_HEAD_CFG.HEAD_DICT) != sorted(HEAD_ORDER):
            raise ConfigError(f"DENSE_HEAD.SEPARATE_HEAD_CFG: HEAD_ORDER {order} with HEAD_DICT keys "
                              f"{sorted(model_cfg.SEPARATE_HEAD_CFG.HEAD_DICT)}: this CenterHead regresses exactly "
                              f"{HEAD_ORDER} (no velocity or IoU branch); set both to those")
        if len(model_cfg.LOSS_CONFIG.LOSS_WEIGHTS.code_weights) != 8:
            raise ConfigError("DENSE_HEAD.LOSS_CONFIG.LOSS_WEIGHTS.code_weights needs 8 values (offset x, y, z, "
                              "log dx, dy, dz, cos, sin)")
        if model_cfg.POST_PROCESSING.NMS_CONFIG.NMS_TYPE == "circle_nms":
            raise ConfigError("DENSE_HEAD.POST_PROCESSING.NMS_CONFIG.NMS_TYPE circle_nms is not supported (nor "
                              "finished in OpenPCDet): use nms_gpu")

    def forward(self, data_dict: dict) -> dict:
        """spatial_features_2d (B, C, H, W) -> per head {'hm', 'center', 'center_z', 'dim', 'rot'} maps (kept for
        get_loss); in eval (or predict_boxes_when_training) data_dict['final_box_dicts']."""
        features = self.shared_conv(data_dict["spatial_features_2d"])
        pred_dicts = [head(features) for head in self.heads_list]
        self.forward_ret_dict = {"pred_dicts": pred_dicts}
        if self.training:
            self.forward_ret_dict["target_dicts"] = self.assign_targets(data_dict["gt_boxes"], features.shape[2:])
        if not self.training or self.predict_boxes_when_training:
            data_dict["final_box_dicts"] = self.generate_predicted_boxes(data_dict["batch_size"], pred_dicts)
        return data_dict

    def assign_targets(self, gt_boxes: torch.Tensor, feature_map_size) -> dict[str, list[torch.Tensor]]:
        """gt_boxes (B, M, 8) with class 1..C in the last column (0: padding); feature_map_size (H, W) ->
        per head {'heatmaps' (B, C_h, H, W), 'target_boxes' (B, N, 8), 'inds' (B, N), 'masks' (B, N)}."""
        cfg = self.model_cfg.TARGET_ASSIGNER_CONFIG
        height, width = (int(size) for size in feature_map_size)
        targets = {"heatmaps": [], "target_boxes": [], "inds": [], "masks": []}
        for names in self.class_names_each_head:
            to_head = torch.zeros(len(self.class_names) + 1, dtype=torch.int64)  # dataset class -> head class
            to_head[[self.class_names.index(name) + 1 for name in names]] = torch.arange(1, len(names) + 1)
            per_frame = []
            for boxes in gt_boxes.detach().cpu():
                boxes = boxes.clone()
                boxes[:, -1] = to_head[boxes[:, -1].long()]
                boxes = boxes[boxes[:, -1] > 0]
                per_frame.append(assign_center_targets(
                    boxes, len(names), (width, height), self.point_cloud_range, self.voxel_size, cfg.FEATURE_MAP_STRIDE,
                    cfg.NUM_MAX_OBJS, cfg.GAUSSIAN_OVERLAP, cfg.MIN_RADIUS))
            for key, values in zip(targets, zip(*per_frame)):
                targets[key].append(torch.stack(values).to(gt_boxes.device))
        return targets

    def get_loss(self) -> tuple[torch.Tensor, dict]:
        """Heatmap focal loss x cls_weight + L1 of the code at centres (code_weights) x loc_weight, summed over
        heads."""
        weights = self.model_cfg.LOSS_CONFIG.LOSS_WEIGHTS
        targets = self.forward_ret_dict["target_dicts"]
        loss, tb_dict = 0.0, {}
        for index, pred_dict in enumerate(self.forward_ret_dict["pred_dicts"]):
            heatmap = pred_dict["hm"].sigmoid().clamp(1e-4, 1 - 1e-4)
            hm_loss = self.hm_loss_func(heatmap, targets["heatmaps"][index]) * weights["cls_weight"]
            code = torch.cat([pred_dict[name] for name in HEAD_ORDER], dim=1)
            reg_loss = self.reg_loss_func(code, targets["masks"][index], targets["inds"][index],
                                          targets["target_boxes"][index])
            loc_loss = (reg_loss * reg_loss.new_tensor(weights["code_weights"])).sum() * weights["loc_weight"]
            loss = loss + hm_loss + loc_loss
            tb_dict[f"hm_loss_head_{index}"] = hm_loss.item()
            tb_dict[f"loc_loss_head_{index}"] = loc_loss.item()
        tb_dict["rpn_loss"] = loss.item()
        return loss, tb_dict

    def generate_predicted_boxes(self, batch_size: int, pred_dicts: list[dict]) -> list[dict]:
        """Per frame {'pred_boxes' (K, 7), 'pred_scores' (K,), 'pred_labels' (K,) 1-based}: decoded best cells of
        every head (in fp32), then class-agnostic rotated NMS per head (DENSE_HEAD.POST_PROCESSING)."""
        cfg = self.model_cfg.POST_PROCESSING
        frames = [{"pred_boxes": [], "pred_scores": [], "pred_labels": []} for _ in range(batch_size)]
        for mapping, pred_dict in zip(self.class_id_mapping_each_head, pred_dicts):
            pred = {name: value.float() for name, value in pred_dict.items()}
            decoded = decode_heatmap(pred["hm"].sigmoid(), pred["center"], pred["center_z"], pred["dim"].exp(),
                                     pred["rot"], self.point_cloud_range, self.voxel_size, self.feature_map_stride,
                                     cfg.MAX_OBJ_PER_SAMPLE, cfg.SCORE_THRESH, cfg.POST_CENTER_LIMIT_RANGE)
            for frame, boxes in zip(frames, decoded):
                selected, scores = class_agnostic_nms(boxes["pred_scores"], boxes["pred_boxes"], cfg.NMS_CONFIG)
                frame["pred_boxes"].append(boxes["pred_boxes"][selected])
                frame["pred_scores"].append(scores)
                frame["pred_labels"].append(torch.as_tensor(mapping, device=scores.device)[
                    boxes["pred_labels"][selected]] + 1)
        return [{key: torch.cat(values) for key, values in frame.items()} for frame in frames]
