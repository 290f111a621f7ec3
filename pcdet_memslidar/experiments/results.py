"""The parts of a reproduction's results.json: run scores, model entries, bootstrap intervals, environment
and figures (experiments.report renders report.md from them).

`results` is one JSON-ready dict (assembled by pcdet_memslidar.experiments.reproduce from the parts here):
    profile, profile_settings ['KEY.SUB value', ...] (what the profile sets: config.profile_settings),
    overrides [KEY, VALUE, ...] (--set), seeds [int], command, date (ISO), wall_seconds,
    environment {package, python, libraries {name: version}, machine {cpu, cores, torch_threads, gpu}},
    stages {name: seconds} (in run order),
    data {domain: {path, frames, boxes}}, test_domain, figures {key: file name}, example_frames [{role, frame_id, why}],
    models {model id: {cfg, counts {source: {frames, train, val}},
                       runs [{seed, metrics {AP3D_R40, ..., AP3D_R40_0-10m, ..., ms_per_frame}, num_gt, num_dt,
                              predictions (folder, relative to the report)}],
                       mean {metric: value}, std {metric: value},
                       interval {metric: [low, high]}, difference_interval {other model id: {metric: [low, high]}}}},
    intervals {level, resamples, seed, frames, seconds}.
AP values are fractions in [0, 1] (None where undefined: no ground truth in a distance bin); gains over M1 are in
percentage points, as the paper's Table 3 ("+17 %" for 0.10 -> 0.27).
`interval`, `difference_interval` and `intervals` come from add_intervals (absent before it runs): bootstrap
percentile intervals over the test frames and the seeds (pcdet_memslidar/evaluation/bootstrap.py) of the seed-mean
AP of each INTERVAL_METRICS (all distances), and of this model's seed-mean AP minus each other model's, with the same
resampled frames for both (paired) and each model's seeds drawn on their own; `intervals` holds the confidence
level, the number of resamples, the seed of the resampling, the number of test frames and the seconds it took.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import subprocess
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar import __version__
from pcdet_memslidar.evaluation.bootstrap import (
    LEVEL,
    RESAMPLES,
    SEED,
    bootstrap_ap,
    check_level,
    frame_matches,
    percentile_interval,
    resample_counts,
)
from pcdet_memslidar.evaluation.diagnose import extent_agreement
from pcdet_memslidar.evaluation.figures import (
    SCORE_THRESHOLD,
    choose_example_frames,
    plot_ap_intervals,
    plot_ap_vs_time,
    plot_example_frames,
    plot_pr_curves,
    plot_training_curves,
)
from pcdet_memslidar.evaluation.folders import CLASS_NAME, aligned_folders, read_label_folder
from pcdet_memslidar.evaluation.metrics import ap_summary, evaluate
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.utils.cores import available_cores

# The paper's Table 2 (synthetic, real frames of each training set, before the 70/30 split) and Table 3 (AP, IoU 0.5)
PAPER_COUNTS = {"M1": {"sim": 0, "real": 2100}, "M2": {"sim": 2100, "real": 0},
                "M3": {"sim": 1050, "real": 1050}, "M4": {"sim": 1470, "real": 630}}
PAPER_AP = {"M1": 0.10, "M2": 0.27, "M3": 0.54, "M4": 0.45}
PAPER_ORDER = ("M3", "M4", "M2", "M1")  # Table 3, best first
HEADLINE = "AP3D_R40"  # compared with the paper's AP: 3D IoU 0.5, OpenPCDet's default 40 recall positions
TABLE3_COLUMNS = ("AP3D_R40", "AP3D_R11", "APBEV_R40", "APBEV_R11")
INTERVAL_METRICS = TABLE3_COLUMNS  # bootstrap intervals of these (all distances)
REFERENCE_MODEL = "M1"
ORIENTATION = "orientation_error_deg"  # median angle [deg] between matched people's long sides (evaluation.diagnose)
ORACLE = "oracle"  # in-domain training: Table 3 gives every model's difference to it
LIBRARIES = ("torch", "spconv", "numpy", "scipy", "open3d", "matplotlib", "easydict", "pyyaml")  # versions reported
VECTOR_EXTENSIONS = {"sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_bf16",
                     "amx_tile"}  # /proc/cpuinfo flags that decide float speed and rounding


def summarise_runs(runs: list[dict]) -> tuple[dict, dict]:
    """Mean and sample standard deviation (0 for one run) over seeds of every metric in runs[i]['metrics'].

    A metric undefined (None) in any run is None in both.
    """
    keys = [key for key in runs[0]["metrics"] if all(key in run["metrics"] for run in runs)]
    mean, std = {}, {}
    for key in keys:
        values = [run["metrics"][key] for run in runs]
        if any(value is None for value in values):
            mean[key] = std[key] = None
            continue
        values = np.asarray(values, dtype=np.float64)
        mean[key] = float(values.mean())
        std[key] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
    return mean, std


def gain_over_reference(models: dict, metric: str = HEADLINE, reference_model: str = REFERENCE_MODEL
                        ) -> dict[str, float | None]:
    """{model: mean metric minus the reference model's (default M1), in percentage points} (None where undefined)."""
    reference = models.get(reference_model, {}).get("mean", {}).get(metric)
    gains = {}
    for name, model in models.items():
        value = model["mean"].get(metric)
        gains[name] = None if value is None or reference is None else 100.0 * (value - reference)
    return gains


def score_run(gt_dir: Path, pred_dir: Path) -> dict:
    """A run's scores as JSON-ready run fields: the AP of its saved prediction labels against the ground-truth
    labels and the median orientation error of its matched people -> {metrics (ap_summary, orientation_error_deg
    and orientation_error_deg_<distance bin>, None without a pair), num_gt, num_dt, pr_curves {3D, BEV} (all
    distances)}."""
    gt_annos, dt_annos, _ = aligned_folders(gt_dir, pred_dir)
    result = evaluate(gt_annos, dt_annos, class_name=CLASS_NAME)
    orientation = extent_agreement(gt_annos, dt_annos)["orientation"]
    metrics = ap_summary(result) | {ORIENTATION: orientation and orientation["median_abs_error"]}
    for label, entry in (orientation or {}).get("by_distance", {}).items():
        metrics[f"{ORIENTATION}_{label}"] = entry["median_abs_error"]
    return {"metrics": metrics, "num_gt": result["num_gt"], "num_dt": result["num_dt"],
            "pr_curves": {kind: result["pr_curves"][kind]["all"] for kind in ("3D", "BEV")}}


def model_entry(cfg_file: str, counts: dict, runs: list[dict], detector: str = "SECONDNet",
                model: str | None = None) -> dict:
    """results['models'][run id]: its config, detector (MODEL.NAME), model (M1 ... oracle, whatever the head),
    Table 2 counts, mean and std over the seeds' runs, and the runs (without their PR curves, which only the
    figure draws)."""
    mean, std = summarise_runs(runs)
    return {"cfg": cfg_file, "detector": detector, "model": model, "counts": counts, "mean": mean, "std": std,
            "runs": [{key: value for key, value in run.items() if key != "pr_curves"} for run in runs]}


def counterpart(models: dict, name: str, base: str) -> str | None:
    """The id of model `base` (M1, oracle) trained with the same detector as model `name` ('M1-center' for
    'M3-center'), None where it did not run. An entry without 'model' (older results) is its own id's model."""
    detector = models[name].get("detector", "SECONDNet")
    return next((other for other, entry in models.items() if (entry.get("model") or other) == base
                 and entry.get("detector", "SECONDNet") == detector), None)


def environment() -> dict:
    """results['environment']: package version and commit, library versions, CPU (model name and vector extensions),
    the vector code torch and oneDNN may use here, cores, torch threads and GPU of this process."""
    libraries = {}
    for name in LIBRARIES:
        with contextlib.suppress(metadata.PackageNotFoundError):
            libraries[name] = metadata.version(name if name != "spconv" else _spconv_distribution())
    cpu, flags = platform.processor() or platform.machine(), set()
    with contextlib.suppress(OSError):
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        names = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
        cpu = names[0] if names else cpu
        flags = next((set(line.split(":", 1)[1].split()) for line in lines if line.startswith("flags")), set())
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"package": __version__, "commit": source_commit(), "python": platform.python_version(),
            "libraries": libraries,
            "machine": {"cpu": cpu, "vector_extensions": sorted(flags & VECTOR_EXTENSIONS),
                        "aten_cpu_capability": torch.backends.cpu.get_cpu_capability(),
                        "onednn_max_cpu_isa": os.environ.get("ONEDNN_MAX_CPU_ISA"),
                        "cores": available_cores(), "torch_threads": torch.get_num_threads(), "gpu": gpu,
                        "platform": platform.platform(), "load_average_1min": os.getloadavg()[0]}}


