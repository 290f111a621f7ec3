"""Training a detector into a run folder: the one set-up behind `memslidar train`, tools/train.py and reproduce.

    train set and validation split -> detector, optimiser, schedule (resumed from the newest checkpoint)
    -> epochs of the training loop, with the AP on the validation split every `val_interval` epochs
    -> <run_dir>/ckpt/checkpoint_epoch_N.pth (OpenPCDet's layout)
"""
from __future__ import annotations

import contextlib
import functools
import time
from pathlib import Path

import torch

from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.runtime.common import set_random_seed
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch, split_config
from pcdet_memslidar.runtime.experiment import Process, local_process
from pcdet_memslidar.runtime.hooks import DisableAugmentationHook
from pcdet_memslidar.runtime.pretrain import PRETRAIN_DIR, split_stages
from pcdet_memslidar.runtime.train_loop import prepare_training, train_model


def final_checkpoint(cfg, run_dir: Path) -> Path:
    """The checkpoint a finished training of cfg leaves in run_dir: ckpt/checkpoint_epoch_<NUM_EPOCHS>.pth (of the
    fine-tuning stage for a config with PRETRAIN)."""
    return Path(run_dir) / "ckpt" / f"checkpoint_epoch_{split_stages(cfg)[1].OPTIMIZATION.NUM_EPOCHS}.pth"


def _shifted_epoch(on_epoch, shift: int, epoch: int, *rest) -> None:
    on_epoch(epoch + shift, *rest)


def train(cfg, run_dir: Path, logger, process: Process | None = None, seed: int | None = None, workers: int = 0,
          resume_from=None, pretrained_model=None, sync_bn: bool = False, merge_all_iters_to_one_epoch: bool = False,
          val_interval: int = 1, on_epoch=None, tb_log=None, **loop_options) -> Path:
    """Train cfg's detector for OPTIMIZATION.NUM_EPOCHS epochs of BATCH_SIZE_PER_GPU frames per process into
    run_dir/ckpt, resuming from `resume_from` or else the newest checkpoint there; returns the final checkpoint
    (when it exists already and no `resume_from` is given, nothing is trained). A config with PRETRAIN trains its
    two stages (runtime.pretrain; stage 1 is skipped when `pretrained_model` is given) and on_epoch counts their
    epochs on.

    process: where it runs, and the execution policy of its detector (default: this process alone); with
    process.dist the model is wrapped in DistributedDataParallel. seed: seeds Python, numpy and torch (plus the
    rank) and the data order (None: random). After every epoch on_epoch(epoch, mean_loss, val_result, seconds) runs
    on every rank: val_result is the AP on the mix's validation split when the epoch is a multiple of `val_interval`
    (0: never; else None; {} on ranks other than 0), seconds the epoch's training wall time without validation.
    loop_options go to train_model (checkpoint intervals, log interval, tqdm, amp); tb_log gets its per-iteration
    scalars.
    """
    process = process or local_process()
    pretraining, cfg = split_stages(cfg)
    if pretraining is not None and pretrained_model is None:  # stage 1 of pre-training then fine-tuning (M5)
        pretrained_model = train(pretraining, Path(run_dir) / PRETRAIN_DIR, logger, process, seed, workers,
                                 sync_bn=sync_bn, val_interval=val_interval, on_epoch=on_epoch, **loop_options)
        if on_epoch is not None:  # stage 2's epochs continue stage 1's
            on_epoch = functools.partial(_shifted_epoch, on_epoch, pretraining.OPTIMIZATION.NUM_EPOCHS)
    final = final_checkpoint(cfg, run_dir)
    if final.is_file() and resume_from is None:
        logger.info(f"reusing {final}: the training has reached its last epoch")
        return final
    if seed is not None:
        set_random_seed(seed + process.rank)
    epochs, batch_size = cfg.OPTIMIZATION.NUM_EPOCHS, cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU
    hook = DisableAugmentationHook.from_cfg(cfg)  # checked before any work
    train_set, train_loader, sampler = build_dataloader(
        cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size, process.dist, workers=workers, seed=seed, logger=logger,
        training=True, merge_all_iters_to_one_epoch=merge_all_iters_to_one_epoch, total_epochs=epochs)
    if val_interval > 0:
        val_cfg = split_config(cfg, "val")
        _, val_loader, _ = build_dataloader(val_cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size, process.dist,
                                            workers=workers, logger=logger, training=False)
    ckpt_dir = final.parent
    if process.rank == 0:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
    iters_per_epoch = len(train_loader) // max(epochs, 1) if merge_all_iters_to_one_epoch else len(train_loader)
    model, optimizer, lr_scheduler, it, start_epoch, average = prepare_training(
        cfg, train_set, ckpt_dir, process.device, iters_per_epoch, epochs, logger, resume_from=resume_from,
        pretrained_model=pretrained_model, sync_bn=sync_bn and process.dist and process.device.type == "cuda")
    model.set_policy(process.policy)
    if process.dist:
        device_ids = [process.device.index] if process.device.type == "cuda" else None
        model = torch.nn.parallel.DistributedDataParallel(model, device_ids=device_ids)

    clock = {"start": time.perf_counter()}

    def on_epoch_end(epoch: int, mean_loss: float) -> None:
        seconds = time.perf_counter() - clock["start"]
        result = None
        if val_interval > 0 and epoch % val_interval == 0:
            # the loader's base seed comes from torch's RNG: fork it, so validating leaves the training unchanged
            rng = torch.random.fork_rng(devices=[process.device] if process.device.type == "cuda" else [])
            weights = average.applied(model) if average is not None else contextlib.nullcontext()
            with rng, weights:  # the weights a checkpoint holds as model_state (the average, when there is one)
                result = eval_one_epoch(val_cfg, model, val_loader, epoch, logger, process.device,
                                        dist_test=process.dist)
        if on_epoch is not None:
            on_epoch(epoch, mean_loss, result, seconds)
        clock["start"] = time.perf_counter()  # validation time is not training time

    def on_epoch_start(epoch: int) -> None:
        if hook is not None:
            hook.before_epoch(train_set.data_augmentor, cfg.DATA_CONFIG.DATA_AUGMENTOR, epoch, epochs, logger)

    train_model(model, optimizer, train_loader, lr_scheduler, cfg.OPTIMIZATION, start_epoch, epochs, it,
                process.rank, tb_log, ckpt_dir, process.device, train_sampler=sampler,
                merge_all_iters_to_one_epoch=merge_all_iters_to_one_epoch, logger=logger,
                on_epoch_start=on_epoch_start, on_epoch_end=on_epoch_end, average=average, **loop_options)
    if process.dist:
        torch.distributed.barrier()  # rank 0 has written the last checkpoint
    return final
