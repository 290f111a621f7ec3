"""Benchmark SECOND on the CPU (or GPU): inference ms/frame and train-step ms per configuration, and a
speed-vs-error table over voxel size and BEV backbone width with AP on the test (industrial) split.

    python tools/benchmark_model.py --cfg cfgs/m3.yaml                         # latency: quick + paper profiles
    python tools/benchmark_model.py --cfg cfgs/m3.yaml --variants --train_epochs 6 --set PROFILE quick

Frames come from the config's data when it exists (generate it first), else from synthetic person frames over
the config's range (the table says which). AP needs data: each variant is trained --train_epochs epochs (or its
checkpoint is given with --ckpt VARIANT=PATH) and evaluated on DATA_SPLIT.test. Results: a Markdown table on
stdout and JSON in output/benchmark/model_benchmark.json.
"""
from __future__ import annotations

import argparse
import copy
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.config import load_config
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.runtime.checkpoint import load_params_from_file
from pcdet_memslidar.runtime.common import get_device, set_random_seed
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.synthetic import SyntheticPersonDataset
from pcdet_memslidar.runtime.train_loop import train_model, train_one_step
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores

# name -> (xy voxel size [m], BEV NUM_FILTERS, NUM_UPSAMPLE_FILTERS); 'paper' is the config as written
VARIANTS = {
    "voxel0.08-width1": (0.08, [128, 256], [256, 256]),
    "voxel0.08-width1/2": (0.08, [64, 128], [128, 128]),
    "voxel0.12-width1": (0.12, [128, 256], [256, 256]),
    "voxel0.16-width1": (0.16, [128, 256], [256, 256]),
    "voxel0.16-width1/2": (0.16, [64, 128], [128, 128]),
    "voxel0.16-width1/4": (0.16, [32, 64], [64, 64]),
}


def voxel_step(cfg) -> dict:
    return next(p for p in cfg.DATA_CONFIG.DATA_PROCESSOR if p.NAME == "transform_points_to_voxels")


def apply_variant(cfg, xy_voxel: float, filters: list[int], upsample_filters: list[int]):
    cfg = copy.deepcopy(cfg)
    step = voxel_step(cfg)
    step.VOXEL_SIZE = [xy_voxel, xy_voxel, step.VOXEL_SIZE[2]]
    cfg.MODEL.BACKBONE_2D.NUM_FILTERS = filters
    cfg.MODEL.BACKBONE_2D.NUM_UPSAMPLE_FILTERS = upsample_filters
    return cfg


def frames_for(cfg, training: bool, count: int):
    """(dataset, source name): the config's data when available, else synthetic frames over its range."""
    try:
        from pcdet_memslidar.datasets import build_dataloader
        dataset, _, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, 1, False, workers=0, training=training)
        if len(dataset) > 0:
            return dataset, "data"
    except Exception as error:  # missing data folders, infos, ...: fall back, and say so
        logging.getLogger(__name__).info(f"no data for {cfg.TAG} ({error}); using synthetic frames")
    step = voxel_step(cfg)
    return SyntheticPersonDataset(cfg.DATA_CONFIG.POINT_CLOUD_RANGE, step.VOXEL_SIZE, num_frames=count,
                                  max_voxels=step.MAX_NUMBER_OF_VOXELS["test"]), "synthetic"


