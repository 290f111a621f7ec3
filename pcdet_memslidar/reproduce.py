"""`memslidar reproduce`: the paper's M1-M4 experiment end to end, one command.

    memslidar reproduce --profile quick [--seeds K] [--out DIR] [--data-root DIR]

The story, one stage per line (each stage's wall time goes into the report):
1. data: simulate the `sim`, `real` and `industrial` frames the profile needs (cached: the simulator skips
   complete frames and refuses a folder made with other settings); a domain folder holding imported recordings
   (frames but no simulation.json) is used as it is, so real data replaces a simulated stand-in;
2. infos: info files and ground-truth databases of each domain (rebuilt only when the frames changed);
3. per seed and model M1-M4 (cfgs/m1.yaml ... m4.yaml, the same SECOND and hyper-parameters, Table 2 mixes):
   train (resumes from the newest checkpoint; a finished model is reused), then evaluate on the industrial split,
   writing KITTI prediction labels with scores;
4. AP of the saved prediction labels against the industrial ground truth (pcdet_memslidar.evaluation), figures,
   results.json and report.md in the output folder.
Profiles change sizes and epochs only (cfgs' PROFILES); the test domain keeps all its frames.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import os
import platform
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar import __version__
from pcdet_memslidar.config import cfg as global_cfg, load_config
from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import Source, resolve_sources, select_frames, split_frames
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation import ap_summary
from pcdet_memslidar.evaluation.cli import evaluate_folders, read_label_folder
from pcdet_memslidar.evaluation.figures import (SCORE_THRESHOLD, choose_example_frames, plot_ap_vs_time,
                                                plot_example_frames, plot_pr_curves)
from pcdet_memslidar.evaluation.report import HEADLINE, summarise_runs, write_report
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import load_params_from_file
from pcdet_memslidar.runtime.common import create_logger, get_device, set_random_seed, set_torch_threads
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch
from pcdet_memslidar.runtime.train_loop import prepare_training, train_model
from pcdet_memslidar.sim.domains import get_domain
from pcdet_memslidar.sim.writer import SETTINGS_FILE, simulate_dataset
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores

MODELS = ("M1", "M2", "M3", "M4")
PROFILES = ("smoke", "quick", "paper")
TEST_FRAMES = {"paper": 230, "quick": 100, "smoke": 8}  # frames of the test domain (the paper's ~230)
DATA_SEED = 0  # the simulated data is the same for every training seed
RUN_CONFIG = "config.json"  # the config a run folder's checkpoints were trained with
LIBRARIES = ("torch", "spconv", "numpy", "scipy", "open3d", "matplotlib", "easydict", "pyyaml")
BENCHMARK_RESULTS = Path("output/benchmark/model_benchmark.json")  # tools/benchmark_model.py, relative to the repo


def model_config(model: str, profile: str, data_root: Path | None, set_cfgs: list[str] | None = None):
    """The experiment config cfgs/<model>.yaml with `profile` applied, then DATA_PATH = data_root (if given) and
    the --set overrides [KEY, VALUE, ...]."""
    overrides = (["DATA_CONFIG.DATA_PATH", str(data_root)] if data_root is not None else []) + list(set_cfgs or [])
    return load_config(Path(global_cfg.ROOT_DIR) / "cfgs" / f"{model.lower()}.yaml", overrides, profile=profile)


def frames_needed(cfgs: dict) -> dict[str, tuple[Path, int]]:
    """{domain: (folder, frames)}: the largest count any model's mix takes of each source, plus the test domain."""
    needed: dict[str, tuple[Path, int]] = {}
    for cfg in cfgs.values():
        data_path = Path(cfg.DATA_CONFIG.DATA_PATH)
        for source in resolve_sources(cfg.DATA_CONFIG.MIX, data_path):
            count = max(source.count, needed.get(source.name, (None, 0))[1])
            needed[source.name] = (source.root, count)
        test = cfg.DATA_CONFIG.TEST_SOURCE
        needed[test.NAME] = (data_path / test.get("PATH", test.NAME), TEST_FRAMES[cfg.PROFILE])
    return {name: entry for name, entry in needed.items() if entry[1] > 0}


def prepare_domain(domain: str, root: Path, frames: int, logger) -> None:
    """Simulate frames 0..frames-1 of a bundled domain into root (complete frames are kept), unless root holds
    frames that were not simulated (imported recordings, no simulation.json): those are used as they are."""
    layout = KittiLayout(root)
    if layout.frame_ids() and not (root / SETTINGS_FILE).is_file():
        logger.info(f"{domain}: using the {len(layout.frame_ids())} frames in {root} as they are (no {SETTINGS_FILE}: "
                    f"not simulated)")
        return
    simulate_dataset(get_domain(domain), frames, root, seed=DATA_SEED)


