"""`memslidar eval --gt DIR --pred DIR [--json]`: AP of KITTI-format prediction labels against ground truth
(evaluation.folders: frames matched by file name, Pedestrian only, a 16th score column in predictions)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pcdet_memslidar.evaluation.folders import evaluate_folders
from pcdet_memslidar.evaluation.metrics import ap_summary, format_results


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gt", type=Path, required=True, help="ground-truth KITTI label_2 folder (*.txt)")
    parser.add_argument("--pred", type=Path, required=True, help="prediction label folder (*.txt with a score column)")
    parser.add_argument("--json", action="store_true", help="print one JSON object of AP values instead of the table")


def run(args: argparse.Namespace) -> int:
    result, counts = evaluate_folders(args.gt, args.pred)
    print(f"{counts['frames']} ground-truth frames; {counts['missing_predictions']} without a prediction file "
          f"(scored as no detections); {counts['predictions_without_gt']} prediction files without ground truth "
          f"(skipped)", file=sys.stderr)
    if args.json:
        print(json.dumps(ap_summary(result) | {"num_gt": result["num_gt"], "num_dt": result["num_dt"]} | counts))
    else:
        print(format_results(result))
    return 0
