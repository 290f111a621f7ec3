"""`memslidar reproduce`: the paper's M1-M4 experiment end to end (pcdet_memslidar.reproduce).

    memslidar reproduce --profile quick [--seeds K] [--out DIR] [--data-root DIR] [--jobs N] [--set KEY VALUE ...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.commands.options import add_profile, add_set, add_workers
from pcdet_memslidar.config import cfg as global_cfg
from pcdet_memslidar.evaluation.report import HEADLINE
from pcdet_memslidar.reproduce import reproduce

BENCHMARK_RESULTS = Path("output/benchmark/model_benchmark.json")  # tools/benchmark_model.py's, relative to the repo


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_profile(parser, default="quick")
    parser.add_argument("--seeds", type=int, default=1, help="training seeds 0..K-1; the report gives mean and std")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/reproduce/<profile>)")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder of the data sources (default: the cfgs' DATA_PATH, data/memslidar)")
    parser.add_argument("--jobs", type=int, default=None,
                        help="models trained at once, each in its own process (default on a CPU: the five models of "
                             "a seed, or one per core if more; 1 on a GPU)")
    add_workers(parser)
    parser.add_argument("--benchmark", type=Path, default=Path(global_cfg.ROOT_DIR) / BENCHMARK_RESULTS,
                        help="tools/benchmark_model.py's results, drawn beside this run's models in the AP-vs-time "
                             "figure when the file exists (default: %(default)s)")
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "reproduce" / args.profile
    data_root = args.data_root.resolve() if args.data_root is not None else None
    command = " ".join(["memslidar reproduce", f"--profile {args.profile}", f"--seeds {args.seeds}",
                        *([f"--out {args.out}"] if args.out else []),
                        *([f"--data-root {args.data_root}"] if args.data_root else []),
                        *([f"--jobs {args.jobs}"] if args.jobs else []),
                        *(["--set", *args.set_cfgs] if args.set_cfgs else [])])
    results = reproduce(args.profile, args.seeds, out.resolve(), data_root, args.workers, command, args.set_cfgs,
                        args.jobs, args.benchmark)
    for model, entry in results["models"].items():
        print(f"{model}: {HEADLINE} {entry['mean'][HEADLINE]}  ms/frame {entry['mean']['ms_per_frame']:.1f}")
    print(f"report: {out / 'report.md'}")
    return 0
