"""The training loop: epochs of forward, backward, gradient clipping, optimizer and schedule steps, with
tensorboard scalars, tqdm progress and OpenPCDet-style checkpoints (checkpoint_epoch_N.pth, latest_model.pth)."""
from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import torch

from pcdet_memslidar.datasets.dataset import iterate_batches
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.runtime.checkpoint import (
    checkpoint_state,
    list_checkpoints,
    load_params_from_file,
    load_params_with_optimizer,
    save_checkpoint,
    unwrap,
)
from pcdet_memslidar.runtime.common import cpu_has_bf16, threads_giving_way
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.weight_average import weight_average
from pcdet_memslidar.utils.progress import progress_bar


def prepare_training(cfg, train_set, ckpt_dir: Path, device, iters_per_epoch: int, epochs: int, logger,
                     resume_from=None, pretrained_model=None, sync_bn: bool = False):
    """cfg's detector on `device` in training mode, its optimizer and learning-rate scheduler, resumed from
    `resume_from` (default: the newest checkpoint in ckpt_dir, if any), and the average of its weights
    (runtime.weight_average; None without OPTIMIZATION.EMA_DECAY). Returns (model, optimizer, lr_scheduler,
    iteration, start_epoch, average)."""
    model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=train_set)
    model.profile = cfg.get("PROFILE")  # recorded in its checkpoints (checkpoint.trained_on)
    if sync_bn:
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    model.to(device)
    optimizer = build_optimizer(model, cfg.OPTIMIZATION)
    if pretrained_model:
        load_params_from_file(model, pretrained_model, logger)
    checkpoints = list_checkpoints(ckpt_dir)
    resume_from = resume_from or (checkpoints[-1] if checkpoints else None)
    it = start_epoch = 0
    if resume_from is not None:
        it, start_epoch = load_params_with_optimizer(model, resume_from, optimizer, logger)
        logger.info(f"resuming from {resume_from}: epoch {start_epoch}, iteration {it}")
    model.train()
    lr_scheduler = build_scheduler(optimizer, iters_per_epoch, epochs, last_epoch=it - 1, optim_cfg=cfg.OPTIMIZATION)
    average = weight_average(cfg.OPTIMIZATION, model, it, resume_from, logger)
    return model, optimizer, lr_scheduler, it, start_epoch, average


def train_one_step(model, optimizer, lr_scheduler, batch: dict, grad_norm_clip: float, device,
                   scaler: torch.amp.GradScaler | None = None, phase_done=None) -> tuple[float, dict]:
    """One optimisation step on `batch` (an OpenPCDet batch_dict). Returns (loss, tb_dict). phase_done(name), if
    given, is called as each phase ends: 'to device', 'forward', 'backward', 'optimizer' (tools/benchmark_model.py
    times them). On a CPU the optimizer's update takes only the cores no other process is using: it is elementwise,
    so its results do not depend on the thread count (the forward and backward keep torch's threads: theirs do)."""
    phase_done = phase_done or (lambda name: None)
    model.train()
    load_data_to_device(batch, device)
    phase_done("to device")
    optimizer.zero_grad(set_to_none=True)
    autocast = torch.autocast("cuda", dtype=torch.float16) if scaler is not None else contextlib.nullcontext()
    with autocast:
        ret_dict, tb_dict, _ = model(batch)
        loss = ret_dict["loss"].mean()
    phase_done("forward")
    if scaler is not None:
        scaler.scale(loss).backward()
        scaler.unscale_(optimizer)
    else:
        loss.backward()
    phase_done("backward")
    torch.nn.utils.clip_grad_norm_(model.parameters(), grad_norm_clip)
    if scaler is not None:
        scaler.step(optimizer)
        scaler.update()
    elif torch.device(device).type == "cpu":
        with threads_giving_way() as give_way:  # the update is elementwise: the same bits on any thread count
            give_way()
            optimizer.step()
    else:
        optimizer.step()
    lr_scheduler.step()
    unwrap(model).update_global_step()
    loss = loss.item()
    phase_done("optimizer")
    return loss, tb_dict


def _batches(train_loader, train_sampler, epoch: int, state: dict):
    """Endless batches; the sampler gets the epoch of each new pass (shuffling differs per pass)."""
    while True:
        if train_sampler is not None:
            train_sampler.set_epoch(epoch + state["passes"])
        state["passes"] += 1
        yield from iterate_batches(train_loader)


