"""`memslidar train` / tools/train.py: train a detector with OpenPCDet's flags, then evaluate it on the test split.

Output: <output root>/<group>/<cfg>/<extra_tag>/{ckpt/checkpoint_epoch_N.pth, log_train_*.txt, tensorboard/,
eval/eval_with_train/epoch_N/<split>/result.pkl}. Training resumes from the newest checkpoint in ckpt/.
"""
from __future__ import annotations

import argparse
import datetime
import time

import torch
from tensorboardX import SummaryWriter

from pcdet_memslidar.config import log_config_to_file
from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import checkpoint_epoch, list_checkpoints, load_params_from_file
from pcdet_memslidar.runtime.common import create_logger, set_random_seed
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch, split_config
from pcdet_memslidar.runtime.experiment import (add_common_arguments, ap_line, check_learning_rate, positive_count,
                                                scalars, setup_experiment, test_split)
from pcdet_memslidar.runtime.train_loop import prepare_training, train_model

SEED = 666  # OpenPCDet's fixed seed (plus the rank)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common_arguments(parser)
    parser.add_argument("--epochs", type=int, default=None, help="default OPTIMIZATION.NUM_EPOCHS")
    parser.add_argument("--pretrained_model", default=None, help="weights to start from (matching entries)")
    parser.add_argument("--sync_bn", action="store_true", default=False, help="synchronised BatchNorm (GPU)")
    parser.add_argument("--fix_random_seed", action="store_true", default=False, help="reproducible run")
    parser.add_argument("--ckpt_save_interval", type=int, default=1, help="epochs between checkpoints")
    parser.add_argument("--max_ckpt_save_num", type=int, default=30, help="checkpoints kept")
    parser.add_argument("--merge_all_iters_to_one_epoch", action="store_true", default=False)
    parser.add_argument("--num_epochs_to_eval", type=int, default=0,
                        help="evaluate the checkpoints of the last N epochs after training (0: the last one)")
    parser.add_argument("--use_tqdm_to_record", action="store_true", default=False,
                        help="log progress lines instead of tqdm bars")
    parser.add_argument("--logger_iter_interval", type=int, default=50)
    parser.add_argument("--ckpt_save_time_interval", type=int, default=300, help="seconds between latest_model saves")
    parser.add_argument("--wo_gpu_stat", action="store_true", default=False, help="accepted for compatibility")
    parser.add_argument("--use_amp", action="store_true", default=False, help="mixed precision (CUDA only)")
    parser.add_argument("--val_interval", type=int, default=1,
                        help="epochs between AP evaluations on the val split (tensorboard val/*); 0: none")


