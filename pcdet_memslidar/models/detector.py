"""SECONDNet: MeanVFE -> VoxelBackBone8x -> HeightCompression -> BaseBEVBackbone -> AnchorHeadSingle."""
from __future__ import annotations

import torch
from torch import nn

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.grid import check_second_grid
from pcdet_memslidar.models.anchor_head import AnchorHeadSingle
from pcdet_memslidar.models.backbone_2d import BaseBEVBackbone
from pcdet_memslidar.models.backbone_3d import VoxelBackBone8x
from pcdet_memslidar.models.map_to_bev import HeightCompression
from pcdet_memslidar.models.post_processing import post_processing, size_limits
from pcdet_memslidar.models.vfe import MeanVFE

# inference precision of the dense 2D part (BEV backbone and head), fast in bf16 on CPUs with bf16 matrix units
# (AMX, AVX512-BF16) and GPUs; the sparse 3D part, box decoding and NMS stay fp32, and training is fp32
PRECISIONS = ("fp32", "bf16")

# OpenPCDet's registries: module NAME in the config -> class
VFES = {"MeanVFE": MeanVFE}
BACKBONES_3D = {"VoxelBackBone8x": VoxelBackBone8x}
MAPS_TO_BEV = {"HeightCompression": HeightCompression}
BACKBONES_2D = {"BaseBEVBackbone": BaseBEVBackbone}
DENSE_HEADS = {"AnchorHeadSingle": AnchorHeadSingle}


def _lookup(registry: dict, section: str, model_cfg):
    name = model_cfg.get(section, {}).get("NAME")
    if name not in registry:
        raise ConfigError(f"MODEL.{section}.NAME is {name!r}; this package provides {', '.join(registry)}")
    return registry[name]


class SECONDNet(nn.Module):
    """The SECOND detector with OpenPCDet's module names, so state dicts match OpenPCDet's key for key.

    forward(batch_dict): in training ({'loss'}, tb_dict, disp_dict); in eval (pred_dicts, recall_dict).
    """

    module_topology = ["vfe", "backbone_3d", "map_to_bev_module", "backbone_2d", "dense_head"]
    precision = "fp32"  # one of PRECISIONS, for inference (set_precision)

    def __init__(self, model_cfg, num_class: int, dataset):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_class = num_class
        self.dataset = dataset
        self.class_names = list(dataset.class_names)
        self.register_buffer("global_step", torch.LongTensor(1).zero_())
        grid_size = check_second_grid(model_cfg, dataset.point_cloud_range, dataset.voxel_size)

        vfe = _lookup(VFES, "VFE", model_cfg)(
            model_cfg=model_cfg.VFE, num_point_features=dataset.point_feature_encoder.num_point_features,
            point_cloud_range=dataset.point_cloud_range, voxel_size=dataset.voxel_size, grid_size=grid_size)
        backbone_3d = _lookup(BACKBONES_3D, "BACKBONE_3D", model_cfg)(
            model_cfg=model_cfg.BACKBONE_3D, input_channels=vfe.get_output_feature_dim(), grid_size=grid_size,
            voxel_size=dataset.voxel_size, point_cloud_range=dataset.point_cloud_range)
        map_to_bev = _lookup(MAPS_TO_BEV, "MAP_TO_BEV", model_cfg)(model_cfg=model_cfg.MAP_TO_BEV, grid_size=grid_size)
        backbone_2d = _lookup(BACKBONES_2D, "BACKBONE_2D", model_cfg)(
            model_cfg=model_cfg.BACKBONE_2D, input_channels=map_to_bev.num_bev_features)
        head_cfg = model_cfg.DENSE_HEAD
        dense_head = _lookup(DENSE_HEADS, "DENSE_HEAD", model_cfg)(
            model_cfg=head_cfg, input_channels=backbone_2d.num_bev_features,
            num_class=1 if head_cfg.get("CLASS_AGNOSTIC", False) else num_class, class_names=self.class_names,
            grid_size=grid_size, point_cloud_range=dataset.point_cloud_range, voxel_size=dataset.voxel_size,
            predict_boxes_when_training=False)
        ratio_range = model_cfg.POST_PROCESSING.get("SIZE_RATIO_RANGE")
        self.size_limits = None if ratio_range is None else size_limits(
            head_cfg.ANCHOR_GENERATOR_CONFIG, self.class_names, ratio_range)
        self.module_list = []
        for name, module in zip(self.module_topology, (vfe, backbone_3d, map_to_bev, backbone_2d, dense_head)):
            self.add_module(name, module)
            self.module_list.append(module)

    def update_global_step(self) -> None:
        self.global_step += 1

    def set_precision(self, precision: str) -> None:
        """Inference precision of the BEV backbone and head (PRECISIONS); ConfigError for another."""
        if precision not in PRECISIONS:
            raise ConfigError(f"precision {precision!r}: use one of {', '.join(PRECISIONS)}")
        self.precision = precision

    def forward(self, batch_dict: dict):
        bf16 = self.precision == "bf16" and not self.training
        for module in self.module_list:
            dense_2d = module is self.backbone_2d or module is self.dense_head
            if bf16 and module is self.backbone_2d:  # NHWC: oneDNN's fast layout for bf16 convolutions
                batch_dict["spatial_features"] = batch_dict["spatial_features"].contiguous(
                    memory_format=torch.channels_last)
            with torch.autocast(self.global_step.device.type, dtype=torch.bfloat16, enabled=bf16 and dense_2d):
                batch_dict = module(batch_dict)
        if self.training:
            loss, tb_dict = self.dense_head.get_loss()
            return {"loss": loss}, {"loss_rpn": loss.item(), **tb_dict}, {}
        return post_processing(batch_dict, self.model_cfg.POST_PROCESSING, self.size_limits)