def source_commit() -> str | None:
    """The git commit of the package's source tree ('<hash>+dirty' with uncommitted changes to tracked files),
    None outside a git checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


def _spconv_distribution() -> str:
    """The installed spconv wheel's distribution name (spconv, spconv-cu121, ...)."""
    names = [dist.metadata["Name"] for dist in metadata.distributions() if dist.metadata["Name"].startswith("spconv")]
    return names[0] if names else "spconv"


def benchmark_entries(results: dict, benchmark_file: Path | None = None) -> list[dict]:
    """Points of the AP-vs-time figure: the models of this run, and the configurations in `benchmark_file`
    (tools/benchmark_model.py's JSON results) when it is given and exists."""
    shared = f" ({results['jobs']} models sharing the cores)" if results.get("jobs", 1) > 1 else ""
    entries = [{"name": name, "ms_per_frame": model["mean"]["ms_per_frame"], "ap": model["mean"][HEADLINE],
                "group": f"this run{shared}"} for name, model in results["models"].items()]
    if benchmark_file is not None and benchmark_file.is_file():
        benchmark = json.loads(benchmark_file.read_text())
        for row in benchmark.get("rows", []):
            if row.get("infer_ms") is not None and row.get(HEADLINE) is not None:
                entries.append({"name": row["config"], "ms_per_frame": row["infer_ms"], "ap": row[HEADLINE],
                                "group": f"tools/benchmark_model.py ({benchmark.get('device')}, "
                                         f"{benchmark.get('threads')} threads)"})
    return entries


