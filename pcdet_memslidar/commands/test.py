"""`memslidar test` / tools/test.py: evaluate one checkpoint (--ckpt) or all of a run (--eval-all) on the test
split with OpenPCDet's flags (runtime.predict) and print AP 3D / BEV at IoU 0.5; with --diagnose also which part
of a box costs the AP (evaluation.diagnose). Another split: --set DATA_CONFIG.DATA_SPLIT.test val.
Output: <run>/eval/epoch_N/<split>/[<eval_tag>/]{result.pkl, log[, diagnosis.json]}."""
from __future__ import annotations

import argparse
import datetime
import json
import pickle
import time
from pathlib import Path

from tensorboardX import SummaryWriter

from pcdet_memslidar.commands.options import add_openpcdet_arguments, add_precision, setup_experiment
from pcdet_memslidar.config import log_config_to_file
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.diagnose import extent_agreement, format_diagnosis, part_ablation
from pcdet_memslidar.experiments.results import json_safe
from pcdet_memslidar.models import is_learned
from pcdet_memslidar.runtime.checkpoint import checkpoint_epoch, list_checkpoints
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.experiment import ap_line, scalars, test_split
from pcdet_memslidar.runtime.predict import predict, test_loader
from pcdet_memslidar.utils.atomic import write_text

POLL_SECONDS = 30


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_openpcdet_arguments(parser)
    parser.add_argument("--eval-tag", "--eval_tag", default="default", help="sub-folder of this evaluation's results")
    parser.add_argument("--eval-all", "--eval_all", action="store_true", default=False,
                        help="evaluate every checkpoint_epoch_N.pth of --ckpt-dir from --start-epoch on")
    parser.add_argument("--ckpt-dir", "--ckpt_dir", default=None, help="default <run>/ckpt")
    parser.add_argument("--diagnose", action="store_true", default=False,
                        help="also print the AP with each part of the boxes replaced by the ground truth's and how "
                             "predicted extents follow the labels (diagnosis.json beside result.pkl)")
    parser.add_argument("--infer-time", "--infer_time", action="store_true", default=False,
                        help=argparse.SUPPRESS)  # OpenPCDet's; ms/frame is always logged
    add_precision(parser)


def _wait_for_checkpoints(ckpt_dir, start_epoch: int, max_waiting_mins: int, logger) -> list:
    """Checkpoints of epoch >= start_epoch; polls up to max_waiting_mins while there are none yet."""
    deadline = time.time() + 60 * max_waiting_mins
    while True:
        found = [c for c in list_checkpoints(ckpt_dir) if checkpoint_epoch(c) >= start_epoch]
        if found or time.time() >= deadline:
            return found
        logger.info(f"waiting for checkpoints in {ckpt_dir} ...")
        time.sleep(POLL_SECONDS)


def diagnose(dataset, result_dir: Path) -> str:
    """Diagnosis of the predictions in result_dir/result.pkl (evaluation.diagnose): written to
    result_dir/diagnosis.json, returned as text."""
    gt_annos, dt_annos = dataset.aligned_annos(pickle.loads((result_dir / "result.pkl").read_bytes()))
    ablation, agreement = part_ablation(gt_annos, dt_annos), extent_agreement(gt_annos, dt_annos)
    diagnosis = json_safe({"part_ablation": ablation, "extent_agreement": agreement})  # NaN (no labels): null
    write_text(result_dir / "diagnosis.json", json.dumps(diagnosis, indent=1, allow_nan=False))
    return format_diagnosis(ablation, agreement)


def run(args: argparse.Namespace) -> int:
    cfg, process, output_dir = setup_experiment(args)
    if not args.eval_all and not args.ckpt and is_learned(cfg.MODEL):
        raise ConfigError("pass --ckpt <checkpoint.pth> or --eval-all")
    split = test_split(cfg)
    eval_dir = output_dir / "eval"
    if not args.eval_all:
        epoch_id = checkpoint_epoch(args.ckpt) if args.ckpt else None
        eval_dir = eval_dir / f"epoch_{epoch_id if epoch_id is not None else 'no_number'}" / split
    else:
        eval_dir = eval_dir / "eval_all_default"
    eval_dir = eval_dir / args.eval_tag if args.eval_tag != "default" else eval_dir
    logger = create_logger(eval_dir / f"log_eval_{datetime.datetime.now():%Y%m%d-%H%M%S}.txt", rank=process.rank)
    logger.info(f"device {process.device}, {process.world_size} process(es), {process.threads} torch threads each")
    log_config_to_file(cfg, logger=logger)
    test_data = test_loader(cfg, logger, process, args.workers)

    if not args.eval_all:
        result = predict(cfg, args.ckpt, eval_dir, logger, process, loader=test_data, save_to_file=args.save_to_file,
                         precision=args.precision)
        if process.rank == 0:
            print(ap_line(result), flush=True)
            if args.diagnose:
                print(diagnose(test_data[0], eval_dir), flush=True)
        return 0

    ckpt_dir = args.ckpt_dir or output_dir / "ckpt"
    checkpoints = _wait_for_checkpoints(ckpt_dir, args.start_epoch, args.max_waiting_mins, logger)
    if not checkpoints:
        raise ConfigError(f"no checkpoint_epoch_N.pth with N >= {args.start_epoch} in {ckpt_dir}: train first, or "
                          f"pass --ckpt-dir, --start-epoch or --max-waiting-mins")
    tb_log = SummaryWriter(str(eval_dir / f"tensorboard_{split}")) if process.rank == 0 else None
    for ckpt in checkpoints:
        epoch = checkpoint_epoch(ckpt)
        result_dir = eval_dir / f"epoch_{epoch}" / split
        result = predict(cfg, ckpt, result_dir, logger, process, loader=test_data, save_to_file=args.save_to_file,
                         precision=args.precision)
        if process.rank == 0:
            print(f"epoch {epoch}: {ap_line(result)}", flush=True)
            if args.diagnose:
                print(diagnose(test_data[0], result_dir), flush=True)
            for key, value in scalars(result).items():
                tb_log.add_scalar(key, value, epoch)
    if tb_log is not None:
        tb_log.close()
    return 0
