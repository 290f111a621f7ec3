"""`memslidar test` / tools/test.py: evaluate one checkpoint (--ckpt) or all of a run (--eval_all) on the test
split and print AP 3D / BEV at IoU 0.5. Output: <run>/eval/epoch_N/<split>/[<eval_tag>/]{result.pkl, log}."""
from __future__ import annotations

import argparse
import datetime
import time

from tensorboardX import SummaryWriter

from pcdet_memslidar.config import log_config_to_file
from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import checkpoint_epoch, list_checkpoints, load_params_from_file
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch
from pcdet_memslidar.runtime.experiment import add_common_arguments, ap_line, scalars, setup_experiment, test_split

POLL_SECONDS = 30


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common_arguments(parser)
    parser.add_argument("--eval_tag", default="default", help="sub-folder of this evaluation's results")
    parser.add_argument("--eval_all", action="store_true", default=False,
                        help="evaluate every checkpoint_epoch_N.pth of --ckpt_dir from --start_epoch on")
    parser.add_argument("--ckpt_dir", default=None, help="default <run>/ckpt")
    parser.add_argument("--infer_time", action="store_true", default=False, help="accepted; ms/frame is always "
                                                                                 "logged")


def _wait_for_checkpoints(ckpt_dir, start_epoch: int, max_waiting_mins: int, logger) -> list:
    """Checkpoints of epoch >= start_epoch; polls up to max_waiting_mins while there are none yet."""
    deadline = time.time() + 60 * max_waiting_mins
    while True:
        found = [c for c in list_checkpoints(ckpt_dir) if checkpoint_epoch(c) >= start_epoch]
        if found or time.time() >= deadline:
            return found
        logger.info(f"waiting for checkpoints in {ckpt_dir} ...")
        time.sleep(POLL_SECONDS)


def run(args: argparse.Namespace) -> int:
    exp = setup_experiment(args)
    cfg = exp.cfg
    if not args.eval_all and not args.ckpt:
        raise SystemExit("pass --ckpt <checkpoint.pth> or --eval_all")
    split = test_split(cfg)
    eval_dir = exp.output_dir / "eval"
    if not args.eval_all:
        epoch_id = checkpoint_epoch(args.ckpt)
        eval_dir = eval_dir / f"epoch_{epoch_id if epoch_id is not None else 'no_number'}" / split
    else:
        eval_dir = eval_dir / "eval_all_default"
    eval_dir = eval_dir / args.eval_tag if args.eval_tag != "default" else eval_dir
    logger = create_logger(eval_dir / f"log_eval_{datetime.datetime.now():%Y%m%d-%H%M%S}.txt", rank=exp.rank)
    logger.info(f"device {exp.device}, {exp.world_size} process(es), {exp.threads} torch threads each")
    log_config_to_file(cfg, logger=logger)

    test_set, test_loader, _ = build_dataloader(
        dataset_cfg=cfg.DATA_CONFIG, class_names=cfg.CLASS_NAMES, batch_size=exp.batch_size, dist=exp.dist,
        workers=args.workers, logger=logger, training=False)
    model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=test_set).to(exp.device)
    model.profile = cfg.get("PROFILE")  # named when a checkpoint of another grid is refused

    if not args.eval_all:
        checkpoint = load_params_from_file(model, args.ckpt, logger, strict=True)
        result = eval_one_epoch(cfg, model, test_loader, checkpoint.get("epoch"), logger, exp.device,
                                dist_test=exp.dist, result_dir=eval_dir, save_to_file=args.save_to_file)
        if exp.rank == 0:
            print(ap_line(result), flush=True)
        return 0

    ckpt_dir = args.ckpt_dir or exp.output_dir / "ckpt"
    checkpoints = _wait_for_checkpoints(ckpt_dir, args.start_epoch, args.max_waiting_mins, logger)
    if not checkpoints:
        raise SystemExit(f"no checkpoint_epoch_N.pth with N >= {args.start_epoch} in {ckpt_dir}")
    tb_log = SummaryWriter(str(eval_dir / f"tensorboard_{split}")) if exp.rank == 0 else None
    for ckpt in checkpoints:
        epoch = checkpoint_epoch(ckpt)
        load_params_from_file(model, ckpt, logger, strict=True)
        result = eval_one_epoch(cfg, model, test_loader, epoch, logger, exp.device, dist_test=exp.dist,
                                result_dir=eval_dir / f"epoch_{epoch}" / split, save_to_file=args.save_to_file)
        if exp.rank == 0:
            print(f"epoch {epoch}: {ap_line(result)}", flush=True)
            for key, value in scalars(result).items():
                tb_log.add_scalar(key, value, epoch)
    if tb_log is not None:
        tb_log.close()
    return 0
