"""`memslidar eval --gt DIR --pred DIR [--json]`: AP of KITTI-format prediction labels against ground truth.

Frames are matched by file name (000123.txt). A ground-truth frame without a prediction file counts as a frame with
no detections; a prediction file without ground truth cannot be scored and is skipped. Both are counted and
reported on stderr. Prediction files carry a 16th score column (an empty file means no detections).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io.kitti import boxes_from_label, read_label

from .metrics import ap_summary, evaluate, format_results


def read_label_folder(folder: Path, with_score: bool) -> dict[str, dict]:
    """{frame id: anno dict (name, boxes_lidar, score if with_score)} of every *.txt label file in `folder`."""
    if not folder.is_dir():
        raise DataFormatError(folder, "label folder not found; pass a KITTI label_2 folder of *.txt files")
    calib = Calibration.virtual()
    annos = {}
    for path in sorted(folder.glob("*.txt")):
        label = read_label(path)
        anno = {"name": label.name, "boxes_lidar": boxes_from_label(label, calib)}
        if with_score:
            if label.score is None and len(label):
                raise DataFormatError(path, "prediction labels need a 16th column with the detection score")
            anno["score"] = label.score if label.score is not None else np.zeros(0)
        annos[path.stem] = anno
    return annos


def evaluate_folders(gt_dir: Path, pred_dir: Path) -> tuple[dict, dict[str, int]]:
    """evaluate() of two label folders -> (result, frame counts {'frames', 'missing_predictions',
    'predictions_without_gt'})."""
    gt, pred = read_label_folder(gt_dir, with_score=False), read_label_folder(pred_dir, with_score=True)
    if not gt:
        raise DataFormatError(gt_dir, "no *.txt ground-truth label files")
    no_detections = {"name": np.zeros(0, dtype=str), "boxes_lidar": np.zeros((0, 7)), "score": np.zeros(0)}
    frame_ids = sorted(gt)
    result = evaluate([gt[i] for i in frame_ids], [pred.get(i, no_detections) for i in frame_ids])
    counts = {"frames": len(frame_ids), "missing_predictions": len(set(gt) - set(pred)),
              "predictions_without_gt": len(set(pred) - set(gt))}
    return result, counts


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
