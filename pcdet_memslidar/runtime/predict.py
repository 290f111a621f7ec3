"""Prediction with a checkpoint: the one path behind `memslidar test`, the evaluation after `memslidar train` and
reproduce.

    test split -> detector with the checkpoint's weights -> per-frame predictions, AP, ms/frame
"""
from __future__ import annotations

from pathlib import Path

import torch

from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network, is_learned
from pcdet_memslidar.models.detector import PRECISIONS
from pcdet_memslidar.runtime.checkpoint import load_params_from_file
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch
from pcdet_memslidar.runtime.experiment import Process, local_process


def test_loader(cfg, logger, process: Process | None = None, workers: int = 0):
    """(dataset, loader) of cfg's evaluation split (DATA_SPLIT.test) in batches of OPTIMIZATION.BATCH_SIZE_PER_GPU;
    building it checks the split's folders, frames and infos."""
    process = process or local_process()
    dataset, loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU,
                                          process.dist, workers=workers, logger=logger, training=False)
    return dataset, loader


def load_detector(cfg, checkpoint: str | Path | None, dataset, process: Process, logger,
                  precision: str = PRECISIONS[0]) -> tuple[torch.nn.Module, int | None]:
    """(cfg's detector with the weights of `checkpoint`, in eval mode on the process's device with its execution
    policy and the inference `precision` (models.detector.PRECISIONS); the checkpoint's epoch). dataset gives the grid
    (a DatasetTemplate); a checkpoint of another model or grid is refused, naming it. A detector without weights
    (models.is_learned) takes no checkpoint (None)."""
    if is_learned(cfg.MODEL) == (checkpoint is None):
        raise ConfigError(f"MODEL.NAME {cfg.MODEL.NAME} " + ("needs a checkpoint: pass --ckpt" if checkpoint is None
                                                             else "has no weights: leave out --ckpt"))
    model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=dataset).to(process.device)
    model.profile = cfg.get("PROFILE")  # named when a checkpoint of another grid is refused
    model.set_policy(process.policy)
    model.set_precision(precision)
    if precision == "bf16" and process.device.type == "cpu" and not torch.cpu._is_avx512_bf16_supported():
        logger.warning("--precision bf16 on a CPU without AVX512-BF16 or AMX: bf16 is emulated there and slower "
                       "than fp32")
    epoch = None if checkpoint is None else load_params_from_file(model, checkpoint, logger, strict=True).get("epoch")
    return model.eval(), epoch


def predict(cfg, checkpoint: str | Path | None, result_dir: Path, logger, process: Process | None = None,
            workers: int = 0, loader=None, save_to_file: bool = True, precision: str = PRECISIONS[0]) -> dict:
    """Run `checkpoint` over cfg's evaluation split; returns eval_one_epoch's result (AP keys, recall,
    infer_time_ms; {} on ranks other than 0). Writes result_dir/result.pkl and, with save_to_file, KITTI labels
    with scores under eval_loop.prediction_folder(result_dir). loader: test_loader's (dataset, loader), built here
    when None; precision: load_detector's."""
    process = process or local_process()
    dataset, data_loader = loader or test_loader(cfg, logger, process, workers)
    model, epoch = load_detector(cfg, checkpoint, dataset, process, logger, precision)
    return eval_one_epoch(cfg, model, data_loader, epoch, logger, process.device, dist_test=process.dist,
                          result_dir=result_dir, save_to_file=save_to_file)
