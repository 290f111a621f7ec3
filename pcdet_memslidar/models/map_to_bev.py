"""Sparse 3D features -> dense bird's-eye-view map."""
from __future__ import annotations

import spconv.pytorch as spconv
import torch
from torch import nn


def dense(tensor: spconv.SparseConvTensor) -> torch.Tensor:
    """spconv's SparseConvTensor.dense(): (B, C, D, H, W), zero where no cell is active. Each active cell's features
    are written into a channel-last view of the output, with no full-size transposed copy (spconv's makes one;
    tools/benchmark_model.py times each module); torch indexing, so safe on all threads."""
    depth, height, width = tensor.spatial_shape
    out = tensor.features.new_zeros(tensor.batch_size, tensor.features.shape[1], depth, height, width)
    b, z, y, x = tensor.indices.long().unbind(dim=1)
    out.permute(0, 2, 3, 4, 1)[b, z, y, x] = tensor.features
    return out


class HeightCompression(nn.Module):
    """Stack the z cells of the sparse output into channels: (B, C, D, H, W) -> (B, C * D, H, W)."""

    def __init__(self, model_cfg, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        self.num_bev_features = model_cfg.NUM_BEV_FEATURES

    def forward(self, batch_dict: dict) -> dict:
        spatial_features = dense(batch_dict["encoded_spconv_tensor"])
        batch, channels, depth, height, width = spatial_features.shape
        batch_dict["spatial_features"] = spatial_features.view(batch, channels * depth, height, width)
        batch_dict["spatial_features_stride"] = batch_dict["encoded_spconv_tensor_stride"]
        return batch_dict
