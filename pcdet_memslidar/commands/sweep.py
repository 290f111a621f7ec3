"""`memslidar sweep`: the paper's open questions as sweeps over the training set (pcdet_memslidar.experiments.sweeps).

    memslidar sweep ratio|real-budget [--grid P ...] --profile quick [--seeds K] [--out DIR] [--data-root DIR]
                    [--jobs N] [--set KEY VALUE ...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.commands.options import add_experiment_arguments, add_profile, add_set, experiment_command
from pcdet_memslidar.config import cfg as global_cfg
from pcdet_memslidar.experiments.sweeps import SWEEPS, sweep


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("kind", choices=list(SWEEPS),
                        help="ratio: 0-100 %% synthetic frames at a fixed total; real-budget: 10-100 %% of the real "
                             "pool, alone and with a fixed pool of synthetic frames")
    parser.add_argument("--grid", type=int, nargs="+", default=None,
                        help="percentages: of synthetic frames (ratio; default 0 10 ... 100) or of the real pool "
                             "(real-budget; default 10 25 50 100)")
    add_profile(parser, default="quick")
    add_experiment_arguments(parser, "points")
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "sweep" / args.kind / args.profile
    data_root = args.data_root.resolve() if args.data_root is not None else None
    grid = ["--grid", *map(str, args.grid)] if args.grid else []
    command = experiment_command(["memslidar sweep", args.kind, *grid], args)
    results = sweep(args.kind, args.profile, args.seeds, out.resolve(), data_root, args.workers, command,
                    args.set_cfgs, args.jobs, args.grid)
    for row in results["rows"]:
        print(f"{row['point']}: AP3D_R40 {row['mean']:.4f}")
    print(f"report: {out / 'report.md'}")
    return 0
