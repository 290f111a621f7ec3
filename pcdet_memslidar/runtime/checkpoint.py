"""Checkpoints in OpenPCDet's format: {'epoch', 'it', 'model_state', 'optimizer_state', 'version'}, plus our
'memslidar' record, which OpenPCDet's loaders ignore.

Written with CPU tensors and plain Python values; the model state has OpenPCDet's keys and the optimizer state its
parameter groups (optimization.build_optimizer), so checkpoints move both ways. The record says what the weights
were trained on and lets damage be found: {'profile': str | None, 'point_cloud_range': [6] m, 'voxel_size': [3] m,
'sha256': {'model_state': hex, 'optimizer_state': hex}} (state_digest at save time). A training that averages its
weights (runtime.weight_average) saves the average as 'model_state' and its trained weights as 'training_state'.
Read with torch.load(weights_only=True), allowing only the numpy scalar types that OpenPCDet's one-cycle optimizer
state holds. Refused, with the reason: a damaged file (digest), NaN or infinite weights, and (strict loads) a model
on another voxel grid; OpenPCDet's own checkpoints carry no record and get the checks that remain.
"""
from __future__ import annotations

import hashlib
import logging
import re
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar import __version__
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.utils.atomic import atomic_path

_EPOCH = re.compile(r"checkpoint_epoch_(\d+)\.pth$")
_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's default format
_PICKLE_PROTO = 0x80  # the legacy format (OpenPCDet's _use_new_zipfile_serialization=False) is a bare pickle


def numpy_scalar_globals() -> list:
    """What OpenPCDet's optimizer state needs beyond torch's safe defaults: numpy scalars (its one-cycle schedule
    writes lr and beta1 as numpy.float64) under numpy 2.x's and 1.x's module names, and the dtype they carry."""
    try:
        from numpy._core.multiarray import scalar  # numpy >= 2
    except ImportError:
        from numpy.core.multiarray import scalar
    return [(scalar, "numpy._core.multiarray.scalar"), (scalar, "numpy.core.multiarray.scalar"), np.dtype,
            type(np.dtype(np.float64))]


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


def state_digest(state) -> str:
    """sha256 of a (nested) state: keys, tensor dtypes, shapes and bytes, and plain values, in order."""
    digest = hashlib.sha256()

    def update(value) -> None:
        if isinstance(value, torch.Tensor):
            tensor = value.detach().cpu().contiguous()
            digest.update(f"tensor {tensor.dtype} {tuple(tensor.shape)}:".encode())
            digest.update(tensor.reshape(-1).view(torch.uint8).numpy())
        elif isinstance(value, dict):
            digest.update(f"dict {len(value)}:".encode())
            for key, item in value.items():
                digest.update(f"{key!r}=".encode())
                update(item)
        elif isinstance(value, (list, tuple)):
            digest.update(f"{type(value).__name__} {len(value)}:".encode())
            for item in value:
                update(item)
        else:
            digest.update(f"{value!r};".encode())

    update(state)
    return digest.hexdigest()


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The model inside a DistributedDataParallel wrapper (or the model itself)."""
    return model.module if isinstance(model, torch.nn.parallel.DistributedDataParallel) else model


def trained_on(model: torch.nn.Module) -> dict:
    """{'profile', 'point_cloud_range' [6] m, 'voxel_size' [3] m}: the grid of the dataset `model` was built for
    ({} without one) and model.profile, the config's PROFILE, where the caller set it (training, `memslidar test`)."""
    model = unwrap(model)
    dataset = getattr(model, "dataset", None)
    if dataset is None:
        return {}
    return {"profile": getattr(model, "profile", None),
            "point_cloud_range": [round(float(v), 6) for v in dataset.point_cloud_range],
            "voxel_size": [round(float(v), 6) for v in dataset.voxel_size]}


def checkpoint_state(model=None, optimizer=None, epoch: int | None = None, it: int | None = None,
                     average=None) -> dict:
    """OpenPCDet's checkpoint dict with CPU tensors and plain Python scalars, plus the 'memslidar' record. With
    `average` (runtime.weight_average) its state is the 'model_state' and the model's own the 'training_state'."""
    own = None if model is None else _plain(unwrap(model).state_dict())
    model_state = own if average is None else _plain(average.state)
    optimizer_state = None if optimizer is None else _plain(optimizer.state_dict())
    record = {} if model is None else trained_on(model)
    record["sha256"] = {"model_state": state_digest(model_state), "optimizer_state": state_digest(optimizer_state)}
    state = {
        "epoch": None if epoch is None else int(epoch),
        "it": None if it is None else int(it),
        "model_state": model_state,
        "optimizer_state": optimizer_state,
        "version": f"pcdet_memslidar+{__version__}",
        "memslidar": record,
    }
    if average is not None:
        state["training_state"] = own
        record["sha256"]["training_state"] = state_digest(own)
    return state