def time_inference(model, dataset, frames: int, warmup: int, device) -> float:
    """Median ms per frame (batch size 1, model forward incl. NMS; data loading excluded)."""
    model.eval()
    times = []
    for index in range(warmup + frames):
        batch = load_data_to_device(dataset.collate_batch([dataset[index % len(dataset)]]), device)
        start = time.perf_counter()
        with torch.no_grad():
            model(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        if index >= warmup:
            times.append((time.perf_counter() - start) * 1000)
    return float(np.median(times))


def time_train_step(model, dataset, cfg, batch_size: int, steps: int, device) -> float:
    """Median ms per training step (forward, backward, clip, Adam) on batches of `batch_size` frames."""
    optimizer = build_optimizer(model, cfg.OPTIMIZATION)
    scheduler = build_scheduler(optimizer, steps + 1, 1, -1, cfg.OPTIMIZATION)
    times = []
    for step in range(steps + 1):
        frames = [dataset[(step * batch_size + i) % len(dataset)] for i in range(batch_size)]
        batch = dataset.collate_batch(frames)
        start = time.perf_counter()
        train_one_step(model, optimizer, scheduler, batch, cfg.OPTIMIZATION.GRAD_NORM_CLIP, device)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        if step:
            times.append((time.perf_counter() - start) * 1000)
    return float(np.median(times))


def train_and_evaluate(cfg, epochs: int, ckpt: str | None, device, out_dir: Path) -> float | None:
    """AP3D_R40 at IoU 0.5 on the test split after `epochs` of training (or of checkpoint `ckpt`)."""
    from pcdet_memslidar.datasets import build_dataloader

    logger = logging.getLogger(__name__)
    test_set, test_loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, 1, False, workers=2, training=False)
    model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), test_set).to(device)
    if ckpt:
        load_params_from_file(model, ckpt, logger, strict=True)
    else:
        set_random_seed(666)
        train_set, train_loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES,
                                                      cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU, False, workers=2, seed=666)
        optimizer = build_optimizer(model, cfg.OPTIMIZATION)
        scheduler = build_scheduler(optimizer, len(train_loader), epochs, -1, cfg.OPTIMIZATION)
        train_model(model, optimizer, train_loader, scheduler, cfg.OPTIMIZATION, 0, epochs, 0, 0, None,
                    out_dir / "ckpt", device, logger=logger)
    result = eval_one_epoch(cfg, model, test_loader, epochs, logger, device, result_dir=out_dir)
    return result.get("AP3D_R40")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", default="cfgs/m3.yaml")
    parser.add_argument("--profiles", nargs="+", default=["quick", "paper"])
    parser.add_argument("--threads", type=int, default=available_cores(), help="torch threads (default: free cores)")
    parser.add_argument("--frames", type=int, default=10, help="timed frames / steps per configuration")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--batch_size", type=int, default=2, help="frames per timed training step")
    parser.add_argument("--variants", action="store_true", help="also the speed-vs-error table")
    parser.add_argument("--train_epochs", type=int, default=0, help="train each variant this long for its AP")
    parser.add_argument("--ckpt", nargs="*", default=[], help="VARIANT=PATH checkpoints instead of training")
    parser.add_argument("--set", dest="set_cfgs", nargs=argparse.REMAINDER, default=None)
    parser.add_argument("--output", default="output/benchmark/model_benchmark.json")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(args.threads)
    device = get_device()
    checkpoints = dict(item.split("=", 1) for item in args.ckpt)
    rows = []

    def measure(name: str, cfg, with_ap: bool) -> None:
        dataset, source = frames_for(cfg, training=False, count=args.frames + args.warmup)
        set_random_seed(0)
        model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), dataset).to(device)
        row = {"config": name, "voxel_xy_m": voxel_step(cfg).VOXEL_SIZE[0],
               "bev_filters": list(cfg.MODEL.BACKBONE_2D.NUM_FILTERS), "frames": source,
               "params": sum(p.numel() for p in model.parameters()),
               "infer_ms": time_inference(model, dataset, args.frames, args.warmup, device),
               "train_step_ms": time_train_step(model, dataset, cfg, args.batch_size, max(2, args.frames // 2),
                                                device)}
        if with_ap and (args.train_epochs or name in checkpoints):
            row["AP3D_R40"] = train_and_evaluate(cfg, args.train_epochs, checkpoints.get(name), device,
                                                 Path(args.output).parent / name.replace("/", "_"))
        rows.append(row)
        logging.getLogger(__name__).info(json.dumps(row))

    for profile in args.profiles:
        measure(f"{Path(args.cfg).stem}/{profile}", load_config(args.cfg, args.set_cfgs, profile=profile), False)
    if args.variants:
        base = load_config(args.cfg, args.set_cfgs)
        for name, (xy_voxel, filters, upsample) in VARIANTS.items():
            measure(name, apply_variant(base, xy_voxel, filters, upsample), True)

    header = ["config", "voxel_xy_m", "bev_filters", "params", "frames", "infer_ms", "train_step_ms", "AP3D_R40"]
    print(f"\ndevice {device}, {args.threads} torch threads, batch {args.batch_size} for train steps, "
          f"median of {args.frames} frames\n")
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in rows:
        cells = [row.get(key, "") for key in header]
        print("| " + " | ".join(f"{c:.1f}" if isinstance(c, float) and c > 1 else
                                 f"{c:.3f}" if isinstance(c, float) else str(c) for c in cells) + " |")
    write_text(args.output, json.dumps({"device": str(device), "threads": args.threads, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