def table2_counts(cfg) -> dict[str, dict[str, int]]:
    """{source: {frames, train, val}} of a model's training set (Table 2 as built)."""
    mix = cfg.DATA_CONFIG.MIX
    counts = {}
    for source in resolve_sources(mix, Path(cfg.DATA_CONFIG.DATA_PATH)):
        frame_ids = select_frames(source, KittiLayout(source.root).frame_ids(), source.root) if source.count else []
        parts = {split: len(split_frames(frame_ids, split, float(mix.get("VAL_FRACTION", 0.3)),
                                         int(mix.get("SPLIT_SEED", 0)))) for split in ("train", "val")}
        counts[source.name] = {"frames": len(frame_ids), **parts}
    return counts


def check_run_config(cfg, run_dir: Path) -> None:
    """Record cfg in run_dir/config.json, or refuse a run folder whose checkpoints come from another config."""
    text = json.dumps(cfg, sort_keys=True, indent=1, default=str) + "\n"
    path = run_dir / RUN_CONFIG
    if path.is_file() and path.read_text() != text:
        raise ConfigError(f"{path}: the models in {run_dir} were trained with another config (profile, --set or "
                          f"cfgs changed); choose another --out or delete {run_dir} to retrain")
    write_text(path, text)


def train_detector(cfg, run_dir: Path, seed: int, workers: int, logger) -> Path:
    """Train cfg's SECOND into run_dir/ckpt (resuming from its newest checkpoint); returns the final checkpoint."""
    check_run_config(cfg, run_dir)
    epochs = int(cfg.OPTIMIZATION.NUM_EPOCHS)
    ckpt_dir = run_dir / "ckpt"
    final = ckpt_dir / f"checkpoint_epoch_{epochs}.pth"
    if final.is_file():
        logger.info(f"reusing {final}")
        return final
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    set_random_seed(seed)
    device = get_device()
    train_set, train_loader, sampler = build_dataloader(
        cfg.DATA_CONFIG, cfg.CLASS_NAMES, cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU, dist=False, workers=workers,
        seed=seed, logger=logger, training=True, total_epochs=epochs)
    model, optimizer, scheduler, it, start_epoch = prepare_training(cfg, train_set, ckpt_dir, device,
                                                                    len(train_loader), epochs, logger)
    train_model(model, optimizer, train_loader, scheduler, cfg.OPTIMIZATION, start_epoch, epochs, it, rank=0,
                tb_log=None, ckpt_save_dir=ckpt_dir, device=device, train_sampler=sampler, logger=logger)
    return final


def predict(cfg, checkpoint: Path, run_dir: Path, workers: int, logger) -> tuple[Path, float]:
    """Run the checkpoint over the test split, writing KITTI labels with scores; returns (their folder, ms/frame)."""
    device = get_device()
    test_set, test_loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU,
                                                dist=False, workers=workers, logger=logger, training=False)
    model = build_network(cfg.MODEL, num_class=len(cfg.CLASS_NAMES), dataset=test_set).to(device)
    epoch = load_params_from_file(model, checkpoint, logger, strict=True).get("epoch")
    result_dir = run_dir / "eval"
    result = eval_one_epoch(cfg, model, test_loader, epoch, logger, device, result_dir=result_dir, save_to_file=True)
    return result_dir / "final_result" / "data" / cfg.DATA_CONFIG.TEST_SOURCE.NAME, float(result["infer_time_ms"])


def score_predictions(gt_dir: Path, pred_dir: Path) -> dict:
    """evaluate() of saved prediction labels against the ground-truth labels, as JSON-ready run fields."""
    result, _ = evaluate_folders(gt_dir, pred_dir)
    return {"metrics": ap_summary(result), "num_gt": result["num_gt"], "num_dt": result["num_dt"],
            "pr_curves": {kind: result["pr_curves"][kind]["all"] for kind in ("3D", "BEV")}}