def run(args: argparse.Namespace) -> int:
    exp = setup_experiment(args)
    cfg = exp.cfg
    check_learning_rate(cfg)
    epochs = positive_count(args.epochs, "--epochs", cfg, "NUM_EPOCHS")
    if args.fix_random_seed:
        set_random_seed(SEED + exp.rank)
    log_file = exp.output_dir / f"log_train_{datetime.datetime.now():%Y%m%d-%H%M%S}.txt"
    logger = create_logger(log_file, rank=exp.rank)
    logger.info("**********************Start logging**********************")
    logger.info(f"device {exp.device}, {exp.world_size} process(es), {exp.threads} torch threads each, "
                f"batch size {exp.batch_size} per process, profile {cfg.get('PROFILE')}")
    for key, value in vars(args).items():
        logger.info(f"{key:24} {value}")
    log_config_to_file(cfg, logger=logger)

    # Every split the run reads (train, val when evaluated during training, test) is loaded, and so checked (its
    # folders, frames and infos), before the first training step: a wrong TEST_SOURCE must not cost a training.
    train_set, train_loader, train_sampler = build_dataloader(
        dataset_cfg=cfg.DATA_CONFIG, class_names=cfg.CLASS_NAMES, batch_size=exp.batch_size, dist=exp.dist,
        workers=args.workers, logger=logger, training=True, seed=SEED if args.fix_random_seed else None,
        merge_all_iters_to_one_epoch=args.merge_all_iters_to_one_epoch, total_epochs=epochs)
    if args.val_interval > 0:
        val_cfg = split_config(cfg, "val")
        _, val_loader, _ = build_dataloader(dataset_cfg=val_cfg.DATA_CONFIG, class_names=cfg.CLASS_NAMES,
                                            batch_size=exp.batch_size, dist=exp.dist, workers=args.workers,
                                            logger=logger, training=False)
    test_set, test_loader, _ = build_dataloader(
        dataset_cfg=cfg.DATA_CONFIG, class_names=cfg.CLASS_NAMES, batch_size=exp.batch_size, dist=exp.dist,
        workers=args.workers, logger=logger, training=False)

    ckpt_dir = exp.output_dir / "ckpt"
    if exp.rank == 0:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
    tb_log = SummaryWriter(str(exp.output_dir / "tensorboard")) if exp.rank == 0 else None
    iters_per_epoch = (len(train_loader) // max(epochs, 1) if args.merge_all_iters_to_one_epoch
                       else len(train_loader))
    model, optimizer, lr_scheduler, it, start_epoch = prepare_training(
        cfg, train_set, ckpt_dir, exp.device, iters_per_epoch, epochs, logger, resume_from=args.ckpt,
        pretrained_model=args.pretrained_model, sync_bn=args.sync_bn and exp.dist and exp.device.type == "cuda")
    if exp.dist:
        device_ids = [exp.device.index] if exp.device.type == "cuda" else None
        model = torch.nn.parallel.DistributedDataParallel(model, device_ids=device_ids)

    on_epoch_end = None
    if args.val_interval > 0:

        def on_epoch_end(epoch: int, mean_loss: float) -> None:
            if epoch % args.val_interval:
                return
            result = eval_one_epoch(val_cfg, model, val_loader, epoch, logger, exp.device, dist_test=exp.dist)
            if exp.rank == 0:
                logger.info(f"epoch {epoch} val: {ap_line(result)}")
                tb_log.add_scalar("train/epoch_loss", mean_loss, epoch)
                for key, value in scalars(result).items():
                    tb_log.add_scalar(f"val/{key}", value, epoch)

    logger.info(f"**********************Start training {cfg.EXP_GROUP_PATH}/{cfg.TAG}({args.extra_tag})"
                f"**********************")
    started = time.time()
    train_model(model, optimizer, train_loader, lr_scheduler, cfg.OPTIMIZATION, start_epoch, epochs, it,
                exp.rank, tb_log, ckpt_dir, exp.device, train_sampler=train_sampler,
                ckpt_save_interval=args.ckpt_save_interval, max_ckpt_save_num=args.max_ckpt_save_num,
                merge_all_iters_to_one_epoch=args.merge_all_iters_to_one_epoch, logger=logger,
                logger_iter_interval=args.logger_iter_interval, ckpt_save_time_interval=args.ckpt_save_time_interval,
                use_tqdm_to_record=args.use_tqdm_to_record, use_amp=args.use_amp, on_epoch_end=on_epoch_end)
    logger.info(f"training done in {time.time() - started:.1f} s")
    if exp.dist:
        torch.distributed.barrier()  # rank 0 has written the last checkpoint

    eval_model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=test_set).to(exp.device)
    first_epoch = max(epochs - args.num_epochs_to_eval, 0) if args.num_epochs_to_eval else epochs
    eval_tb = SummaryWriter(str(exp.output_dir / "eval" / "eval_with_train" / "tensorboard_val")) \
        if exp.rank == 0 else None
    for ckpt in list_checkpoints(ckpt_dir):
        epoch = checkpoint_epoch(ckpt)
        if epoch < first_epoch:
            continue
        load_params_from_file(eval_model, ckpt, logger, strict=True)
        result_dir = exp.output_dir / "eval" / "eval_with_train" / f"epoch_{epoch}" / test_split(cfg)
        result = eval_one_epoch(cfg, eval_model, test_loader, epoch, logger, exp.device, dist_test=exp.dist,
                                result_dir=result_dir, save_to_file=args.save_to_file)
        if exp.rank == 0:
            logger.info(f"epoch {epoch}: {ap_line(result)}")
            for key, value in scalars(result).items():
                eval_tb.add_scalar(key, value, epoch)
                tb_log.add_scalar(f"eval/{key}", value, epoch)
    for writer in (tb_log, eval_tb):
        if writer is not None:
            writer.close()
    logger.info("**********************End evaluation**********************")
    return 0
