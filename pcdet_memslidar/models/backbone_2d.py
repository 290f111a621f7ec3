"""Dense 2D BEV backbone of SECOND: downsampling blocks, upsampled and concatenated (OpenPCDet's BaseBEVBackbone)."""
from __future__ import annotations

import numpy as np
import torch
from torch import nn


def _bn_relu(channels: int) -> list[nn.Module]:
    return [nn.BatchNorm2d(channels, eps=1e-3, momentum=0.01), nn.ReLU()]


class BaseBEVBackbone(nn.Module):
    """LAYER_NUMS / LAYER_STRIDES / NUM_FILTERS per level; UPSAMPLE_STRIDES / NUM_UPSAMPLE_FILTERS per level."""

    def __init__(self, model_cfg, input_channels: int, **kwargs):
        super().__init__()
        self.model_cfg = model_cfg
        layer_nums = model_cfg.get("LAYER_NUMS", [])
        layer_strides = model_cfg.get("LAYER_STRIDES", [])
        num_filters = model_cfg.get("NUM_FILTERS", [])
        upsample_strides = model_cfg.get("UPSAMPLE_STRIDES", [])
        num_upsample_filters = model_cfg.get("NUM_UPSAMPLE_FILTERS", [])
        if not len(layer_nums) == len(layer_strides) == len(num_filters):
            raise ValueError("BACKBONE_2D: LAYER_NUMS, LAYER_STRIDES and NUM_FILTERS need the same length")
        if len(upsample_strides) != len(num_upsample_filters):
            raise ValueError("BACKBONE_2D: UPSAMPLE_STRIDES and NUM_UPSAMPLE_FILTERS need the same length")

        in_channels = [input_channels, *num_filters[:-1]]
        self.blocks, self.deblocks = nn.ModuleList(), nn.ModuleList()
        for level, (layers, stride, filters) in enumerate(zip(layer_nums, layer_strides, num_filters)):
            block = [nn.ZeroPad2d(1), nn.Conv2d(in_channels[level], filters, 3, stride=stride, padding=0, bias=False),
                     *_bn_relu(filters)]
            for _ in range(layers):
                block += [nn.Conv2d(filters, filters, 3, padding=1, bias=False), *_bn_relu(filters)]
            self.blocks.append(nn.Sequential(*block))
            if level < len(upsample_strides):
                self.deblocks.append(self._upsample(filters, num_upsample_filters[level], upsample_strides[level]))
        channels = sum(num_upsample_filters) if num_upsample_filters else num_filters[-1]
        if len(upsample_strides) > len(layer_nums):
            self.deblocks.append(nn.Sequential(
                nn.ConvTranspose2d(channels, channels, upsample_strides[-1], stride=upsample_strides[-1], bias=False),
                *_bn_relu(channels)))
        self.num_bev_features = channels

    def _upsample(self, in_channels: int, out_channels: int, stride: float) -> nn.Sequential:
        if stride > 1 or (stride == 1 and not self.model_cfg.get("USE_CONV_FOR_NO_STRIDE", False)):
            conv = nn.ConvTranspose2d(in_channels, out_channels, int(stride), stride=int(stride), bias=False)
        else:
            down = int(np.round(1 / stride))
            conv = nn.Conv2d(in_channels, out_channels, down, stride=down, bias=False)
        return nn.Sequential(conv, *_bn_relu(out_channels))

    def forward(self, data_dict: dict) -> dict:
        """spatial_features (B, C, H, W) -> spatial_features_2d (B, num_bev_features, H', W')."""
        spatial_features = data_dict["spatial_features"]
        x, ups = spatial_features, []
        for level, block in enumerate(self.blocks):
            x = block(x)
            stride = int(spatial_features.shape[2] / x.shape[2])
            data_dict[f"spatial_features_{stride}x"] = x
            ups.append(self.deblocks[level](x) if level < len(self.deblocks) else x)
        x = torch.cat(ups, dim=1) if len(ups) > 1 else ups[0]
        if len(self.deblocks) > len(self.blocks):
            x = self.deblocks[-1](x)
        data_dict["spatial_features_2d"] = x
        return data_dict
