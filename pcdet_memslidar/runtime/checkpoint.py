"""Checkpoints in OpenPCDet's format: {'epoch', 'it', 'model_state', 'optimizer_state', 'version'}.

Everything in them is a tensor or a plain Python scalar/string, so they load with torch.load(weights_only=True)
(torch >= 2.6 refuses numpy scalars), and the model state has OpenPCDet's keys, so a checkpoint moves both ways.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import torch

from pcdet_memslidar import __version__
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.utils.atomic import atomic_path

_EPOCH = re.compile(r"checkpoint_epoch_(\d+)\.pth$")


def _plain(value):
    """Tensors moved to the CPU; numpy and torch scalars -> Python scalars; containers converted recursively."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_plain(item) for item in value)
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return value.item()
    return value


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The model inside a DistributedDataParallel wrapper (or the model itself)."""
    return model.module if isinstance(model, torch.nn.parallel.DistributedDataParallel) else model


def checkpoint_state(model=None, optimizer=None, epoch: int | None = None, it: int | None = None) -> dict:
    """OpenPCDet's checkpoint dict with CPU tensors and plain Python scalars."""
    return {
        "epoch": None if epoch is None else int(epoch),
        "it": None if it is None else int(it),
        "model_state": None if model is None else _plain(unwrap(model).state_dict()),
        "optimizer_state": None if optimizer is None else _plain(optimizer.state_dict()),
        "version": f"pcdet_memslidar+{__version__}",
    }


def save_checkpoint(state: dict, filename: str | Path) -> Path:
    """Write `state` atomically to `filename` (.pth added when missing)."""
    path = Path(filename)
    path = path if path.suffix == ".pth" else path.with_name(path.name + ".pth")
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    return path


def read_checkpoint(filename: str | Path) -> dict:
    """torch.load(weights_only=True) on the CPU; DataFormatError naming the file when it is missing or unsafe."""
    path = Path(filename)
    if not path.is_file():
        raise DataFormatError(path, "checkpoint not found: pass an existing .pth file (--ckpt)")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # pickle errors come in many types
        raise DataFormatError(path, f"cannot be loaded with weights_only=True ({error}); re-save it with plain "
                                    "Python scalars instead of numpy ones") from None
    if "model_state" not in checkpoint:
        raise DataFormatError(path, "has no 'model_state': not an OpenPCDet / pcdet_memslidar checkpoint")
    return checkpoint


def checkpoint_epoch(filename: str | Path) -> int | None:
    """N of '.../checkpoint_epoch_N.pth', else None."""
    match = _EPOCH.search(str(filename))
    return int(match.group(1)) if match else None


def list_checkpoints(ckpt_dir: str | Path) -> list[Path]:
    """checkpoint_epoch_N.pth files in `ckpt_dir`, by increasing N."""
    files = [p for p in Path(ckpt_dir).glob("checkpoint_epoch_*.pth") if checkpoint_epoch(p) is not None]
    return sorted(files, key=checkpoint_epoch)


def load_params_from_file(model: torch.nn.Module, filename: str | Path, logger: logging.Logger | None = None,
                          strict: bool = False) -> dict:
    """Load the model state of a checkpoint into `model` (on the model's device). Entries whose name or shape
    does not match are reported (and raise with strict=True). Returns the checkpoint dict."""
    logger = logger or logging.getLogger(__name__)
    checkpoint = read_checkpoint(filename)
    model = unwrap(model)
    own = model.state_dict()
    state = checkpoint["model_state"]
    usable = {k: v for k, v in state.items() if k in own and own[k].shape == v.shape}
    skipped = sorted(set(state) - set(usable))
    missing = sorted(set(own) - set(usable))
    if strict and (skipped or missing):
        raise DataFormatError(filename, f"does not match the model: unexpected or reshaped {skipped[:5]}, "
                                        f"missing {missing[:5]}; check that the config is the one it was trained with")
    model.load_state_dict({**own, **usable})
    logger.info(f"==> Loaded {filename} (version {checkpoint.get('version')}): {len(usable)}/{len(own)} entries")
    for key in missing:
        logger.info(f"Not updated weight {key}: {tuple(own[key].shape)}")
    return checkpoint


def load_params_with_optimizer(model: torch.nn.Module, filename: str | Path, optimizer=None,
                               logger: logging.Logger | None = None) -> tuple[int, int]:
    """Resume: model (strict), optimizer state when it fits. Returns (it, epoch) of the checkpoint."""
    logger = logger or logging.getLogger(__name__)
    checkpoint = load_params_from_file(model, filename, logger, strict=True)
    if optimizer is not None and checkpoint.get("optimizer_state") is not None:
        try:
            optimizer.load_state_dict(checkpoint["optimizer_state"])
        except (ValueError, KeyError) as error:
            logger.info(f"Optimizer state of {filename} not loaded ({error}); starting the optimizer afresh")
    return int(checkpoint.get("it") or 0), int(checkpoint.get("epoch") or 0)