def train_model(model, optimizer, train_loader, lr_scheduler, optim_cfg, start_epoch: int, total_epochs: int,
                start_iter: int, rank: int, tb_log, ckpt_save_dir: str | Path, device, train_sampler=None,
                ckpt_save_interval: int = 1, max_ckpt_save_num: int = 50, merge_all_iters_to_one_epoch: bool = False,
                logger: logging.Logger | None = None, logger_iter_interval: int = 50,
                ckpt_save_time_interval: float = 300, use_tqdm_to_record: bool = False,
                use_amp: bool = False, on_epoch_start=None, on_epoch_end=None,
                average=None) -> int:
    """Train from `start_epoch` to `total_epochs`; rank 0 writes checkpoints and logs. Returns the iteration
    count reached. Mixed precision (use_amp or OPTIMIZATION.USE_AMP): fp16 autocast and a gradient scaler on a GPU
    (OpenPCDet's --use_amp); bf16 in the BEV backbone and head on a CPU that has bf16 units. With
    merge_all_iters_to_one_epoch the loader holds all epochs and is cut into equal parts. on_epoch_start(epoch) runs
    on every rank before each epoch's first batch (epoch counts from 0, OpenPCDet's cur_epoch); on_epoch_end(epoch,
    mean_loss) after each epoch's checkpoint (epoch counts from 1). average (runtime.weight_average): updated after
    every step and saved as the checkpoints' model_state."""
    logger = logger or logging.getLogger(__name__)
    ckpt_save_dir = Path(ckpt_save_dir)
    accumulated_iter = start_iter
    iters_per_epoch = len(train_loader) // max(total_epochs, 1) if merge_all_iters_to_one_epoch else len(train_loader)
    if iters_per_epoch == 0:
        raise ValueError("the training split gives no batch: add frames or lower --batch-size")
    use_amp = use_amp or bool(optim_cfg.get("USE_AMP", False))
    scaler = torch.amp.GradScaler("cuda") if use_amp and torch.device(device).type == "cuda" else None
    if use_amp and scaler is None:
        if cpu_has_bf16():
            unwrap(model).set_precision("bf16", training=True)
            logger.info("mixed precision on the CPU: the BEV backbone and head train in bfloat16 (autocast); the "
                        "sparse 3D part, the loss and the weights stay fp32")
        else:
            logger.info("mixed precision is off: this CPU has no bfloat16 units (AVX512-BF16 or AMX), and torch "
                        "emulates bfloat16 slower than fp32; training in fp32")
    state = {"passes": 0}
    batches = _batches(train_loader, train_sampler, start_epoch, state)
    show_bar = rank == 0 and not use_tqdm_to_record
    last_save = time.time()
    for epoch in progress_bar(range(start_epoch, total_epochs), enabled=show_bar, desc="epochs"):
        if on_epoch_start is not None:
            on_epoch_start(epoch)
        epoch_start = time.time()
        epoch_loss = 0.0
        with progress_bar(total=iters_per_epoch, enabled=show_bar, desc="train", leave=False) as bar:
            for step in range(iters_per_epoch):
                loss, tb_dict = train_one_step(model, optimizer, lr_scheduler, next(batches),
                                               optim_cfg.GRAD_NORM_CLIP, device, scaler)
                if average is not None:
                    average.update(model)
                accumulated_iter += 1
                epoch_loss += loss
                lr = optimizer.param_groups[0]["lr"]
                bar.set_postfix(loss=f"{loss:.3f}", lr=f"{lr:.2e}")
                bar.update()
                if rank != 0:
                    continue
                if tb_log is not None:
                    tb_log.add_scalar("train/loss", loss, accumulated_iter)
                    tb_log.add_scalar("meta_data/learning_rate", lr, accumulated_iter)
                    for key, value in tb_dict.items():
                        tb_log.add_scalar(f"train/{key}", value, accumulated_iter)
                if use_tqdm_to_record and (step + 1) % logger_iter_interval == 0:
                    rate = (time.time() - epoch_start) / (step + 1)
                    logger.info(f"epoch {epoch + 1}/{total_epochs} iter {step + 1}/{iters_per_epoch} "
                                f"loss {loss:.4f} lr {lr:.3e} {rate:.2f} s/iter")
                if time.time() - last_save > ckpt_save_time_interval:
                    save_checkpoint(checkpoint_state(model, optimizer, epoch, accumulated_iter, average),
                                    ckpt_save_dir / "latest_model.pth")
                    last_save = time.time()
        trained_epoch = epoch + 1
        if rank == 0:
            logger.info(f"epoch {trained_epoch}/{total_epochs}: loss {loss:.4f}, {time.time() - epoch_start:.1f} s")
            if trained_epoch % ckpt_save_interval == 0 or trained_epoch == total_epochs:
                existing = list_checkpoints(ckpt_save_dir)
                for old in existing[:max(0, len(existing) - max_ckpt_save_num + 1)]:
                    old.unlink()
                save_checkpoint(checkpoint_state(model, optimizer, trained_epoch, accumulated_iter,
                                                 average),
                                ckpt_save_dir / f"checkpoint_epoch_{trained_epoch}.pth")
        if on_epoch_end is not None:
            on_epoch_end(trained_epoch, epoch_loss / iters_per_epoch)
            model.train()
    return accumulated_iter