def save_checkpoint(state: dict, filename: str | Path) -> Path:
    """Write `state` atomically to `filename` (.pth added when missing)."""
    path = Path(filename)
    path = path if path.suffix == ".pth" else path.with_name(path.name + ".pth")
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    return path


def _load_failure(path: Path, error: Exception) -> DataFormatError:
    """Why torch.load refused `path`: an object a safe load does not build, or a damaged / foreign file."""
    text = str(error)
    unsafe = re.search(r"GLOBAL (\S+) was not an allowed global|but got (<class [^>]+>)", text)
    if unsafe:
        return DataFormatError(path, f"holds an object of type {unsafe.group(1) or unsafe.group(2)}, which a safe "
                                     "load (weights_only) does not build; checkpoints may hold only tensors, plain "
                                     "Python values and numpy scalars: load it where it was written and save its "
                                     "weights as torch.save({'model_state': model.state_dict()}, path)")
    detail = re.search(r"WeightsUnpickler error:\s*(.+)", text)
    first = text.splitlines()[0].split(". ")[0] if text else "no data"  # torch's advice after the first sentence
    reason = detail.group(1) if detail else f"{type(error).__name__}: {first}"
    return DataFormatError(path, f"cannot be read: truncated, corrupt or not written by torch.save ({reason}); "
                                 "it was not saved completely or was damaged since: use another checkpoint or copy it "
                                 "again")


def read_checkpoint(filename: str | Path) -> dict:
    """The checkpoint dict, loaded safely on the CPU and checked (see the module docstring); DataFormatError
    naming the file and what is wrong with it otherwise."""
    path = Path(filename)
    if path.is_dir():
        raise DataFormatError(path, "is a folder, not a checkpoint: pass a .pth file (e.g. "
                                    "<run>/ckpt/checkpoint_epoch_N.pth)")
    if not path.is_file():
        raise DataFormatError(path, "checkpoint not found: pass an existing .pth file (--ckpt)")
    with path.open("rb") as file:
        head = file.read(4)
    if not head:
        raise DataFormatError(path, "is empty (0 bytes): its saving was interrupted; use another checkpoint")
    if not head.startswith(_ZIP_MAGIC) and head[0] != _PICKLE_PROTO:
        raise DataFormatError(path, f"is not a PyTorch checkpoint (it starts with {head!r}, neither torch.save's zip "
                                    "nor its legacy pickle format): pass a .pth file written by training")
    try:
        # only those not registered already: leaving the context removes what it added (the OpenPCDet launcher
        # registers them for the whole process)
        registered = torch.serialization.get_safe_globals()
        with torch.serialization.safe_globals([item for item in numpy_scalar_globals() if item not in registered]):
            checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch.load fails with many error types
        raise _load_failure(path, error) from None
    if not isinstance(checkpoint, dict) or "model_state" not in checkpoint:
        if isinstance(checkpoint, dict) and checkpoint and all(isinstance(v, torch.Tensor)
                                                               for v in checkpoint.values()):
            raise DataFormatError(path, "is a bare state_dict, not a checkpoint: save it as "
                                        "torch.save({'model_state': state_dict}, path) (OpenPCDet's layout)")
        found = f"keys {list(checkpoint)[:8]}" if isinstance(checkpoint, dict) else f"a {type(checkpoint).__name__}"
        raise DataFormatError(path, f"has no 'model_state' (it holds {found}): not an OpenPCDet / pcdet_memslidar "
                                    "checkpoint")
    state = checkpoint["model_state"]
    if not isinstance(state, dict) or not all(isinstance(value, torch.Tensor) for value in state.values()):
        raise DataFormatError(path, "'model_state' is not a dict of tensors: not an OpenPCDet / pcdet_memslidar "
                                    "checkpoint")
    record = checkpoint.get("memslidar")
    digests = record.get("sha256", {}) if isinstance(record, dict) else {}
    for key, expected in digests.items():
        if state_digest(checkpoint.get(key)) != expected:
            raise DataFormatError(path, f"'{key}' differs from the sha256 stored when it was saved: the file was "
                                        "damaged since (disk or copy error); use another checkpoint or copy it again")
    for name, tensor in state.items():
        if tensor.is_floating_point() and not torch.isfinite(tensor).all():
            raise DataFormatError(path, f"weight '{name}' {tuple(tensor.shape)} has NaN or infinite values: the "
                                        "training diverged before this checkpoint; use an earlier one (or retrain "
                                        "with a lower OPTIMIZATION.LR)")
    return checkpoint


