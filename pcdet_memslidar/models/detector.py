"""SECONDNet: MeanVFE -> VoxelBackBone8x -> HeightCompression -> BaseBEVBackbone -> AnchorHeadSingle."""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models.anchor_head import AnchorHeadSingle
from pcdet_memslidar.models.backbone_2d import BaseBEVBackbone
from pcdet_memslidar.models.backbone_3d import VoxelBackBone8x, sparse_output_depth
from pcdet_memslidar.models.map_to_bev import HeightCompression
from pcdet_memslidar.models.post_processing import post_processing, size_limits
from pcdet_memslidar.models.vfe import MeanVFE

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


def check_grid(model_cfg, grid_size) -> None:
    """ConfigError unless the voxel grid (x, y, z cells) fits the sparse backbone, BEV backbone and anchors."""
    grid_size = np.asarray(grid_size)
    depth = sparse_output_depth(int(grid_size[2]))
    bev_features = model_cfg.MAP_TO_BEV.NUM_BEV_FEATURES
    if depth < 1 or 128 * depth != bev_features:
        raise ConfigError(f"MODEL.MAP_TO_BEV.NUM_BEV_FEATURES is {bev_features} but a grid {int(grid_size[2])} voxels "
                          f"deep gives {128 * max(depth, 0)}: use 40 z cells (z range / z voxel = 40) for 256")
    multiple = 8 * int(np.prod(model_cfg.BACKBONE_2D.get("LAYER_STRIDES", [1])))
    if grid_size[0] % multiple or grid_size[1] % multiple:
        raise ConfigError(f"the voxel grid has {int(grid_size[0])} x {int(grid_size[1])} cells (x, y); SECOND with "
                          f"LAYER_STRIDES {list(model_cfg.BACKBONE_2D.LAYER_STRIDES)} needs multiples of {multiple}: "
                          f"change POINT_CLOUD_RANGE or VOXEL_SIZE")
    head_stride = bev_output_stride(model_cfg.BACKBONE_2D)
    for anchor in model_cfg.DENSE_HEAD.get("ANCHOR_GENERATOR_CONFIG", []):
        if anchor["feature_map_stride"] != head_stride:
            raise ConfigError(f"ANCHOR_GENERATOR_CONFIG {anchor['class_name']}: feature_map_stride is "
                              f"{anchor['feature_map_stride']} but BACKBONE_2D (LAYER_STRIDES "
                              f"{list(model_cfg.BACKBONE_2D.LAYER_STRIDES)}, UPSAMPLE_STRIDES "
                              f"{list(model_cfg.BACKBONE_2D.UPSAMPLE_STRIDES)}) outputs stride {head_stride:g}: "
                              f"set feature_map_stride {head_stride:g} or change UPSAMPLE_STRIDES")


def bev_output_stride(backbone_2d_cfg) -> float:
    """Voxels per cell of BaseBEVBackbone's output on VoxelBackBone8x's stride-8 map (the anchors' stride);
    ConfigError when the levels it concatenates are upsampled to different strides."""
    strides = 8 * np.cumprod(backbone_2d_cfg.get("LAYER_STRIDES", [1])).astype(np.float64)
    upsample = [float(up) for up in backbone_2d_cfg.get("UPSAMPLE_STRIDES", [])]
    levels = [float(stride / upsample[level] if level < len(upsample) else stride)
              for level, stride in enumerate(strides)]
    if len(set(levels)) > 1:
        raise ConfigError(f"BACKBONE_2D: LAYER_STRIDES {list(backbone_2d_cfg.LAYER_STRIDES)} with UPSAMPLE_STRIDES "
                          f"{upsample} bring its levels to strides {levels}; they must meet at one stride")
    extra = upsample[len(strides):]  # one more upsampling after the concatenation
    return levels[0] / (extra[0] if extra else 1.0)


class SECONDNet(nn.Module):
    """The SECOND detector with OpenPCDet's module names, so state dicts match OpenPCDet's key for key.

    forward(batch_dict): in training ({'loss'}, tb_dict, disp_dict); in eval (pred_dicts, recall_dict).
    """

    module_topology = ["vfe", "backbone_3d", "map_to_bev_module", "backbone_2d", "dense_head"]

    def __init__(self, model_cfg, num_class: int, dataset):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_class = num_class
        self.dataset = dataset
        self.class_names = list(dataset.class_names)
        self.register_buffer("global_step", torch.LongTensor(1).zero_())
        grid_size = np.asarray(dataset.grid_size)
        check_grid(model_cfg, grid_size)

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

    def forward(self, batch_dict: dict):
        for module in self.module_list:
            batch_dict = module(batch_dict)
        if self.training:
            loss, tb_dict = self.dense_head.get_loss()
            return {"loss": loss}, {"loss_rpn": loss.item(), **tb_dict}, {}
        return post_processing(batch_dict, self.model_cfg.POST_PROCESSING, self.size_limits)
