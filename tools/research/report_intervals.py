"""Bootstrap intervals for a finished reproduction: read its results.json, add the intervals of every AP and of the
differences between models (experiments.results.add_intervals) and write results.json and report.md to --out.

    python tools/research/report_intervals.py output/reproduce/quick --out /tmp/quick_intervals [--gt DIR]
        [--resamples N]

The ground truth defaults to the label_2 folder of the results' test domain. The intervals figure (ap_intervals.png)
is drawn into --out; the other figures stay beside the original report (report.md in --out links them by name).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pcdet_memslidar.evaluation.bootstrap import LEVEL, RESAMPLES, SEED
from pcdet_memslidar.experiments.report import write_report
from pcdet_memslidar.experiments.results import add_intervals
from pcdet_memslidar.io.layout import KittiLayout


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report_dir", type=Path, help="folder of the finished reproduction (results.json)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the new results.json and report.md")
    parser.add_argument("--gt", type=Path, help="ground-truth label folder (default: the test domain's label_2)")
    parser.add_argument("--resamples", type=int, default=RESAMPLES, help="bootstrap resamples of the test frames")
    parser.add_argument("--level", type=float, default=LEVEL, help="confidence level in (0, 1)")
    parser.add_argument("--seed", type=int, default=SEED, help="seed of the resampling")
    args = parser.parse_args(argv)
    results = json.loads((args.report_dir / "results.json").read_text())
    gt_dir = args.gt or KittiLayout(results["data"][results["test_domain"]]["path"]).training / "label_2"
    args.out.mkdir(parents=True, exist_ok=True)
    add_intervals(results, gt_dir, args.report_dir, args.resamples, args.level, args.seed, figure_dir=args.out)
    report_path, json_path = write_report(results, args.out)
    print(f"bootstrap: {results['intervals']['seconds']:.1f} s; report: {report_path}; results: {json_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