def environment() -> dict:
    """Package and library versions, CPU, cores, torch threads and GPU of this process."""
    libraries = {}
    for name in LIBRARIES:
        with contextlib.suppress(metadata.PackageNotFoundError):
            libraries[name] = metadata.version(name if name != "spconv" else _spconv_distribution())
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        names = [line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                 if line.startswith("model name")]
        cpu = names[0] if names else cpu
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"package": __version__, "python": platform.python_version(), "libraries": libraries,
            "machine": {"cpu": cpu, "cores": available_cores(), "torch_threads": torch.get_num_threads(), "gpu": gpu,
                        "platform": platform.platform(), "load_average_1min": os.getloadavg()[0]}}


def _spconv_distribution() -> str:
    """The installed spconv wheel's distribution name (spconv, spconv-cu121, ...)."""
    names = [dist.metadata["Name"] for dist in metadata.distributions() if dist.metadata["Name"].startswith("spconv")]
    return names[0] if names else "spconv"


def benchmark_entries(results: dict) -> list[dict]:
    """Points of the AP-vs-time figure: M1-M4 of this run and tools/benchmark_model.py's configurations."""
    entries = [{"name": name, "ms_per_frame": model["mean"]["ms_per_frame"], "ap": model["mean"][HEADLINE],
                "group": "M1-M4 (this run)"} for name, model in results["models"].items()]
    path = Path(global_cfg.ROOT_DIR) / BENCHMARK_RESULTS
    if path.is_file():
        benchmark = json.loads(path.read_text())
        for row in benchmark.get("rows", []):
            if row.get("infer_ms") is not None and row.get(HEADLINE) is not None:
                entries.append({"name": row["config"], "ms_per_frame": row["infer_ms"], "ap": row[HEADLINE],
                                "group": f"tools/benchmark_model.py ({benchmark.get('device')}, "
                                         f"{benchmark.get('threads')} threads)"})
    return entries


def make_figures(results: dict, runs: dict, gt_dir: Path, velodyne_dir: Path, out: Path) -> None:
    """The three figures of the report from the first seed's saved predictions; fills results['figures'] and
    results['example_frames']."""
    gt = read_label_folder(gt_dir, with_score=False)
    frame_ids = sorted(gt)
    predictions = {}
    for name, run in runs.items():
        saved = read_label_folder(out / run["predictions"], with_score=True)
        empty = {"name": np.zeros(0, dtype=str), "boxes_lidar": np.zeros((0, 7)), "score": np.zeros(0)}
        predictions[name] = [saved.get(frame_id, empty) for frame_id in frame_ids]
    gt_boxes = [gt[frame_id]["boxes_lidar"][gt[frame_id]["name"] == "Pedestrian"] for frame_id in frame_ids]
    examples = choose_example_frames(gt_boxes, predictions)
    frames = [{"points": read_points(velodyne_dir / f"{frame_ids[e.index]}.bin"), "gt_boxes": gt_boxes[e.index],
               "title": f"{e.role} ({frame_ids[e.index]})"} for e in examples]
    plot_example_frames(out / "fig3_examples.png", frames,
                        {name: [annos[e.index] for e in examples] for name, annos in predictions.items()})
    plot_pr_curves(out / "pr_curves.png", {name: run["pr_curves"] for name, run in runs.items()},
                   {name: {"3D": run["metrics"]["AP3D_R40"], "BEV": run["metrics"]["APBEV_R40"]}
                    for name, run in runs.items()})
    plot_ap_vs_time(out / "ap_vs_time.png", benchmark_entries(results))
    results["figures"] = {"examples": "fig3_examples.png", "pr_curves": "pr_curves.png",
                          "ap_vs_time": "ap_vs_time.png"}
    results["example_frames"] = [{"role": e.role, "frame_id": frame_ids[e.index], "why": e.why,
                                  "score_threshold": SCORE_THRESHOLD} for e in examples]


class StageClock:
    """Wall time of each named stage, logged when it starts and ends."""

    def __init__(self, logger):
        self.logger, self.seconds = logger, {}

    @contextlib.contextmanager
    def __call__(self, name: str):
        self.logger.info(f"==> {name}")
        start = time.perf_counter()
        yield
        self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
        self.logger.info(f"<== {name}: {self.seconds[name]:.1f} s")


