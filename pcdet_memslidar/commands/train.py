"""`memslidar train` / tools/train.py: train a detector with OpenPCDet's flags (runtime.train), then evaluate its
last checkpoints on the test split (runtime.predict).

Output: <output root>/<group>/<cfg>/<extra_tag>/{ckpt/checkpoint_epoch_N.pth, log_train_*.txt, tensorboard/,
eval/eval_with_train/epoch_N/<split>/result.pkl}. Training resumes from the newest checkpoint in ckpt/.
"""
from __future__ import annotations

import argparse
import datetime
import time

from tensorboardX import SummaryWriter

from pcdet_memslidar.commands.options import add_openpcdet_arguments, setup_experiment
from pcdet_memslidar.config import log_config_to_file
from pcdet_memslidar.runtime.checkpoint import checkpoint_epoch, list_checkpoints
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.experiment import ap_line, option_count, scalars, test_split
from pcdet_memslidar.runtime.predict import predict, test_loader
from pcdet_memslidar.runtime.pretrain import split_stages
from pcdet_memslidar.runtime.train import train

SEED = 666  # OpenPCDet's fixed seed (plus the rank)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_openpcdet_arguments(parser)
    parser.add_argument("--epochs", type=int, default=None, help="default OPTIMIZATION.NUM_EPOCHS")
    parser.add_argument("--pretrained-model", "--pretrained_model", default=None,
                        help="weights to start from (matching entries)")
    parser.add_argument("--sync-bn", "--sync_bn", action="store_true", default=False,
                        help="synchronised BatchNorm (GPU)")
    parser.add_argument("--fix-random-seed", "--fix_random_seed", action="store_true", default=False,
                        help="reproducible run")
    parser.add_argument("--ckpt-save-interval", "--ckpt_save_interval", type=int, default=1,
                        help="epochs between checkpoints")
    parser.add_argument("--max-ckpt-save-num", "--max_ckpt_save_num", type=int, default=30, help="checkpoints kept")
    parser.add_argument("--merge-all-iters-to-one-epoch", "--merge_all_iters_to_one_epoch", action="store_true",
                        default=False, help="one loader pass over all epochs' iterations, cut into epochs")
    parser.add_argument("--num-epochs-to-eval", "--num_epochs_to_eval", type=int, default=0,
                        help="evaluate the checkpoints of the last N epochs after training (0: the last one)")
    parser.add_argument("--use-tqdm-to-record", "--use_tqdm_to_record", action="store_true", default=False,
                        help="log progress lines instead of tqdm bars")
    parser.add_argument("--logger-iter-interval", "--logger_iter_interval", type=int, default=50,
                        help="iterations between log lines")
    parser.add_argument("--ckpt-save-time-interval", "--ckpt_save_time_interval", type=int, default=300,
                        help="seconds between latest_model saves")
    parser.add_argument("--wo-gpu-stat", "--wo_gpu_stat", action="store_true", default=False,
                        help=argparse.SUPPRESS)  # OpenPCDet's; there is no GPU statistic to leave out
    parser.add_argument("--use-amp", "--use_amp", action="store_true", default=False,
                        help="mixed precision, as OPTIMIZATION.USE_AMP: fp16 on a GPU, bf16 in the BEV backbone and "
                             "head on a CPU with bf16 units")
    parser.add_argument("--val-interval", "--val_interval", type=int, default=1,
                        help="epochs between AP evaluations on the val split (tensorboard val/*); 0: none")


def run(args: argparse.Namespace) -> int:
    cfg, process, output_dir = setup_experiment(args)
    cfg.OPTIMIZATION.NUM_EPOCHS = option_count(args.epochs, "--epochs", "NUM_EPOCHS", cfg)
    logger = create_logger(output_dir / f"log_train_{datetime.datetime.now():%Y%m%d-%H%M%S}.txt", rank=process.rank)
    logger.info("**********************Start logging**********************")
    logger.info(f"device {process.device}, {process.world_size} process(es), {process.threads} torch threads each, "
                f"batch size {cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU} per process, profile {cfg.get('PROFILE')}")
    for key, value in vars(args).items():
        logger.info(f"{key:24} {value}")
    log_config_to_file(cfg, logger=logger)

    # The test split is loaded, and so checked (its folders, frames and infos), before the first training step (train
    # and val inside train()): a wrong TEST_SOURCE must not cost a training.
    test_data = test_loader(cfg, logger, process, args.workers)
    tb_log = SummaryWriter(str(output_dir / "tensorboard")) if process.rank == 0 else None

    def log_epoch(epoch: int, mean_loss: float, val: dict | None, seconds: float) -> None:
        if val is None or process.rank != 0:
            return
        logger.info(f"epoch {epoch} val: {ap_line(val)}")
        tb_log.add_scalar("train/epoch_loss", mean_loss, epoch)
        for key, value in scalars(val).items():
            tb_log.add_scalar(f"val/{key}", value, epoch)

    logger.info(f"**********************Start training {cfg.EXP_GROUP_PATH}/{cfg.TAG}({args.extra_tag})"
                f"**********************")
    started = time.time()
    train(cfg, output_dir, logger, process, seed=SEED if args.fix_random_seed else None, workers=args.workers,
          resume_from=args.ckpt, pretrained_model=args.pretrained_model, sync_bn=args.sync_bn,
          merge_all_iters_to_one_epoch=args.merge_all_iters_to_one_epoch, val_interval=args.val_interval,
          on_epoch=log_epoch, tb_log=tb_log, ckpt_save_interval=args.ckpt_save_interval,
          max_ckpt_save_num=args.max_ckpt_save_num, logger_iter_interval=args.logger_iter_interval,
          ckpt_save_time_interval=args.ckpt_save_time_interval, use_tqdm_to_record=args.use_tqdm_to_record,
          use_amp=args.use_amp)
    logger.info(f"training done in {time.time() - started:.1f} s")

    last = split_stages(cfg)[1].OPTIMIZATION.NUM_EPOCHS  # of the fine-tuning stage for a config with PRETRAIN
    first_epoch = max(last - args.num_epochs_to_eval, 0) if args.num_epochs_to_eval else last
    eval_dir = output_dir / "eval" / "eval_with_train"
    eval_tb = SummaryWriter(str(eval_dir / "tensorboard_val")) if process.rank == 0 else None
    for ckpt in list_checkpoints(output_dir / "ckpt"):
        epoch = checkpoint_epoch(ckpt)
        if epoch < first_epoch:
            continue
        result = predict(cfg, ckpt, eval_dir / f"epoch_{epoch}" / test_split(cfg), logger, process,
                         loader=test_data, save_to_file=args.save_to_file)
        if process.rank == 0:
            logger.info(f"epoch {epoch}: {ap_line(result)}")
            for key, value in scalars(result).items():
                eval_tb.add_scalar(key, value, epoch)
                tb_log.add_scalar(f"eval/{key}", value, epoch)
    for writer in (tb_log, eval_tb):
        if writer is not None:
            writer.close()
    logger.info("**********************End evaluation**********************")
    return 0
