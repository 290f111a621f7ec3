"""Optimizers and learning-rate schedules by OPTIMIZATION.OPTIMIZER name (OpenPCDet's names)."""
from __future__ import annotations

import torch

from pcdet_memslidar.errors import ConfigError

BATCH_NORMS = (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d, torch.nn.BatchNorm3d, torch.nn.SyncBatchNorm)


def onecycle_parameter_groups(model: torch.nn.Module) -> list[list[torch.nn.Parameter]]:
    """OpenPCDet's two parameter groups of adam_onecycle: [the trainable parameters of every module but the batch
    norms, those of the batch norms], each in model.parameters() order, so optimizer states move both ways."""
    norm = {id(p) for module in model.modules() if isinstance(module, BATCH_NORMS)
            for p in module.parameters(recurse=False)}
    params = [p for p in model.parameters() if p.requires_grad]
    return [[p for p in params if id(p) not in norm], [p for p in params if id(p) in norm]]


def build_optimizer(model: torch.nn.Module, optim_cfg) -> torch.optim.Optimizer:
    """adam_onecycle: AdamW (betas 0.9, 0.99; decoupled WEIGHT_DECAY, as OpenPCDet's wrapper applies it) over
    OpenPCDet's two parameter groups (onecycle_parameter_groups); adam: Adam with L2 WEIGHT_DECAY; sgd: SGD with
    MOMENTUM (one group each, as in OpenPCDet)."""
    params = [p for p in model.parameters() if p.requires_grad]
    name = optim_cfg.OPTIMIZER
    if name == "adam_onecycle":
        groups = [{"params": group} for group in onecycle_parameter_groups(model)]
        return torch.optim.AdamW(groups, lr=optim_cfg.LR, betas=(0.9, 0.99), weight_decay=optim_cfg.WEIGHT_DECAY)
    if name == "adam":
        return torch.optim.Adam(params, lr=optim_cfg.LR, weight_decay=optim_cfg.WEIGHT_DECAY)
    if name == "sgd":
        return torch.optim.SGD(params, lr=optim_cfg.LR, weight_decay=optim_cfg.WEIGHT_DECAY,
                               momentum=optim_cfg.MOMENTUM)
    raise ConfigError(f"OPTIMIZATION.OPTIMIZER '{name}' is unknown: use adam_onecycle, adam or sgd")


def build_scheduler(optimizer: torch.optim.Optimizer, total_iters_each_epoch: int, total_epochs: int,
                    last_epoch: int, optim_cfg) -> torch.optim.lr_scheduler.LRScheduler:
    """Per-iteration schedule. `last_epoch` is the number of iterations already done minus one (-1: fresh).

    adam_onecycle: cosine one-cycle from LR / DIV_FACTOR up to LR over PCT_START of all iterations, then down to
    LR / DIV_FACTOR / 1e4, with beta1 cycling MOMS[0] -> MOMS[1] -> MOMS[0]; others: LR times LR_DECAY at each
    epoch of DECAY_STEP_LIST, never below LR_CLIP.
    """
    total_steps = max(1, total_iters_each_epoch * total_epochs)
    decay_iters = [epoch * total_iters_each_epoch for epoch in optim_cfg.get("DECAY_STEP_LIST", [])]
    lr_clip = optim_cfg.get("LR_CLIP", 0.0) / optim_cfg.LR

    def factor(it: int) -> float:
        return max(optim_cfg.get("LR_DECAY", 0.1) ** sum(it >= step for step in decay_iters), lr_clip)

    def build(last: int) -> torch.optim.lr_scheduler.LRScheduler:
        if optim_cfg.OPTIMIZER == "adam_onecycle":
            moms = optim_cfg.get("MOMS", [0.95, 0.85])
            return torch.optim.lr_scheduler.OneCycleLR(
                optimizer, max_lr=optim_cfg.LR, total_steps=total_steps, pct_start=optim_cfg.get("PCT_START", 0.4),
                anneal_strategy="cos", cycle_momentum=True, base_momentum=moms[1], max_momentum=moms[0],
                div_factor=optim_cfg.get("DIV_FACTOR", 10), final_div_factor=1e4, last_epoch=last)
        return torch.optim.lr_scheduler.LambdaLR(optimizer, factor, last_epoch=last)

    if last_epoch >= 0:
        for group in optimizer.param_groups:
            group["lr"] = optim_cfg.LR
        build(-1)  # writes this config's schedule settings (initial_lr, max_lr, ...) into the param groups
    return build(last_epoch)