def reproduce(profile: str, seeds: int, out: Path, data_root: Path | None = None, workers: int = 0,
              command: str = "", set_cfgs: list[str] | None = None) -> dict:
    """Run the whole reproduction (module docstring) and return the results dict written to out/results.json."""
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile '{profile}'; use one of {', '.join(PROFILES)}")
    if seeds < 1:
        raise ConfigError(f"--seeds must be >= 1, got {seeds}")
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "reproduce_log.txt")
    set_torch_threads()
    clock = StageClock(logger)
    cfgs = {model: model_config(model, profile, data_root, set_cfgs) for model in MODELS}
    needed = frames_needed(cfgs)

    for domain, (root, frames) in needed.items():  # 1. data
        with clock(f"data: {domain}"):
            prepare_domain(domain, root, frames, logger)
    with clock("infos"):  # 2. info files and gt databases
        infos = {domain: create_domain_infos(Source(domain, root, frames)) for domain, (root, frames) in needed.items()}

    test = cfgs[MODELS[0]].DATA_CONFIG.TEST_SOURCE.NAME
    test_root = needed[test][0]
    gt_dir, velodyne_dir = KittiLayout(test_root).training / "label_2", KittiLayout(test_root).training / "velodyne"
    runs: dict[str, list[dict]] = {model: [] for model in MODELS}
    for seed in range(seeds):  # 3. train and evaluate M1-M4
        for model, cfg in cfgs.items():
            run_dir = out / "models" / model / f"seed_{seed}"
            with clock(f"train {model}"):
                checkpoint = train_detector(cfg, run_dir, seed, workers, logger)
            with clock(f"evaluate {model}"):
                pred_dir, ms_per_frame = predict(cfg, checkpoint, run_dir, workers, logger)
                run = {"seed": seed, **score_predictions(gt_dir, pred_dir),
                       "predictions": str(pred_dir.relative_to(out))}
                run["metrics"]["ms_per_frame"] = ms_per_frame
                runs[model].append(run)
                logger.info(f"{model} seed {seed}: AP3D_R40 {run['metrics']['AP3D_R40']}, "
                            f"{ms_per_frame:.1f} ms/frame")

    results = {  # 4. report
        "profile": profile, "overrides": list(set_cfgs or []), "seeds": list(range(seeds)), "command": command,
        "date": started.isoformat(timespec="seconds"),
        "environment": environment(), "test_domain": test,
        "data": {domain: {"path": str(needed[domain][0]), "frames": len(domain_infos),
                          "boxes": sum(len(info["annos"]["name"]) for info in domain_infos)}
                 for domain, domain_infos in infos.items()},
        "models": {},
    }
    for model, model_runs in runs.items():
        mean, std = summarise_runs(model_runs)
        results["models"][model] = {"cfg": str(Path(cfgs[model].CFG_FILE).relative_to(global_cfg.ROOT_DIR)),
                                    "counts": table2_counts(cfgs[model]), "mean": mean, "std": std,
                                    "runs": [{key: value for key, value in run.items() if key != "pr_curves"}
                                             for run in model_runs]}
    with clock("figures"):
        make_figures(results, {model: model_runs[0] for model, model_runs in runs.items()}, gt_dir, velodyne_dir, out)
    results["stages"] = clock.seconds
    results["wall_seconds"] = time.perf_counter() - wall_start
    report_path, json_path = write_report(results, out)
    logger.info(f"report: {report_path}; results: {json_path}")
    return results


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", choices=PROFILES, default="quick",
                        help="sizes and epochs: smoke (seconds), quick (2-core CPU, ~20 min), paper (GPU)")
    parser.add_argument("--seeds", type=int, default=1, help="training seeds 0..K-1; the report gives mean and std")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/reproduce/<profile>)")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder of the sim/real/industrial domains (default: the cfgs' DATA_PATH, data/memslidar)")
    parser.add_argument("--workers", type=int, default=0,
                        help="data loader worker processes (0: in the training process, best on a 2-core CPU)")
    parser.add_argument("--set", dest="set_cfgs", default=None, nargs=argparse.REMAINDER,
                        help="overrides of all four model configs: KEY.SUB VALUE ... (after the profile)")


def run(args: argparse.Namespace) -> int:
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "reproduce" / args.profile
    data_root = args.data_root.resolve() if args.data_root is not None else None
    command = " ".join(["memslidar reproduce", f"--profile {args.profile}", f"--seeds {args.seeds}",
                        *([f"--out {args.out}"] if args.out else []),
                        *([f"--data-root {args.data_root}"] if args.data_root else []),
                        *(["--set", *args.set_cfgs] if args.set_cfgs else [])])
    results = reproduce(args.profile, args.seeds, out.resolve(), data_root, args.workers, command, args.set_cfgs)
    for model, entry in results["models"].items():
        print(f"{model}: {HEADLINE} {entry['mean'][HEADLINE]}  ms/frame {entry['mean']['ms_per_frame']:.1f}")
    print(f"report: {out / 'report.md'}")
    return 0
