"""`memslidar docs [--add RUN_FOLDER ...]`: store finished runs' results and render the generated tables of README.md
and docs/results.md from every stored run (experiments.publish)."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.experiments.publish import STORE, publish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--add", type=Path, nargs="*", default=[],
                        help=f"output folders of `memslidar reproduce` or `memslidar site train` to store under "
                             f"{STORE} first (replacing a stored run of the same profile or site)")
    parser.add_argument("--root", type=Path, default=Path("."), help="the repository root (default: here)")


def run(args: argparse.Namespace) -> int:
    written = publish(args.root, args.add)
    print(f"rendered {', '.join(map(str, written)) or 'nothing new'} from {args.root / STORE}")
    return 0
