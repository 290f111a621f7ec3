"""Box encoding relative to anchors (OpenPCDet's ResidualCoder)."""
from __future__ import annotations

import math

import torch

# Largest log size ratio decoded: exp(4.135) = 62.5 x the anchor size; keeps extreme regressions finite.
LOG_SIZE_CLIP = math.log(1000.0 / 16)


class ResidualCoder:
    """Boxes [x, y, z, dx, dy, dz, heading, ...] <-> residuals: x, y over the anchor's BEV diagonal, z over its
    height, log size ratios, heading difference; extra columns (velocities) are differences."""

    def __init__(self, code_size: int = 7, encode_angle_by_sin_cos: bool = False, **kwargs):
        if encode_angle_by_sin_cos:
            raise ValueError("BOX_CODER_CONFIG.encode_angle_by_sin_cos is not supported: use the default False")
        self.code_size = code_size

    def encode_torch(self, boxes: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """boxes (N, 7+C), anchors (N, 7+C) -> residuals (N, 7+C)."""
        anchors = torch.cat([anchors[:, :3], anchors[:, 3:6].clamp_min(1e-5), anchors[:, 6:]], dim=-1)
        boxes = torch.cat([boxes[:, :3], boxes[:, 3:6].clamp_min(1e-5), boxes[:, 6:]], dim=-1)
        xa, ya, za, dxa, dya, dza, ra, *cas = torch.split(anchors, 1, dim=-1)
        xg, yg, zg, dxg, dyg, dzg, rg, *cgs = torch.split(boxes, 1, dim=-1)
        diagonal = torch.sqrt(dxa ** 2 + dya ** 2)
        residuals = [(xg - xa) / diagonal, (yg - ya) / diagonal, (zg - za) / dza,
                     torch.log(dxg / dxa), torch.log(dyg / dya), torch.log(dzg / dza), rg - ra]
        residuals += [g - a for g, a in zip(cgs, cas)]
        return torch.cat(residuals, dim=-1)

    def decode_torch(self, residuals: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """residuals (..., 7+C), anchors (..., 7+C) -> boxes (..., 7+C); size exponents clamped, always finite."""
        xa, ya, za, dxa, dya, dza, ra, *cas = torch.split(anchors, 1, dim=-1)
        xt, yt, zt, dxt, dyt, dzt, rt, *cts = torch.split(residuals, 1, dim=-1)
        diagonal = torch.sqrt(dxa ** 2 + dya ** 2)
        sizes = [torch.exp(t.clamp(-LOG_SIZE_CLIP, LOG_SIZE_CLIP)) * a for t, a in ((dxt, dxa), (dyt, dya), (dzt, dza))]
        boxes = [xt * diagonal + xa, yt * diagonal + ya, zt * dza + za, *sizes, rt + ra]
        boxes += [t + a for t, a in zip(cts, cas)]
        return torch.cat(boxes, dim=-1)
