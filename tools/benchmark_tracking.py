"""Benchmark `memslidar detect` on simulated industrial sequences: tracking (MOTA, IDF1), AP with and without
tracking, and frames/s end to end (read, normalise, voxelise, infer, track, write) on this machine's threads.

    pip install -e ".[bench]"
    python tools/benchmark_tracking.py --cfg cfgs/m3.yaml --profile quick \
        --ckpt output/reproduce/quick/models/oracle/seed_0/ckpt/checkpoint_epoch_2.pth

Sequences: `memslidar simulate --domain industrial --sequence LENGTH --seed S`, S = SEED_BASE, SEED_BASE + 1, ...
(kept in --out/sequences). Tracking: tracking_metrics.py beside this script (motmetrics; a box within 0.5 m of a
person's BEV centre).
AP 3D R40 at IoU 0.5 of the detections detect keeps (score >= TRACKER.MIN_SCORE), all of them and those of confirmed
tracks only, at each --precisions entry (the inference precision of the BEV backbone and head: what bf16 costs in
AP and tracking). Speed: the checkpoint, then an untrained SECOND of each --speed-profiles entry at each precision
(the paper profile cannot be trained on a CPU; the weights change the time only through the boxes NMS gets) over the
first sequence, next to each profile's compute floor: the FLOPs of one forward pass on its first frame over this
machine's fp32 GEMM rate (compute_floor.py beside this script), the least ms/frame any fp32 implementation of that
model needs on these threads.
Results: Markdown on stdout, JSON in --out/tracking_benchmark.json.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np
import torch

from compute_floor import floor_ms, forward_flops, gemm_flops_per_s  # beside this script
from pcdet_memslidar.config import load_config
from pcdet_memslidar.evaluation.folders import evaluate_folders
from pcdet_memslidar.evaluation.metrics import ap_summary
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.models.detector import PRECISIONS
from pcdet_memslidar.monitor.detect import DETECTIONS_FILE, DetectOptions, FrameVoxeliser, detect
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, save_checkpoint
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import SETTINGS_FILE, simulate_sequence_dataset
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores
from tracking_metrics import mot_metrics, sequence_truth

SEED_BASE = 1000  # sequence seeds: far from the datasets' seeds (0, 1)


def sequences(out: Path, count: int, length: int) -> list[Path]:
    """The benchmark's industrial sequences, simulated once into out/sequences."""
    roots = []
    for seed in range(SEED_BASE, SEED_BASE + count):
        root = out / "sequences" / f"industrial_{length}_{seed}"
        if not (root / SETTINGS_FILE).is_file():
            simulate_sequence_dataset(get_domain("industrial"), length, root, seed=seed)
        roots.append(root)
    return roots


def tracked_labels(records: list[dict], folder: Path) -> Path:
    """KITTI labels (with scores) of the detections of confirmed tracks only."""
    for record in records:
        tracked = [d for d in record["detections"] if d["track_id"] is not None]
        boxes = np.array([d["box"] for d in tracked], dtype=np.float64).reshape(-1, 7)
        scores = np.array([d["score"] for d in tracked], dtype=np.float64)
        kitti.write_label(folder / f"{record['frame']}.txt",
                          kitti.label_from_boxes(["Pedestrian"] * len(boxes), boxes, Calibration.virtual(), scores))
    return folder


def untrained_model(cfg) -> torch.nn.Module:
    model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=FrameVoxeliser(cfg, logging.getLogger()))
    model.profile = cfg.get("PROFILE")
    return model.eval()


def frame_flops(model, root: Path) -> int:
    """FLOPs of model's forward pass on the first frame of the KITTI folder `root`."""
    layout = KittiLayout(root)
    frame_id = layout.frame_ids()[0]
    sample = model.dataset(kitti.read_points(layout.velodyne(frame_id)), frame_id)
    return forward_flops(model, load_data_to_device(model.dataset.collate_batch([sample]), torch.device("cpu")))


