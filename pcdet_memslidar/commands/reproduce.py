"""`memslidar reproduce`: the paper's M1-M4 experiment end to end (pcdet_memslidar.experiments.reproduce).

    memslidar reproduce --profile quick [--models M ...] [--heads anchor center] [--seeds K (default 3)] [--out DIR]
                        [--data-root DIR] [--jobs N] [--set KEY VALUE ...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.commands.options import add_experiment_arguments, add_profile, add_set, experiment_command
from pcdet_memslidar.config import cfg as global_cfg
from pcdet_memslidar.experiments.reproduce import KNOWN_RUNS, PAPER_HEAD, RUNS, head_configs, reproduce
from pcdet_memslidar.experiments.results import HEADLINE

BENCHMARK_RESULTS = Path("output/benchmark/model_benchmark.json")  # tools/benchmark_model.py's, relative to the repo


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_profile(parser, default="quick")
    parser.add_argument("--models", nargs="+", default=list(RUNS), choices=list(KNOWN_RUNS),
                        help="the models to train and test (default: %(default)s; M5: pre-trained on sim, "
                             "fine-tuned on real, cfgs/m5.yaml)")
    configs = ", ".join(f"{head}: {path.name}" for head, path in head_configs().items())
    parser.add_argument("--heads", nargs="+", default=[PAPER_HEAD], choices=list(head_configs()),
                        help=f"the dense heads to train each model with, each with the MODEL of its model config "
                             f"({configs}; default: %(default)s, SECOND's, the paper's)")
    # Three seeds: one training's AP moves with its seed and with the CPU's float rounding by more than the
    # differences Table 3 is about (docs/experiments.md#float-rounding-and-the-outcome-of-a-training); --seeds 1: a
    # quick look.
    add_experiment_arguments(parser, "models", seeds=3)
    parser.add_argument("--benchmark", type=Path, default=Path(global_cfg.ROOT_DIR) / BENCHMARK_RESULTS,
                        help="tools/benchmark_model.py's results, drawn beside this run's models in the AP-vs-time "
                             "figure when the file exists (default: %(default)s)")
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "reproduce" / args.profile
    data_root = args.data_root.resolve() if args.data_root is not None else None
    models = [] if args.models == list(RUNS) else ["--models", *args.models]
    head_args = [] if args.heads == [PAPER_HEAD] else ["--heads", *args.heads]
    command = experiment_command(["memslidar reproduce", *models, *head_args], args)
    results = reproduce(args.profile, args.seeds, out.resolve(), data_root, args.workers, command, args.set_cfgs,
                        args.jobs, args.benchmark, tuple(args.models), tuple(args.heads))
    for model, entry in results["models"].items():
        print(f"{model}: {HEADLINE} {entry['mean'][HEADLINE]}  ms/frame {entry['mean']['ms_per_frame']:.1f}")
    print(f"report: {out / 'report.md'}")
    return 0
