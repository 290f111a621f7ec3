"""Detectors as OpenPCDet builds them: a template that builds its modules from the config's sections, and the two
one-stage detectors on it.

Detector3DTemplate: MeanVFE -> VoxelBackBone8x -> HeightCompression -> BaseBEVBackbone -> a dense head, each looked
up by its section's NAME, under OpenPCDet's module names (state dicts match OpenPCDet's key for key); the grid
check, inference precision, the forward loop, the optional box from its points (POST_PROCESSING.BOX_FROM_POINTS) and
the recall record are shared. A detector adds its post-processing:
- SECONDNet: AnchorHeadSingle; scores and boxes per anchor -> size filter, threshold, rotated NMS;
- CenterPoint: CenterHead; the head decodes and suppresses itself (final_box_dicts).
"""
from __future__ import annotations

import abc

import torch
from torch import nn

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.grid import check_voxel_grid
from pcdet_memslidar.models.anchor_head import AnchorHeadSingle
from pcdet_memslidar.models.backbone_2d import BaseBEVBackbone
from pcdet_memslidar.models.backbone_3d import VoxelBackBone8x
from pcdet_memslidar.models.center_head import CenterHead
from pcdet_memslidar.models.map_to_bev import HeightCompression
from pcdet_memslidar.models.post_processing import (
    box_from_points,
    fit_to_points,
    post_processing,
    recall_record,
    size_limits,
)
from pcdet_memslidar.models.vfe import MeanVFE
from pcdet_memslidar.policy import ExecutionPolicy

# precision of the dense 2D part (BEV backbone and head), fast in bf16 on CPUs with bf16 matrix units (AMX,
# AVX512-BF16) and GPUs; the sparse 3D part, box decoding, NMS, the loss and the weights stay fp32
PRECISIONS = ("fp32", "bf16")


