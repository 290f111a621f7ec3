"""AP of KITTI-format label folders: prediction labels (with scores) against ground truth, frame by file name.

Frames are matched by file name (000123.txt). A ground-truth frame without a prediction file counts as a frame with
no detections; a prediction file without ground truth cannot be scored and is skipped; evaluate_folders counts both.
Prediction files carry a 16th score column (an empty file means no detections).
Only Pedestrian objects count. KITTI's other classes (Car, Cyclist, DontCare, ...) are left out as KITTI's evaluation
does; a class that is Pedestrian in another case ('pedestrian') is an error, any other name a warning on stderr.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.evaluation.metrics import evaluate
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io.kitti import (
    CLASS_NAME,
    KITTI_CLASSES,
    boxes_from_label,
    check_class_case,
    object_line,
    read_label,
)


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


def unevaluated_classes(folder: Path, annos: dict[str, dict], class_name: str = CLASS_NAME) -> list[str]:
    """Warnings (one per class name, naming its first file:line) for objects that do not count for `class_name` and are
    no KITTI class; DataFormatError (file:line) for a name that is `class_name` in another case."""
    ignored = {}  # name -> [objects, files, first file]
    for frame_id, anno in annos.items():
        path = folder / f"{frame_id}.txt"
        check_class_case(path, anno["name"], [class_name])
        names, counts = np.unique(anno["name"], return_counts=True)
        for name, count in zip(names.tolist(), counts.tolist()):
            if name != class_name and name not in KITTI_CLASSES:
                entry = ignored.setdefault(name, [0, 0, path])
                entry[0] += count
                entry[1] += 1
    return [f"{path}:{object_line(path, name)}: class {name!r} is not evaluated (only {class_name} is): {objects} "
            f"object(s) in {files} file(s) of {folder} left out; rename them to {class_name} if they are people"
            for name, (objects, files, path) in sorted(ignored.items())]


def aligned_folders(gt_dir: Path, pred_dir: Path) -> tuple[list[dict], list[dict], dict[str, int]]:
    """The annos of two label folders, frame by frame in the ground truth's sorted order (no detections where a
    prediction file is missing), and frame counts {'frames', 'missing_predictions', 'predictions_without_gt'};
    objects of classes that are not evaluated are reported on stderr (unevaluated_classes)."""
    gt, pred = read_label_folder(gt_dir, with_score=False), read_label_folder(pred_dir, with_score=True)
    if not gt:
        raise DataFormatError(gt_dir, "no *.txt ground-truth label files")
    for warning in unevaluated_classes(gt_dir, gt) + unevaluated_classes(pred_dir, pred):
        print(f"warning: {warning}", file=sys.stderr)
    no_detections = {"name": np.zeros(0, dtype=str), "boxes_lidar": np.zeros((0, 7)), "score": np.zeros(0)}
    frame_ids = sorted(gt)
    counts = {"frames": len(frame_ids), "missing_predictions": len(set(gt) - set(pred)),
              "predictions_without_gt": len(set(pred) - set(gt))}
    return [gt[i] for i in frame_ids], [pred.get(i, no_detections) for i in frame_ids], counts


def evaluate_folders(gt_dir: Path, pred_dir: Path) -> tuple[dict, dict[str, int]]:
    """evaluate() of two label folders (aligned_folders) -> (result, frame counts)."""
    gt_annos, dt_annos, counts = aligned_folders(gt_dir, pred_dir)
    return evaluate(gt_annos, dt_annos, class_name=CLASS_NAME), counts