def frame_predictions(pred_dir: Path, frame_ids: list[str]) -> list[dict]:
    """Prediction annos of a label folder, one per frame id in order (a frame without a file: no detections)."""
    saved = read_label_folder(pred_dir, with_score=True)
    empty = {"name": np.zeros(0, dtype=str), "boxes_lidar": np.zeros((0, 7)), "score": np.zeros(0)}
    return [saved.get(frame_id, empty) for frame_id in frame_ids]


def add_intervals(results: dict, gt_dir: Path, report_dir: Path, resamples: int = RESAMPLES, level: float = LEVEL,
                  seed: int = SEED, figure_dir: Path | None = None) -> None:
    """Fill results['intervals'] and every model's 'interval' and 'difference_interval' (module docstring): the
    bootstrap over the test frames of gt_dir, from the prediction folders of results' runs (relative to
    report_dir), the same resampled frames for every model and seed, each model's seeds resampled on their own
    (bootstrap.resample_counts over its seeds; seed + 1 + the model's index); draw ap_intervals.png into figure_dir
    (default report_dir) and name it in results['figures']."""
    started = time.perf_counter()
    check_level(level)
    gt = read_label_folder(Path(gt_dir), with_score=False)
    frame_ids = sorted(gt)
    gt_annos = [gt[frame_id] for frame_id in frame_ids]
    counts = resample_counts(len(frame_ids), resamples, seed)
    samples = {}  # {model: {metric: (resamples,) seed-mean AP}}
    for index, (name, model) in enumerate(results["models"].items()):
        runs = [frame_matches(gt_annos, frame_predictions(Path(report_dir) / run["predictions"], frame_ids))
                for run in model["runs"]]
        seed_counts = resample_counts(len(runs), resamples, seed + 1 + index)
        samples[name] = {f"AP{kind}_{positions}": values for kind in ("3D", "BEV")
                         for positions, values in bootstrap_ap([run[kind] for run in runs], counts,
                                                               seed_counts).items()}
    for name, model in results["models"].items():
        model["interval"] = {metric: list(percentile_interval(samples[name][metric], level))
                             for metric in INTERVAL_METRICS}
        model["difference_interval"] = {
            other: {metric: list(percentile_interval(samples[name][metric] - samples[other][metric], level))
                    for metric in INTERVAL_METRICS}
            for other in results["models"] if other != name}
    results["intervals"] = {"level": level, "resamples": resamples, "seed": seed, "frames": len(frame_ids),
                            "seconds": time.perf_counter() - started}
    entries = [{"name": name, "ap": model["mean"][HEADLINE], "interval": model["interval"][HEADLINE],
                "paper": PAPER_AP.get(name) if model.get("detector", "SECONDNet") == "SECONDNet" else None}
               for name, model in results["models"].items() if model["mean"].get(HEADLINE) is not None]
    oracle = results["models"].get(ORACLE, {}).get("mean", {}).get(HEADLINE)
    results.setdefault("figures", {})["ap_intervals"] = plot_ap_intervals(
        Path(figure_dir or report_dir) / "ap_intervals.png", entries, oracle).name


