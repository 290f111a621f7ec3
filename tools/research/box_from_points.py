"""What do a person's own points show of its box? The long side of each labelled box against the main axis of the
points inside it (principal component analysis in BEV), per number of points and per spread of the points; how
far the box's centre lies behind the mean of those points, along the sensor's ray; and, where the frames keep
their points' time offsets (training/time_offset, as `memslidar simulate` writes them), the direction in which
those points move during the frame, per range.

    python tools/research/box_from_points.py data/memslidar/industrial [--frames 150] [--min-points 5]
        [--min-height 0.4] [--margin 0.1] [--min-speed 0.5]

A detector can only learn what the points show. If the main axis of a person's own points (the points inside its
labelled box: the segmentation is given) follows the box's long side, the orientation is observable; the error of
this estimate bounds what is lost to the sensor, not to the detector. Errors are angles between long sides, in [0, 90]
deg (evaluation.diagnose.orientation_error_deg); 45 deg is what a guess scores on people facing every way. A LiDAR sees
a person's near side: the median depth of the centre behind the points' mean is what POST_PROCESSING.BOX_FROM_POINTS
.CENTER_DEPTH sets (measure it on training labels, with the step's MARGIN and MIN_HEIGHT). A MEMS scanner takes
a whole frame period (0.4 s for the Cube 1 patterns here) to sweep its field of view, and a person's points are
taken over up to most of it: a walking person's points drift along its path. The velocity fitted to the points'
positions against their times (geometry.box_from_points.drift_velocity) shows that direction: what
POST_PROCESSING.BOX_FROM_POINTS.MIN_DRIFT_SPEED uses.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pcdet_memslidar.evaluation.diagnose import orientation_error_deg
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.evaluation.metrics import DISTANCE_BINS, bin_label
from pcdet_memslidar.geometry.box_from_points import MIN_RANGE, drift_velocity, main_axis, point_windows
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.io.kitti import CLASS_NAME, read_point_times, read_points
from pcdet_memslidar.io.layout import KittiLayout

POINT_BINS = ((5, 20), (20, 50), (50, 100), (100, None))  # points per person, lower bound included
SPREAD_BINS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 1.0))  # smaller / larger BEV variance, upper bound included


def long_side_error(direction: float, box: np.ndarray) -> float:
    """Angle [deg] in [0, 90] between a direction [rad] and the long side of a (7,) box."""
    return float(orientation_error_deg(np.array([[*box[:3], 1.0, 0.5, box[5], direction]]), box[None])[0])


def person_measurements(root: Path, frames: int | None, min_points: int, min_height: float = 0.0,
                        margin: float = 0.0) -> dict[str, np.ndarray]:
    """Every labelled person with at least min_points points in its window (its box grown by `margin` [m] in x and y,
    from `min_height` [m] above its bottom) in the first `frames` frames of the KITTI folder `root`, as (P,) arrays:
    'error' [deg] of the points' main axis against the long side (NaN: no main axis), 'count' of points, 'spread'
    (the smaller over the larger variance in BEV, 1 for points as wide every way) and 'depth' [m] of the labelled
    centre behind the points' mean along the ray from the sensor (negative: in front of it; NaN on the sensor's
    axis, where there is no ray), 'range' [m] of the labelled centre in BEV, and from the frame's time offsets (NaN
    without them, or where the points were taken at one time) 'speed' [m/s] of drift_velocity and 'drift_error'
    [deg] of its direction against the long side."""
    layout = KittiLayout(root)
    labels = read_label_folder(layout.training / "label_2", with_score=False)
    found = {"error": [], "count": [], "spread": [], "depth": [], "range": [], "speed": [], "drift_error": []}
    for frame_id in sorted(labels)[:frames]:
        boxes = labels[frame_id]["boxes_lidar"][labels[frame_id]["name"] == CLASS_NAME]
        if not len(boxes):
            continue
        points = read_points(layout.training / "velodyne" / f"{frame_id}.bin")
        time_file = layout.time_offset(frame_id)
        times = read_point_times(time_file, len(points)).astype(np.float64) if time_file.is_file() else None
        inside = points_in_boxes_mask(points[:, :3], point_windows(boxes, margin, min_height))
        for index, box in enumerate(boxes):
            own = points[inside[:, index], :2].astype(np.float64)
            if len(own) < min_points:
                continue
            axis = main_axis(own)
            found["error"].append(long_side_error(axis, box) if axis is not None else np.nan)
            found["count"].append(len(own))
            variances = np.linalg.eigvalsh(np.cov(own.T))
            found["spread"].append(variances[0] / variances[1])
            mean = own.mean(axis=0)
            reach = float(np.hypot(*mean))
            found["depth"].append(float(np.dot(box[:2] - mean, mean / reach)) if reach >= MIN_RANGE else np.nan)
            found["range"].append(float(np.hypot(*box[:2])))
            velocity = None if times is None else drift_velocity(own, times[inside[:, index]])
            if velocity is None:
                found["speed"].append(np.nan)
                found["drift_error"].append(np.nan)
            else:
                found["speed"].append(float(np.hypot(*velocity)))
                found["drift_error"].append(long_side_error(float(np.arctan2(velocity[1], velocity[0])), box))
    return {key: np.asarray(values, dtype=np.float64) for key, values in found.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="a KITTI domain folder (training/velodyne, training/label_2)")
    parser.add_argument("--frames", type=int, default=None, help="the first N frames (default: all)")
    parser.add_argument("--min-points", type=int, default=5)
    parser.add_argument("--min-height", type=float, default=0.0,
                        help="only points this high above the box's bottom [m] (BOX_FROM_POINTS.MIN_HEIGHT)")
    parser.add_argument("--margin", type=float, default=0.0,
                        help="the box grown by this much on every side in x and y [m] (BOX_FROM_POINTS.MARGIN)")
    parser.add_argument("--min-speed", type=float, default=0.5,
                        help="people whose points drift at least this fast [m/s] count as moving")
    args = parser.parse_args(argv)
    people = person_measurements(args.root, args.frames, args.min_points, args.min_height, args.margin)
    has_axis = ~np.isnan(people["error"])
    errors, counts, spreads = people["error"][has_axis], people["count"][has_axis], people["spread"][has_axis]
    print(f"{args.root}: {len(people['count'])} people with >= {args.min_points} points >= {args.min_height} m above "
          f"the bottom, margin {args.margin} m; {len(errors)} with a main axis\n")
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
    depth = people["depth"][~np.isnan(people["depth"])]
    if len(depth):
        quartiles = np.percentile(depth, [25, 50, 75])
        print(f"\nCentre behind the points' mean along the ray (CENTER_DEPTH): median {quartiles[1]:.3f} m, quartiles "
              f"{quartiles[0]:.3f} .. {quartiles[2]:.3f} m, {len(depth)} people")
    if np.isnan(people["speed"]).all():
        print("\nNo time offsets (training/time_offset): the drift of the points is not measured")
        return 0
    moving = people["speed"] >= args.min_speed  # NaN compares False
    print(f"\nMedian error (deg) of the main axis and of the drift of the points (moving: they drift >= "
          f"{args.min_speed} m/s)\n")
    print("| range | people | main axis | moving | their main axis | their drift | standing | their main axis |\n"
          "|---|---|---|---|---|---|---|---|")
    def median(values: np.ndarray, chosen: np.ndarray) -> str:
        return f"{np.nanmedian(values[chosen]):.1f}" if chosen.any() else "-"

    for low, high in DISTANCE_BINS:
        near = has_axis & (people["range"] >= low) & (people["range"] < high)
        walking, standing = near & moving, near & ~moving
        print(f"| {bin_label(low, high)} | {near.sum()} | {median(people['error'], near)} | {walking.sum()} | "
              f"{median(people['error'], walking)} | {median(people['drift_error'], walking)} | {standing.sum()} | "
              f"{median(people['error'], standing)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
