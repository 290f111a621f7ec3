"""Benchmark the detectors on the CPU (or GPU): inference ms/frame and train-step ms per configuration (a step split
into data, to device, forward, backward and optimizer), and a speed-vs-error table of variants of the quick recipe
(BEV backbone width, head stride) with real AP.

    python tools/benchmark_model.py --cfg cfgs/m3.yaml                 # latency: quick + paper profiles
    python tools/benchmark_model.py --cfg cfgs/m3.yaml cfgs/centerpoint/m3.yaml   # the two heads side by side
    python tools/benchmark_model.py --cfg cfgs/m3.yaml --variants      # + each variant trained with the budget
    python tools/benchmark_model.py --cfg cfgs/m3.yaml --profiles paper --epochs 2   # + seconds per training epoch
    python tools/benchmark_model.py --cfg cfgs/m3.yaml --profiles quick --op_kinds   # + a step per kind of work

Frames come from the config's data when it exists (generate it first), else from synthetic person frames over
the config's range (the table says which). Latency is measured first, alone on the machine; then every variant is
trained with the --profile's budget (epochs, frames, optimiser), several at once in their own processes as in
`memslidar reproduce`, and its saved predictions of the test split are scored (AP 3D R40 at IoU 0.5), next to
the AP on its validation split after the last epoch and its training minutes. With --epochs, each configuration
also trains that many epochs with the training loop itself (loader workers, scheduler, checkpoints in a temporary
folder), in fp32 and with mixed precision (USE_AMP: fp16 on a GPU, bf16 on a CPU with bf16 units). Results: a
Markdown table on stdout and JSON in output/benchmark/model_benchmark.json (the report's AP-vs-time figure reads it).
"""
from __future__ import annotations

import argparse
import copy
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.mixing import split_sources
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.experiments.runs import default_jobs, run_jobs
from pcdet_memslidar.grid import bev_output_stride
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.models.detector import PRECISIONS
from pcdet_memslidar.runtime.common import default_workers, get_device, set_random_seed
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train_loop import prepare_training, train_model, train_one_step
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores

# name -> changes to the profile's config: BEV NUM_FILTERS / NUM_UPSAMPLE_FILTERS, UPSAMPLE_STRIDES with the
# head's stride (the anchors' feature_map_stride, or the center head's FEATURE_MAP_STRIDE)
VARIANTS = {
    "recipe": {},
    "BEV width x2": {"width": 2.0},
    "BEV width x1/2": {"width": 0.5},
    "stride-8 head": {"upsample_strides": [1, 2], "head_stride": 8},
}
# kind of work in a training step -> name prefixes of torch.profiler's events; an event's own (self) CPU time counts
OP_KINDS = {
    "sparse convs: gather and scatter": ("SubMConvFunction", "SparseConvFunction"),  # spconv's or the rulebook's
    "matrix products (BLAS)": ("aten::mm", "aten::addmm", "aten::bmm"),
    "dense convs (oneDNN, ATen)": ("aten::convolution", "aten::_convolution", "aten::mkldnn_convolution",
                                   "aten::_slow_conv2d", "aten::slow_conv"),
    "batch norm": ("aten::native_batch_norm", "aten::batch_norm"),
}


def config_name(cfg_file: str) -> str:
    """'m3' for cfgs/m3.yaml, 'centerpoint/m3' for cfgs/centerpoint/m3.yaml."""
    path = Path(cfg_file)
    return path.stem if path.parent.name == "cfgs" else f"{path.parent.name}/{path.stem}"


def voxel_step(cfg) -> dict:
    return next(p for p in cfg.DATA_CONFIG.DATA_PROCESSOR if p.NAME == "transform_points_to_voxels")


def apply_variant(cfg, width=1.0, upsample_strides=None, head_stride=None):
    """A copy of cfg with the BEV backbone's channels times `width` and the variant's head stride."""
    cfg = copy.deepcopy(cfg)
    bev = cfg.MODEL.BACKBONE_2D
    bev.NUM_FILTERS = [round(n * width) for n in bev.NUM_FILTERS]
    bev.NUM_UPSAMPLE_FILTERS = [round(n * width) for n in bev.NUM_UPSAMPLE_FILTERS]
    bev.UPSAMPLE_STRIDES = upsample_strides or bev.UPSAMPLE_STRIDES
    head = cfg.MODEL.DENSE_HEAD
    for anchor in head.get("ANCHOR_GENERATOR_CONFIG", []):
        anchor["feature_map_stride"] = head_stride or anchor["feature_map_stride"]
    if "FEATURE_MAP_STRIDE" in head.get("TARGET_ASSIGNER_CONFIG", {}):
        head.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE = head_stride or head.TARGET_ASSIGNER_CONFIG.FEATURE_MAP_STRIDE
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


