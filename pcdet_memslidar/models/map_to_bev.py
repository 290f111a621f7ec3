"""Sparse 3D features -> dense bird's-eye-view map."""
from __future__ import annotations

from torch import nn


class HeightCompression(nn.Module):
    """Stack the z cells of the sparse output into channels: (B, C, D, H, W) -> (B, C * D, H, W)."""

    def __init__(self, model_cfg, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_bev_features = model_cfg.NUM_BEV_FEATURES

    def forward(self, batch_dict: dict) -> dict:
        spatial_features = batch_dict["encoded_spconv_tensor"].dense()  # torch indexing: safe on all threads
        batch, channels, depth, height, width = spatial_features.shape
        batch_dict["spatial_features"] = spatial_features.view(batch, channels * depth, height, width)
        batch_dict["spatial_features_stride"] = batch_dict["encoded_spconv_tensor_stride"]
        return batch_dict
