"""Voxel feature encoders: points of a voxel -> one feature vector per voxel."""
from __future__ import annotations

import torch
from torch import nn


class MeanVFE(nn.Module):
    """Mean of the point features in each voxel (OpenPCDet's MeanVFE; no parameters)."""

    def __init__(self, model_cfg, num_point_features: int, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_point_features = num_point_features

    def get_output_feature_dim(self) -> int:
        return self.num_point_features

    def forward(self, batch_dict: dict, **kwargs) -> dict:
        """voxels (V, max_points, C) zero-padded, voxel_num_points (V,) -> voxel_features (V, C)."""
        voxels, num_points = batch_dict["voxels"], batch_dict["voxel_num_points"]
        normalizer = torch.clamp_min(num_points.view(-1, 1).to(voxels.dtype), 1.0)
        batch_dict["voxel_features"] = voxels.sum(dim=1) / normalizer
        return batch_dict