def speed_row(name: str, summary: dict) -> str:
    stages = summary["ms_per_frame"]
    return (f"| {name} | {summary['frames_per_s']:.2f} | " + " | ".join(f"{stages[s]:.0f}" for s in stages)
            + f" | {summary['detections'] / summary['frames']:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", required=True, help="the detector's config")
    parser.add_argument("--profile", default="quick", help="its profile (the checkpoint's)")
    parser.add_argument("--ckpt", required=True, type=Path, help="a trained checkpoint of --cfg / --profile")
    parser.add_argument("--sequences", type=int, default=6, help="industrial sequences (default %(default)s)")
    parser.add_argument("--length", type=int, default=25,
                        help="frames per sequence (default %(default)s: 10 s; a walk must stay clear of the machines "
                             "for the whole sequence, so long ones keep mostly people who stand)")
    parser.add_argument("--speed-profiles", nargs="*", default=["quick", "paper"],
                        help="profiles timed with an untrained SECOND (default: %(default)s)")
    parser.add_argument("--precisions", nargs="+", choices=PRECISIONS, default=list(PRECISIONS),
                        help="inference precisions to run (default: %(default)s)")
    parser.add_argument("--threads", type=int, default=available_cores(), help="torch threads (default: the cores)")
    parser.add_argument("--out", type=Path, default=Path("output/benchmark/tracking"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load_config(args.cfg, profile=args.profile)
    roots = sequences(args.out, args.sequences, args.length)

    per_sequence, pooled, speeds = {}, {}, {}
    for precision in args.precisions:
        runs, rows = [], []
        for root in roots:
            out = args.out / "detect" / precision / root.name
            summary = detect(cfg, args.ckpt, DetectOptions(src=root, out=out, fmt="kitti", precision=precision))
            records = [json.loads(line) for line in (out / DETECTIONS_FILE).open()]
            gt = KittiLayout(root).training / "label_2"
            all_ap = ap_summary(evaluate_folders(gt, out / "labels")[0])["AP3D_R40"]
            tracked = tracked_labels(records, args.out / "tracked_labels" / precision / root.name)
            tracked_ap = ap_summary(evaluate_folders(gt, tracked)[0])["AP3D_R40"]
            runs.append((sequence_truth(root), records))
            rows.append({"sequence": root.name, "AP3D_R40": all_ap, "AP3D_R40_tracked": tracked_ap,
                         **mot_metrics(runs[-1:]), "speed": summary})
        per_sequence[precision], pooled[precision] = rows, mot_metrics(runs)
        speeds[f"{args.profile} (trained), {precision}"] = rows[0]["speed"]
    gemm_rate, floors = gemm_flops_per_s(), {}
    for profile in args.speed_profiles:
        speed_cfg = load_config(args.cfg, profile=profile)
        model = untrained_model(speed_cfg)
        checkpoint = save_checkpoint(checkpoint_state(model, epoch=0), args.out / f"untrained_{profile}.pth")
        for precision in args.precisions:
            speeds[f"{profile} (untrained), {precision}"] = detect(
                speed_cfg, checkpoint, DetectOptions(src=roots[0], out=args.out / "speed" / profile / precision,
                                                     fmt="kitti", precision=precision))
        flops = frame_flops(model, roots[0])
        floor = floor_ms(flops, gemm_rate)
        floors[f"{profile} (untrained), fp32"] = {"gflop_per_frame": flops / 1e9, "floor_ms": floor,
                                                  "max_frames_per_s": 1000.0 / floor}

    print(f"# memslidar detect on {len(roots)} simulated industrial sequences of {args.length} frames "
          f"({args.threads} torch threads, {args.ckpt})\n")
    print("| precision | sequence | AP3D R40 | AP3D R40 tracked only | MOTA | IDF1 | ID switches | FP | misses | "
          "people |\n|---|---|---|---|---|---|---|---|---|---|")
    for precision, rows in per_sequence.items():
        for row in rows + [{"sequence": "all (pooled)", "AP3D_R40": float("nan"), "AP3D_R40_tracked": float("nan"),
                            **pooled[precision]}]:
            print(f"| {precision} | {row['sequence']} | {row['AP3D_R40']:.3f} | {row['AP3D_R40_tracked']:.3f} | "
                  f"{row['mota']:.3f} | {row['idf1']:.3f} | {row['num_switches']:.0f} | "
                  f"{row['num_false_positives']:.0f} | {row['num_misses']:.0f} | {row['num_unique_objects']:.0f} |")
    stages = " | ".join(f"{stage} ms" for stage in next(iter(speeds.values()))["ms_per_frame"])
    print(f"\n| model | frames/s | {stages} | detections/frame |\n|---|---|" + "---|" * 6)
    for name, summary in speeds.items():
        print(speed_row(name, summary))
    if floors:
        print(f"\n| model | GFLOP/frame | fp32 GEMM GFLOP/s ({args.threads} threads) | floor ms/frame "
              "| at most frames/s | measured infer ms/frame |\n|---|---|---|---|---|---|")
    for name, floor in floors.items():
        print(f"| {name} | {floor['gflop_per_frame']:.1f} | {gemm_rate / 1e9:.0f} | {floor['floor_ms']:.0f} | "
              f"{floor['max_frames_per_s']:.1f} | {speeds[name]['ms_per_frame']['infer']:.0f} |")
    write_text(args.out / "tracking_benchmark.json",
               json.dumps({"checkpoint": str(args.ckpt), "threads": args.threads, "length": args.length,
                           "sequences": per_sequence, "pooled": pooled, "speed": speeds,
                           "gemm_flops_per_s": gemm_rate, "compute_floor": floors}, indent=1) + "\n")


if __name__ == "__main__":
    main()
