"""Losses of the heads (OpenPCDet's loss_utils): for the anchor head sigmoid focal, weighted smooth-L1, weighted
cross entropy; for the center head the heatmap focal loss and the L1 loss at object centres."""
from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from pcdet_memslidar.geometry.boxes import limit_period
from pcdet_memslidar.models.centernet import gather_cells


class SigmoidFocalClassificationLoss(nn.Module):
    """Focal loss on logits, numerically stable for any logit (uses log1p(exp(-|x|)))."""

    def __init__(self, gamma: float = 2.0, alpha: float = 0.25):
        super().__init__()
        self.gamma, self.alpha = gamma, alpha

    def forward(self, logits: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """logits, targets (B, A, C) one-hot; weights (B, A) -> loss (B, A, C)."""
        probability = torch.sigmoid(logits)
        alpha_weight = targets * self.alpha + (1 - targets) * (1 - self.alpha)
        p_wrong = targets * (1.0 - probability) + (1.0 - targets) * probability
        bce = torch.clamp_min(logits, 0) - logits * targets + torch.log1p(torch.exp(-logits.abs()))
        return alpha_weight * p_wrong.pow(self.gamma) * bce * weights.unsqueeze(-1)


class WeightedSmoothL1Loss(nn.Module):
    """Smooth-L1 (quadratic below `beta`) per code entry, scaled by code weights and anchor weights."""

    def __init__(self, beta: float = 1.0 / 9.0, code_weights=None):
        super().__init__()
        self.beta = beta
        self.register_buffer("code_weights", None if code_weights is None
                             else torch.tensor(code_weights, dtype=torch.float32), persistent=False)

    def forward(self, predictions: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """predictions, targets (B, A, code); weights (B, A) -> loss (B, A, code); NaN targets count as exact."""
        targets = torch.where(torch.isnan(targets), predictions, targets)
        diff = predictions - targets
        if self.code_weights is not None:
            diff = diff * self.code_weights
        abs_diff = diff.abs()
        loss = torch.where(abs_diff < self.beta, 0.5 * abs_diff ** 2 / self.beta, abs_diff - 0.5 * self.beta)
        return loss * weights.unsqueeze(-1)


class WeightedCrossEntropyLoss(nn.Module):
    """Softmax cross entropy of (B, A, C) logits against one-hot targets, weighted per anchor -> (B, A)."""

    def forward(self, logits: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        return F.cross_entropy(logits.permute(0, 2, 1), targets.argmax(dim=-1), reduction="none") * weights


class FocalLossCenterNet(nn.Module):
    """CornerNet's focal loss of a heatmap: -(sum over peak cells of (1 - p)^2 log p + sum over other cells of
    (1 - target)^4 p^2 log(1 - p)) / number of peaks (not divided where there is none)."""

    def forward(self, probability: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """probability, target (B, C, H, W) in [0, 1] (probability clamped away from 0 and 1) -> scalar."""
        peak = target.eq(1).float()
        positive = (torch.log(probability) * (1 - probability) ** 2 * peak).sum()
        negative = (torch.log(1 - probability) * probability ** 2 * (1 - target) ** 4 * (1 - peak)).sum()
        peaks = peak.sum()
        return -negative if peaks == 0 else -(positive + negative) / peaks


class RegLossCenterNet(nn.Module):
    """L1 loss of regressions read at object centre cells, per code entry, summed over objects and frames and
    divided by the number of objects (at least 1); NaN targets count as exact."""

    def forward(self, output: torch.Tensor, mask: torch.Tensor, inds: torch.Tensor, target: torch.Tensor):
        """output (B, code, H, W); mask, inds (B, M); target (B, M, code) -> (code,)."""
        prediction = gather_cells(output, inds)
        target = torch.where(torch.isnan(target), prediction, target)
        weight = mask.unsqueeze(-1).float()
        loss = (prediction * weight - target * weight).abs().sum(dim=(0, 1))
        return loss / mask.float().sum().clamp_min(1.0)


def add_sin_difference(predictions: torch.Tensor, targets: torch.Tensor, dim: int = 6):
    """Replace heading residuals by sin(a)cos(b) and cos(a)sin(b), so their difference is sin(a - b):
    a heading off by pi costs nothing (the direction classifier resolves it)."""
    sin_pred = torch.sin(predictions[..., dim:dim + 1]) * torch.cos(targets[..., dim:dim + 1])
    sin_target = torch.cos(predictions[..., dim:dim + 1]) * torch.sin(targets[..., dim:dim + 1])
    predictions = torch.cat([predictions[..., :dim], sin_pred, predictions[..., dim + 1:]], dim=-1)
    targets = torch.cat([targets[..., :dim], sin_target, targets[..., dim + 1:]], dim=-1)
    return predictions, targets


def direction_targets(anchors: torch.Tensor, reg_targets: torch.Tensor, dir_offset: float, num_bins: int):
    """One-hot (B, A, num_bins) direction bin of the target heading (anchor heading + residual)."""
    heading = reg_targets[..., 6] + anchors[..., 6]
    offset_heading = limit_period(heading - dir_offset, 0, 2 * math.pi)
    bins = torch.floor(offset_heading / (2 * math.pi / num_bins)).long().clamp(0, num_bins - 1)
    return F.one_hot(bins, num_bins).to(anchors.dtype)