def time_inference(model, dataset, frames: int, warmup: int, device) -> tuple[float, dict[str, float]]:
    """Median ms per frame (batch size 1, model forward incl. NMS; data loading excluded), and the median ms of each
    module of model.module_topology and of the post-processing after them."""
    model.eval()
    times, parts = [], {name: [] for name in [*model.module_topology, "post_processing"]}
    ticks = {}

    def tick(name):
        def hook(*_):
            if device.type == "cuda":
                torch.cuda.synchronize(device)
            ticks[name] = time.perf_counter()
        return hook

    handles = []
    for name in model.module_topology:
        handles.append(getattr(model, name).register_forward_pre_hook(tick(f"{name} start")))
        handles.append(getattr(model, name).register_forward_hook(tick(f"{name} end")))
    for index in range(warmup + frames):
        batch = load_data_to_device(dataset.collate_batch([dataset[index % len(dataset)]]), device)
        start = time.perf_counter()
        with torch.no_grad():
            model(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        end = time.perf_counter()
        if index >= warmup:
            times.append((end - start) * 1000)
            for name in model.module_topology:
                parts[name].append((ticks[f"{name} end"] - ticks[f"{name} start"]) * 1000)
            parts["post_processing"].append((end - ticks[f"{model.module_topology[-1]} end"]) * 1000)
    for handle in handles:
        handle.remove()
    return float(np.median(times)), {name: float(np.median(ms)) for name, ms in parts.items()}


def time_train_step(model, dataset, cfg, batch_size: int, steps: int, device) -> tuple[float, dict[str, float]]:
    """Median ms per training step (forward, backward, clip, Adam) on batches of `batch_size` frames, and the median
    ms of its phases: 'data' (reading, augmenting and voxelising the frames, collating; in training a loader worker
    can do it beside the step), then train_one_step's 'to device', 'forward', 'backward', 'optimizer'."""
    optimizer = build_optimizer(model, cfg.OPTIMIZATION)
    scheduler = build_scheduler(optimizer, steps + 1, 1, -1, cfg.OPTIMIZATION)
    times, phases = [], {}
    marks = []

    def phase_done(name: str) -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        marks.append((name, time.perf_counter()))

    for step in range(steps + 1):
        marks.clear()
        phase_done("start")
        frames = [dataset[(step * batch_size + i) % len(dataset)] for i in range(batch_size)]
        batch = dataset.collate_batch(frames)
        phase_done("data")
        train_one_step(model, optimizer, scheduler, batch, cfg.OPTIMIZATION.GRAD_NORM_CLIP, device,
                       phase_done=phase_done)
        if step:  # the first step warms up
            times.append((marks[-1][1] - marks[1][1]) * 1000)
            for (_, begin), (name, end) in zip(marks, marks[1:]):
                phases.setdefault(name, []).append((end - begin) * 1000)
    return float(np.median(times)), {name: float(np.median(ms)) for name, ms in phases.items()}


def op_kind_times(model, dataset, cfg, batch_size: int, steps: int, device) -> dict[str, float]:
    """ms per training step of each of OP_KINDS and of all other torch ops ('other ops'), from torch.profiler's self
    CPU time over time_train_step's steps (its warm-up step included). Python between the ops is not counted."""
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as profiler:
        time_train_step(model, dataset, cfg, batch_size, steps, device)
    totals = dict.fromkeys([*OP_KINDS, "other ops"], 0.0)
    for event in profiler.key_averages():
        kind = next((name for name, prefixes in OP_KINDS.items() if event.key.startswith(prefixes)), "other ops")
        totals[kind] += event.self_cpu_time_total / 1000 / (steps + 1)
    return totals


def time_epochs(cfg, dataset, epochs: int, use_amp: bool, device) -> dict:
    """Seconds of each of `epochs` epochs of runtime.train_loop.train_model on `dataset` (the config's batch size,
    default_workers() loader workers, checkpoints into a temporary folder), steps per epoch, and the GPU's peak
    memory [GiB] (0 on a CPU)."""
    workers = default_workers()
    loader = torch.utils.data.DataLoader(dataset, batch_size=cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU, shuffle=True,
                                         num_workers=workers, collate_fn=dataset.collate_batch, drop_last=True,
                                         persistent_workers=workers > 0)
    logger = logging.getLogger(__name__)
    starts, seconds = [], []
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    with tempfile.TemporaryDirectory(prefix="benchmark_epochs_") as ckpt_dir:
        set_random_seed(0)
        model, optimizer, scheduler, it, start, _ = prepare_training(cfg, dataset, Path(ckpt_dir), device, len(loader),
                                                                  epochs, logger)
        train_model(model, optimizer, loader, scheduler, cfg.OPTIMIZATION, start, epochs, it, 0, None, ckpt_dir,
                    device, use_tqdm_to_record=True, logger=logger, logger_iter_interval=100, use_amp=use_amp,
                    on_epoch_start=lambda _: starts.append(time.perf_counter()),
                    on_epoch_end=lambda *_: seconds.append(time.perf_counter() - starts[-1]))
    peak = torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda" else 0.0
    return {"steps_per_epoch": len(loader), "epoch_s": seconds, "workers": workers, "peak_gpu_gib": peak}


def train_variants(variants: dict, out_dir: Path, threads: int) -> dict[str, dict]:
    """{name: {AP3D_R40 (test split), val_AP3D_R40 (last epoch), train_minutes}} of every variant trained with its
    config's budget, all at once in worker processes (experiments.runs.run_jobs) into out_dir/<name>."""
    jobs = []
    for name, cfg in variants.items():
        test, = split_sources(cfg.DATA_CONFIG, "test", Path(cfg.DATA_CONFIG.DATA_PATH))
        run_dir = out_dir / name.replace("/", "-").replace(" ", "_")
        jobs.append({"model": name, "seed": 0, "cfg": cfg, "run_dir": run_dir,
                     "gt_dir": KittiLayout(test.root).training / "label_2", "out": out_dir, "workers": 0,
                     "threads": threads, "every_epoch": False})
    runs = run_jobs(jobs, min(len(jobs), default_jobs(len(jobs))), logging.getLogger(__name__))
    return {job["model"]: {"AP3D_R40": run["metrics"]["AP3D_R40"], "val_AP3D_R40": run["curve"][-1]["val_AP3D_R40"],
                           "train_minutes": run["curve"][-1]["minutes"]} for job, run in zip(jobs, runs)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", nargs="+", default=["cfgs/m3.yaml"], help="one or more experiment configs")
    parser.add_argument("--profiles", nargs="+", default=["quick", "paper"])
    parser.add_argument("--threads", type=int, default=available_cores(), help="torch threads (default: free cores)")
    parser.add_argument("--frames", type=int, default=10, help="timed frames / steps per configuration")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--batch_size", type=int, default=2, help="frames per timed training step")
    parser.add_argument("--precisions", nargs="+", choices=PRECISIONS, default=[PRECISIONS[0]],
                        help="precisions of the BEV part timed per profile, in inference and training (default: "
                             "%(default)s; bf16 in training: OPTIMIZATION.USE_AMP on a CPU)")
    parser.add_argument("--op_kinds", action="store_true",
                        help="also a training step's ms per kind of work (OP_KINDS), from torch's profiler")
    parser.add_argument("--variants", action="store_true",
                        help="also the speed-vs-error table: every variant trained with the --profile's budget")
    parser.add_argument("--profile", default="quick", help="the profile whose recipe the variants change")
    parser.add_argument("--epochs", type=int, default=0,
                        help="also train each configuration this many epochs, fp32 and mixed precision (USE_AMP)")
    parser.add_argument("--epoch_frames", type=int, default=1200,
                        help="synthetic training frames per epoch where the config's data is missing")
    parser.add_argument("--set", dest="set_cfgs", nargs=argparse.REMAINDER, default=None)
    parser.add_argument("--output", default="output/benchmark/model_benchmark.json")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(args.threads)
    device = get_device()
    rows = []

    def measure(name: str, cfg, precision: str = PRECISIONS[0]) -> None:
        dataset, source = frames_for(cfg, training=False, count=args.frames + args.warmup)
        set_random_seed(0)
        model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), dataset).to(device)
        model.set_precision(precision)
        row = {"config": name, "precision": precision, "voxel_xy_m": voxel_step(cfg).VOXEL_SIZE[0],
               "bev_filters": list(cfg.MODEL.BACKBONE_2D.NUM_FILTERS), "head": cfg.MODEL.DENSE_HEAD.NAME,
               "head_stride": int(bev_output_stride(cfg.MODEL.BACKBONE_2D)), "frames": source,
               "params": sum(p.numel() for p in model.parameters())}
        row["infer_ms"], row["infer_ms_per_module"] = time_inference(model, dataset, args.frames, args.warmup, device)
        model.set_precision(precision, training=True)  # the BEV part's precision in training too (USE_AMP)
        train_frames, _ = frames_for(cfg, training=True, count=args.frames + args.warmup)
        steps = max(2, args.frames // 2)
        row["train_step_ms"], row["train_ms_per_phase"] = time_train_step(model, train_frames, cfg, args.batch_size,
                                                                          steps, device)
        if args.op_kinds:
            row["train_ms_per_op_kind"] = op_kind_times(model, train_frames, cfg, args.batch_size, steps, device)
        rows.append(row)
        logging.getLogger(__name__).info(json.dumps(row))

    epoch_rows = []
    for cfg_file in args.cfg:
        for profile in args.profiles:
            cfg = load_config(cfg_file, args.set_cfgs, profile=profile)
            for precision in args.precisions:
                measure(f"{config_name(cfg_file)}/{profile}", cfg, precision)
            if args.epochs:
                frames, source = frames_for(cfg, training=True, count=args.epoch_frames)
                for mode in ("fp32", "amp"):
                    epoch_rows.append({"config": f"{config_name(cfg_file)}/{profile}", "mode": mode, "frames": source,
                                       **time_epochs(cfg, frames, args.epochs, mode == "amp", device)})
                    logging.getLogger(__name__).info(json.dumps(epoch_rows[-1]))
    if args.variants:
        variants = {}
        for cfg_file in args.cfg:
            base = load_config(cfg_file, args.set_cfgs, profile=args.profile)
            variants |= {f"{config_name(cfg_file)} {args.profile} {name}": apply_variant(base, **changes)
                         for name, changes in VARIANTS.items()}
        for name, cfg in variants.items():
            measure(name, cfg)
        trained = train_variants(variants, Path(args.output).parent / "variants", threads=1)
        for row in rows:
            row.update(trained.get(row["config"], {}))

    header = ["config", "precision", "head", "voxel_xy_m", "bev_filters", "head_stride", "params", "frames", "infer_ms",
              "train_step_ms", "train_minutes", "val_AP3D_R40", "AP3D_R40"]
    print(f"\ndevice {device}, {args.threads} torch threads, batch {args.batch_size} for train steps, "
          f"median of {args.frames} frames\n")
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in rows:
        cells = [row.get(key, "") for key in header]
        print("| " + " | ".join(f"{c:.1f}" if isinstance(c, float) and c > 1 else
                                 f"{c:.3f}" if isinstance(c, float) else str(c) for c in cells) + " |")
    modules = list(rows[0]["infer_ms_per_module"])
    print("\ninference ms per module (medians; they need not add up to infer_ms, itself a median)\n")
    print("| config | " + " | ".join(modules) + " |\n|" + "---|" * (len(modules) + 1))
    for row in rows:
        print(f"| {row['config']}, {row['precision']} | "
              + " | ".join(f"{row['infer_ms_per_module'][m]:.1f}" for m in modules) + " |")
    trained_rows = [row for row in rows if "train_ms_per_phase" in row]
    phases = list(trained_rows[0]["train_ms_per_phase"]) if trained_rows else []
    print(f"\ntraining step ms per phase (medians, batch {args.batch_size})\n")
    print("| config | " + " | ".join(phases) + " |\n|" + "---|" * (len(phases) + 1))
    for row in trained_rows:
        print(f"| {row['config']}, {row['precision']} | "
              + " | ".join(f"{row['train_ms_per_phase'][p]:.1f}" for p in phases) + " |")
    kind_rows = [row for row in rows if "train_ms_per_op_kind" in row]
    if kind_rows:
        print(f"\ntraining step ms per kind of work (torch's profiler, self CPU time, batch {args.batch_size})\n")
        print("| config | " + " | ".join(OP_KINDS) + " | other ops |\n|" + "---|" * (len(OP_KINDS) + 2))
        for row in kind_rows:
            print(f"| {row['config']}, {row['precision']} | "
                  + " | ".join(f"{ms:.1f}" for ms in row["train_ms_per_op_kind"].values()) + " |")
    if epoch_rows:
        print("\ntraining epochs (runtime.train_loop.train_model; s per epoch, the first includes warm-up)\n")
        print("| config | mode | frames | steps/epoch | loader workers | s per epoch | peak GPU GiB |\n|" + "---|" * 7)
        for row in epoch_rows:
            seconds = ", ".join(f"{s:.1f}" for s in row["epoch_s"])
            print(f"| {row['config']} | {row['mode']} | {row['frames']} | {row['steps_per_epoch']} | "
                  f"{row['workers']} | {seconds} | {row['peak_gpu_gib']:.2f} |")
    write_text(args.output, json.dumps({"device": str(device), "threads": args.threads, "rows": rows,
                                        "epochs": epoch_rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