def _float32(value):
    """`value` (tensors in dicts and lists) with its bf16 tensors cast to fp32 (differentiably)."""
    if isinstance(value, dict):
        return {key: _float32(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_float32(item) for item in value]
    return value.float() if isinstance(value, torch.Tensor) and value.dtype == torch.bfloat16 else value


# OpenPCDet's registries (its __all__ tables): module NAME in the config -> class
VFES = {"MeanVFE": MeanVFE}
BACKBONES_3D = {"VoxelBackBone8x": VoxelBackBone8x}
MAPS_TO_BEV = {"HeightCompression": HeightCompression}
BACKBONES_2D = {"BaseBEVBackbone": BaseBEVBackbone}
DENSE_HEADS = {"AnchorHeadSingle": AnchorHeadSingle, "CenterHead": CenterHead}  # see register_dense_head


def register(registry: dict, key: str, module: type) -> type:
    """Add `module` to `registry` under its class name, the value of config key `key` that selects it; returns it.
    ValueError if another class has that name there."""
    name = module.__name__
    if registry.get(name, module) is not module:
        raise ValueError(f"{key} {name} is taken by {registry[name].__module__}.{name}: give "
                         f"{module.__module__}.{name} another class name")
    registry[name] = module
    return module


def register_dense_head(head: type[nn.Module]) -> type[nn.Module]:
    """Make `head` the DENSE_HEAD.NAME of its class name (a class decorator). Its `short_name` (run ids 'M3-center')
    and `model_config` (the shipped model config with this head, relative to cfgs/) put it in `memslidar reproduce
    --heads`; a head without them is built from configs only."""
    return register(DENSE_HEADS, "DENSE_HEAD.NAME", head)


def _lookup(registry: dict, section: str, model_cfg):
    name = model_cfg.get(section, {}).get("NAME")
    if name not in registry:
        raise ConfigError(f"MODEL.{section}.NAME is {name!r}; this package provides {', '.join(registry)}")
    return registry[name]


class Detector3DTemplate(nn.Module, abc.ABC):
    """Modules of `module_topology` built from the MODEL sections in order, run in order on one batch_dict.

    forward(batch_dict): in training ({'loss'}, tb_dict, disp_dict); in eval (pred_dicts, recall_dict), each
    pred_dict {pred_boxes (K, 7), pred_scores (K,), pred_labels (K,) 1-based}: the detector's post_processing, then,
    with POST_PROCESSING.BOX_FROM_POINTS, each box's centre and heading from its points (models.post_processing).
    """

    module_topology = ["vfe", "backbone_3d", "map_to_bev_module", "backbone_2d", "dense_head"]
    display_name: str  # the detector's name in reports (Table 3's Architecture column)
    dense_head_names: tuple[str, ...] = ()  # the heads a detector is made for (empty: any)
    precision = "fp32"  # one of PRECISIONS, for inference (set_precision)
    train_precision = "fp32"  # one of PRECISIONS, for training (set_precision(..., training=True))

    def __init__(self, model_cfg, num_class: int, dataset):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_class = num_class
        self.dataset = dataset
        self.class_names = list(dataset.class_names)
        self.register_buffer("global_step", torch.LongTensor(1).zero_())
        self.box_from_points = box_from_points(model_cfg.POST_PROCESSING)
        head = model_cfg.get("DENSE_HEAD", {}).get("NAME")
        if self.dense_head_names and head not in self.dense_head_names:
            raise ConfigError(f"MODEL.NAME {model_cfg.NAME} takes DENSE_HEAD.NAME {' or '.join(self.dense_head_names)}"
                              f", not {head!r}")
        info = {"num_point_features": dataset.point_feature_encoder.num_point_features,
                "grid_size": check_voxel_grid(model_cfg, dataset.point_cloud_range, dataset.voxel_size),
                "point_cloud_range": dataset.point_cloud_range, "voxel_size": dataset.voxel_size}
        self.module_list = []
        for name in self.module_topology:
            module = getattr(self, f"build_{name}")(info)
            self.add_module(name, module)
            self.module_list.append(module)

    def build_vfe(self, info: dict) -> nn.Module:
        vfe = _lookup(VFES, "VFE", self.model_cfg)(
            model_cfg=self.model_cfg.VFE, num_point_features=info["num_point_features"],
            point_cloud_range=info["point_cloud_range"], voxel_size=info["voxel_size"], grid_size=info["grid_size"])
        info["num_point_features"] = vfe.get_output_feature_dim()
        return vfe

    def build_backbone_3d(self, info: dict) -> nn.Module:
        return _lookup(BACKBONES_3D, "BACKBONE_3D", self.model_cfg)(
            model_cfg=self.model_cfg.BACKBONE_3D, input_channels=info["num_point_features"],
            grid_size=info["grid_size"], voxel_size=info["voxel_size"], point_cloud_range=info["point_cloud_range"])

    def build_map_to_bev_module(self, info: dict) -> nn.Module:
        module = _lookup(MAPS_TO_BEV, "MAP_TO_BEV", self.model_cfg)(
            model_cfg=self.model_cfg.MAP_TO_BEV, grid_size=info["grid_size"])
        info["num_bev_features"] = module.num_bev_features
        return module

    def build_backbone_2d(self, info: dict) -> nn.Module:
        module = _lookup(BACKBONES_2D, "BACKBONE_2D", self.model_cfg)(
            model_cfg=self.model_cfg.BACKBONE_2D, input_channels=info["num_bev_features"])
        info["num_bev_features"] = module.num_bev_features
        return module

    def build_dense_head(self, info: dict) -> nn.Module:
        head_cfg = self.model_cfg.DENSE_HEAD
        return _lookup(DENSE_HEADS, "DENSE_HEAD", self.model_cfg)(
            model_cfg=head_cfg, input_channels=info["num_bev_features"],
            num_class=1 if head_cfg.get("CLASS_AGNOSTIC", False) else self.num_class, class_names=self.class_names,
            grid_size=info["grid_size"], point_cloud_range=info["point_cloud_range"], voxel_size=info["voxel_size"],
            predict_boxes_when_training=False)

    def update_global_step(self) -> None:
        self.global_step += 1

    def set_policy(self, policy: ExecutionPolicy) -> None:
        """Run with the execution `policy` (pcdet_memslidar.policy: threads and sparse-conv back end), which the
        sparse backbone reads; the runtime sets its process's policy when it builds or loads a detector."""
        self.backbone_3d.policy = policy

    def set_precision(self, precision: str, training: bool = False) -> None:
        """Precision of the BEV backbone and head (PRECISIONS) in inference, or in training with training=True (bf16:
        their forward under autocast, their outputs back in fp32 for the loss); ConfigError for another."""
        if precision not in PRECISIONS:
            raise ConfigError(f"precision {precision!r}: use one of {', '.join(PRECISIONS)}")
        if training:
            self.train_precision = precision
        else:
            self.precision = precision

    def forward(self, batch_dict: dict):
        bf16 = (self.train_precision if self.training else self.precision) == "bf16"
        for module in self.module_list:
            dense_2d = module is self.backbone_2d or module is self.dense_head
            if bf16 and module is self.backbone_2d:  # NHWC: oneDNN's fast layout for bf16 convolutions
                batch_dict["spatial_features"] = batch_dict["spatial_features"].contiguous(
                    memory_format=torch.channels_last)
            with torch.autocast(self.global_step.device.type, dtype=torch.bfloat16, enabled=bf16 and dense_2d):
                batch_dict = module(batch_dict)
        if self.training:
            if bf16:
                self.dense_head.forward_ret_dict = _float32(self.dense_head.forward_ret_dict)
            loss, tb_dict = self.dense_head.get_loss()
            return {"loss": loss}, {"loss_rpn": loss.item(), **tb_dict}, {}
        pred_dicts = self.post_processing(batch_dict)
        if self.box_from_points is not None:
            fit_to_points(pred_dicts, batch_dict["points"], *self.box_from_points,
                          point_times=batch_dict.get("point_times"))
        recall_dict = {}
        for index, pred_dict in enumerate(pred_dicts if "gt_boxes" in batch_dict else []):
            recall_record(pred_dict["pred_boxes"], batch_dict["gt_boxes"][index],
                          self.model_cfg.POST_PROCESSING.RECALL_THRESH_LIST, recall_dict)
        return pred_dicts, recall_dict

    @abc.abstractmethod
    def post_processing(self, batch_dict: dict) -> list[dict]:
        """The head's outputs in batch_dict -> per frame {pred_boxes (K, 7), pred_scores (K,), pred_labels (K,)}."""


class SECONDNet(Detector3DTemplate):
    """SECOND (Yan et al. 2018): the anchor head's scores and boxes -> plausible sizes, threshold, rotated NMS."""

    display_name = "SECOND"
    dense_head_names = ("AnchorHeadSingle",)

    def __init__(self, model_cfg, num_class: int, dataset):
        super().__init__(model_cfg, num_class, dataset)
        ratio_range = model_cfg.POST_PROCESSING.get("SIZE_RATIO_RANGE")
        self.size_limits = None if ratio_range is None else size_limits(
            model_cfg.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG, self.class_names, ratio_range)

    def post_processing(self, batch_dict: dict) -> list[dict]:
        return post_processing(batch_dict, self.model_cfg.POST_PROCESSING, self.size_limits)


class CenterPoint(Detector3DTemplate):
    """CenterPoint (Yin et al. 2021), one stage: the center head's final boxes (its own NMS)."""

    display_name = "CenterPoint"
    dense_head_names = ("CenterHead",)

    def post_processing(self, batch_dict: dict) -> list[dict]:
        return batch_dict["final_box_dicts"]