def add_figures(results: dict, runs: dict, gt_dir: Path, velodyne_dir: Path, out: Path,
                benchmark_file: Path | None = None) -> None:
    """Draw the report's figures into `out` from the runs {model: run with predictions, pr_curves, curve} (the
    first seed's) and fill results['figures'] and results['example_frames']."""
    gt = read_label_folder(gt_dir, with_score=False)
    frame_ids = sorted(gt)
    predictions = {name: frame_predictions(out / run["predictions"], frame_ids) for name, run in runs.items()}
    gt_boxes = [gt[frame_id]["boxes_lidar"][gt[frame_id]["name"] == CLASS_NAME] for frame_id in frame_ids]
    examples = choose_example_frames(gt_boxes, predictions)
    frames = [{"points": read_points(velodyne_dir / f"{frame_ids[e.index]}.bin"), "gt_boxes": gt_boxes[e.index],
               "title": f"{e.role} ({frame_ids[e.index]})"} for e in examples]
    plot_example_frames(out / "fig3_examples.png", frames,
                        {name: [annos[e.index] for e in examples] for name, annos in predictions.items()})
    plot_pr_curves(out / "pr_curves.png", {name: run["pr_curves"] for name, run in runs.items()},
                   {name: {"3D": run["metrics"]["AP3D_R40"], "BEV": run["metrics"]["APBEV_R40"]}
                    for name, run in runs.items()})
    plot_ap_vs_time(out / "ap_vs_time.png", benchmark_entries(results, benchmark_file))
    plot_training_curves(out / "training_curves.png", {name: run["curve"] for name, run in runs.items()})
    results["figures"] = {"examples": "fig3_examples.png", "pr_curves": "pr_curves.png",
                          "ap_vs_time": "ap_vs_time.png", "training_curves": "training_curves.png"}
    results["example_frames"] = [{"role": e.role, "frame_id": frame_ids[e.index], "why": e.why,
                                  "score_threshold": SCORE_THRESHOLD} for e in examples]



def json_safe(value):
    """`value` with NaN floats as None and numpy scalars / arrays as Python values."""
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return None
    return value

