"""Is a person's orientation in the points at all? The long side of each labelled box against the main axis of the
points inside it (principal component analysis in BEV), per number of points and per spread of the points.

    python tools/orientation_from_points.py data/memslidar/industrial [--frames 150] [--min-points 5] [--min-height 0.4]

A detector can only learn what the points show. If the main axis of a person's own points (the points inside its
labelled box: the segmentation is given) follows the box's long side, the orientation is observable; the error of
this estimate bounds what is lost to the sensor, not to the detector. Errors are angles between long sides, in [0, 90]
deg (evaluation.diagnose.orientation_error_deg); 45 deg is what a guess scores on people facing every way.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pcdet_memslidar.evaluation.diagnose import orientation_error_deg
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.geometry.heading import main_axis, raise_bottoms
from pcdet_memslidar.io.kitti import CLASS_NAME, read_points
from pcdet_memslidar.io.layout import KittiLayout

POINT_BINS = ((5, 20), (20, 50), (50, 100), (100, None))  # points per person, lower bound included
SPREAD_BINS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 1.0))  # smaller / larger BEV variance, upper bound included


def orientation_errors(root: Path, frames: int | None, min_points: int,
                       min_height: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(errors [deg] (P,), points per person (P,), spread (P,): the smaller over the larger variance of the points in
    BEV, 1 for points as wide every way) of every labelled person with at least min_points points at least
    `min_height` [m] above its box's bottom in the first `frames` frames of the KITTI folder `root`."""
    layout = KittiLayout(root)
    labels = read_label_folder(layout.training / "label_2", with_score=False)
    errors, counts, spreads = [], [], []
    for frame_id in sorted(labels)[:frames]:
        boxes = labels[frame_id]["boxes_lidar"][labels[frame_id]["name"] == CLASS_NAME]
        if not len(boxes):
            continue
        points = read_points(layout.training / "velodyne" / f"{frame_id}.bin")
        inside = points_in_boxes_mask(points[:, :3], raise_bottoms(boxes, min_height))
        for index, box in enumerate(boxes):
            own = points[inside[:, index], :2]
            axis = main_axis(own) if len(own) >= min_points else None
            if axis is None:
                continue
            estimate = np.array([[*box[:3], 1.0, 0.5, box[5], axis]])  # its long side along the axis
            errors.append(orientation_error_deg(estimate, box[None])[0])
            counts.append(len(own))
            variances = np.linalg.eigvalsh(np.cov(own.T))
            spreads.append(variances[0] / variances[1])
    return np.asarray(errors), np.asarray(counts), np.asarray(spreads)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="a KITTI domain folder (training/velodyne, training/label_2)")
    parser.add_argument("--frames", type=int, default=None, help="the first N frames (default: all)")
    parser.add_argument("--min-points", type=int, default=5)
    parser.add_argument("--min-height", type=float, default=0.0,
                        help="only points this high above the box's bottom [m] (HEADING_FROM_POINTS.MIN_HEIGHT)")
    args = parser.parse_args(argv)
    errors, counts, spreads = orientation_errors(args.root, args.frames, args.min_points, args.min_height)
    print(f"{args.root}: {len(errors)} people with >= {args.min_points} points >= {args.min_height} m above the "
          f"bottom\n")
    print("| points per person | people | median error (deg) | within 15 deg |\n|---|---|---|---|")
    for low, high in ((args.min_points, None), *POINT_BINS):
        chosen = (counts >= low) & (counts < (high or np.inf))
        if chosen.any():
            label = f"{low}+" if high is None else f"{low}-{high - 1}"
            print(f"| {label}{' (all)' if low == args.min_points and high is None else ''} | {int(chosen.sum())} | "
                  f"{np.median(errors[chosen]):.1f} | {np.mean(errors[chosen] <= 15):.0%} |")
    print("\n| spread (smaller / larger variance) | people | median error (deg) | within 15 deg |\n|---|---|---|---|")
    for low, high in SPREAD_BINS:
        chosen = (spreads > low) & (spreads <= high) if low else spreads <= high
        if chosen.any():
            print(f"| {low:.1f}-{high:.1f} | {int(chosen.sum())} | {np.median(errors[chosen]):.1f} | "
                  f"{np.mean(errors[chosen] <= 15):.0%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