def _grid_text(record: dict) -> str:
    profile = f"profile '{record['profile']}', " if record.get("profile") else ""
    return f"{profile}POINT_CLOUD_RANGE {record['point_cloud_range']}, VOXEL_SIZE {record['voxel_size']}"


def grid_mismatch(checkpoint: dict, model: torch.nn.Module) -> str | None:
    """Why `checkpoint`'s weights were trained on another voxel grid than `model`'s, or None (same grid, or a
    checkpoint / model that does not say)."""
    saved, here = checkpoint.get("memslidar"), trained_on(model)
    if not isinstance(saved, dict) or "voxel_size" not in saved or not here:
        return None
    if (np.allclose(saved["point_cloud_range"], here["point_cloud_range"], rtol=0, atol=1e-5)
            and np.allclose(saved["voxel_size"], here["voxel_size"], rtol=0, atol=1e-6)):
        return None
    fix = f"--set PROFILE {saved['profile']}" if saved.get("profile") else "its POINT_CLOUD_RANGE and VOXEL_SIZE"
    return (f"was trained on {_grid_text(saved)}, but this config has {_grid_text(here)}: its weights do not fit "
            f"these voxels and anchors. Use the config it was trained with ({fix}) or a checkpoint trained on this "
            "grid")


def _state_mismatch(state: dict, own: dict) -> str:
    """What differs between a checkpoint's model state and the model's (names and shapes), briefly."""
    reshaped = [f"{k} {tuple(state[k].shape)} vs {tuple(own[k].shape)}" for k in state
                if k in own and state[k].shape != own[k].shape]
    parts = [f"{len(items)} {what} ({', '.join(items[:3])}{', ...' if len(items) > 3 else ''})" for what, items in (
        ("weights of another shape, checkpoint vs model", reshaped),
        ("weights the model does not have", [k for k in state if k not in own]),
        ("weights of the model missing", [k for k in own if k not in state])) if items]
    return "; ".join(parts)


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
    does not match, and a checkpoint trained on another grid, are reported (and raise with strict=True).
    Returns the checkpoint dict."""
    logger = logger or logging.getLogger(__name__)
    checkpoint = read_checkpoint(filename)
    model = unwrap(model)
    mismatch = grid_mismatch(checkpoint, model)
    if mismatch and strict:
        raise DataFormatError(filename, mismatch)
    if mismatch:
        logger.warning(f"{filename} {mismatch}")
    own = model.state_dict()
    state = checkpoint["model_state"]
    usable = {k: v for k, v in state.items() if k in own and own[k].shape == v.shape}
    if strict and len(usable) < max(len(state), len(own)):
        raise DataFormatError(filename, f"does not fit the model of this config: {_state_mismatch(state, own)}. Use "
                                        "the config (MODEL section and PROFILE) it was trained with")
    model.load_state_dict({**own, **usable})
    logger.info(f"==> Loaded {filename} (version {checkpoint.get('version')}): {len(usable)}/{len(own)} entries")
    for key in sorted(set(own) - set(usable)):
        logger.info(f"Not updated weight {key}: {tuple(own[key].shape)}")
    return checkpoint


def load_params_with_optimizer(model: torch.nn.Module, filename: str | Path, optimizer=None,
                               logger: logging.Logger | None = None) -> tuple[int, int]:
    """Resume: model (strict; its 'training_state' when it has one), then the optimizer's moments when its
    parameter groups fit; the optimizer keeps the config's settings (weight decay, ...; lr and momentum come from
    the schedule). Returns (it, epoch)."""
    logger = logger or logging.getLogger(__name__)
    checkpoint = load_params_from_file(model, filename, logger, strict=True)
    if checkpoint.get("training_state") is not None:  # the average was the model_state: train on from the weights
        unwrap(model).load_state_dict(checkpoint["training_state"])
    if optimizer is not None and checkpoint.get("optimizer_state") is not None:
        configured = [{k: v for k, v in group.items() if k != "params"} for group in optimizer.param_groups]
        try:
            optimizer.load_state_dict(checkpoint["optimizer_state"])
        except (ValueError, KeyError) as error:
            logger.warning(f"Optimizer state of {filename} not loaded ({error}): the optimizer starts afresh; the "
                           "weights and the schedule's position are resumed")
        else:
            for group, settings in zip(optimizer.param_groups, configured):
                group.update(settings)  # OpenPCDet saves weight_decay 0 (its wrapper applies the decay itself)
    return int(checkpoint.get("it") or 0), int(checkpoint.get("epoch") or 0)
