"""Benchmark the evaluator: 1,000 frames x 10 ground-truth people x 50 scored detections (issue 2, target < 2 s).

    python tools/benchmark_eval.py [--frames 1000] [--gt 10] [--dt 50] [--threads N]

Per frame: 10 people at 2-40 m; 20 detections near them (jittered hits and duplicates, so IoUs spread around the
0.5 threshold) and 30 clutter boxes anywhere in the field of view. Prints the wall time of evaluate() (scene
generation excluded), the same-frame (detection, ground truth) pairs it considered per second, and how many of
them got an exact rotated IoU after the circumscribed-circle prefilter.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from pcdet_memslidar.evaluation import evaluate, format_results
from pcdet_memslidar.evaluation.matching import same_frame_pairs
from pcdet_memslidar.geometry.iou import circles_overlap
from pcdet_memslidar.io.kitti import CLASS_NAME


def people(rng: np.random.Generator, centres: np.ndarray) -> np.ndarray:
    """(K, 7) person-sized boxes standing on the ground at (K, 2) centres."""
    count = len(centres)
    return np.column_stack([centres, rng.uniform(0.85, 0.95, count), rng.uniform(0.4, 0.8, (count, 2)),
                            rng.uniform(1.5, 1.9, count), rng.uniform(-np.pi, np.pi, count)])


def random_frames(frames: int, num_gt: int, num_dt: int, seed: int = 0) -> tuple[list[dict], list[dict]]:
    """Ground-truth and detection annos of `frames` synthetic frames."""
    rng = np.random.default_rng(seed)
    gt_annos, dt_annos = [], []
    for _ in range(frames):
        distance, azimuth = rng.uniform(2, 40, num_gt), rng.uniform(-0.6, 0.6, num_gt)
        gt = people(rng, np.column_stack([distance * np.cos(azimuth), distance * np.sin(azimuth)]))
        near = gt[rng.integers(0, num_gt, 2 * num_gt)] + rng.normal(0, 1, (2 * num_gt, 7)) * [0.15, 0.15, 0.05,
                                                                                               0.05, 0.05, 0.05, 0.3]
        clutter = people(rng, np.column_stack([rng.uniform(2, 40, num_dt - len(near)),
                                               rng.uniform(-20, 20, num_dt - len(near))]))
        dt = np.concatenate([near, clutter])
        gt_annos.append({"name": np.full(num_gt, CLASS_NAME), "boxes_lidar": gt})
        dt_annos.append({"name": np.full(num_dt, CLASS_NAME), "boxes_lidar": dt, "score": rng.uniform(size=num_dt)})
    return gt_annos, dt_annos


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--gt", type=int, default=10, help="ground-truth boxes per frame")
    parser.add_argument("--dt", type=int, default=50, help="detections per frame (at least 2x --gt)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    gt_annos, dt_annos = random_frames(args.frames, args.gt, args.dt)
    evaluate(gt_annos[:2], dt_annos[:2])  # warm-up: imports and first-call overheads are not what we measure

    start = time.perf_counter()
    result = evaluate(gt_annos, dt_annos)
    wall = time.perf_counter() - start

    counts = np.full(args.frames, args.dt), np.full(args.frames, args.gt)
    dt_index, gt_index = same_frame_pairs(*counts)
    dt_boxes = np.concatenate([anno["boxes_lidar"] for anno in dt_annos])
    gt_boxes = np.concatenate([anno["boxes_lidar"] for anno in gt_annos])
    exact = int(circles_overlap(dt_boxes[dt_index], gt_boxes[gt_index]).sum())
    print(format_results(result))
    print(f"{args.frames} frames x {args.gt} gt x {args.dt} detections on {torch.get_num_threads()} torch threads: "
          f"{wall:.3f} s wall, {len(dt_index) / wall:,.0f} pairs/s ({len(dt_index):,} same-frame pairs, "
          f"{exact:,} with an exact rotated IoU after the prefilter)")


if __name__ == "__main__":
    main()
