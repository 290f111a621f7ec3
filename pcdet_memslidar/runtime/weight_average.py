"""An exponential moving average (EMA) of a detector's weights over its training steps (OPTIMIZATION.EMA_DECAY, our
key; absent or null: off).

After optimizer step t (counting from 1) every floating-point entry of the model's state (weights and BatchNorm
running statistics) moves towards the trained value: average = d_t * average + (1 - d_t) * value, with
d_t = min(EMA_DECAY, (1 + t) / (10 + t)), so the first steps do not keep the random initialisation; integer entries
(BatchNorm's step counts) are copied. The average is what gets validated and saved as a checkpoint's 'model_state'
(what OpenPCDet's test.py and ours load); the trained weights go beside it as 'training_state', which resuming reads.
Averaging reads the weights and never writes them: a training with it takes the same steps, to the bit.
"""
from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.runtime.checkpoint import read_checkpoint, unwrap


class WeightAverage:
    """The EMA of `model`'s state_dict entries (CPU or GPU, where the model is) with decay at most `decay`."""

    def __init__(self, model: torch.nn.Module, decay: float, steps: int = 0, state: dict | None = None):
        self.decay, self.steps = decay, steps
        own = model.state_dict()
        self.state = {key: (state[key] if state is not None else value).detach().clone().to(value.device)
                      for key, value in own.items()}

    def update(self, model: torch.nn.Module) -> None:
        """Fold in the state of `model` after one more optimizer step."""
        self.steps += 1
        decay = min(self.decay, (1 + self.steps) / (10 + self.steps))
        floats, targets = [], []
        for key, value in unwrap(model).state_dict().items():
            if value.is_floating_point():
                floats.append(self.state[key])
                targets.append(value.detach())
            else:
                self.state[key].copy_(value)
        torch._foreach_lerp_(floats, targets, 1.0 - decay)

    @contextlib.contextmanager
    def applied(self, model: torch.nn.Module):
        """Inside the block `model` holds the average; its trained state comes back after."""
        model = unwrap(model)
        trained = {key: value.detach().clone() for key, value in model.state_dict().items()}
        model.load_state_dict(self.state)
        try:
            yield model
        finally:
            model.load_state_dict(trained)


def weight_average(optim_cfg, model: torch.nn.Module, steps: int, resume_from: str | Path | None = None,
                   logger: logging.Logger | None = None) -> WeightAverage | None:
    """The average of OPTIMIZATION.EMA_DECAY for `model` after `steps` optimizer steps (None when the key is absent
    or null): resumed from the 'model_state' of `resume_from` when that checkpoint was trained with an average,
    else starting from the model's weights."""
    decay = optim_cfg.get("EMA_DECAY")
    if decay is None:
        return None
    if not 0.0 < float(decay) < 1.0:
        raise ConfigError(f"OPTIMIZATION.EMA_DECAY must be in (0, 1) or null (off), got {decay}: 0.995 averages "
                          "about the last 200 steps")
    model = unwrap(model)
    checkpoint = read_checkpoint(resume_from) if resume_from is not None else {}
    state = checkpoint["model_state"] if checkpoint.get("training_state") is not None else None
    if logger is not None:
        logger.info(f"weights averaged over the steps (EMA, decay {decay}), "
                    f"{'resumed from ' + str(resume_from) if state is not None else 'from the current weights'}")
    return WeightAverage(model, float(decay), steps, state)
