"""`memslidar reproduce`: the paper's M1-M4 experiment end to end, one command.

    memslidar reproduce --profile quick [--seeds K] [--out DIR] [--data-root DIR] [--jobs N]

The story, one stage per line (each stage's wall time goes into the report):
1. data: simulate the frames the profile needs of every source (cached: the simulator skips complete frames and
   refuses a folder made with other settings); a folder holding imported recordings (frames but no
   simulation.json) is used as it is, so real data replaces a simulated stand-in;
2. infos: info files and ground-truth databases of each source (rebuilt only when the frames changed);
3. per seed, M1-M4 (cfgs/m1.yaml ... m4.yaml, the same SECOND and hyper-parameters, Table 2 mixes) and the oracle
   (cfgs/oracle.yaml: industrial frames of another simulation seed, the same budget): train with the validation AP
   of every epoch (resumes from the newest checkpoint; a finished model is reused), then predict the industrial
   split as KITTI labels with scores. `--jobs` models train at once, each in its own process on its share of the
   cores: on a CPU the sparse convolutions use one thread, so several one-thread trainings make better use of the
   cores than one training on all of them;
4. AP of the saved prediction labels against the industrial ground truth (pcdet_memslidar.evaluation), figures,
   results.json and report.md in the output folder.
Profiles change sizes, epochs and the grid (cfgs' PROFILES); the test domain keeps all its frames.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import multiprocessing
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from importlib import metadata
from pathlib import Path

import numpy as np
import torch
import tqdm

from pcdet_memslidar import __version__
from pcdet_memslidar.config import cfg as global_cfg, load_config
from pcdet_memslidar.datasets import build_dataloader
from pcdet_memslidar.datasets.grid import check_config_grid
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import Source, resolve_sources, select_frames, split_frames, split_sources
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation import ap_summary
from pcdet_memslidar.evaluation.cli import evaluate_folders, read_label_folder
from pcdet_memslidar.evaluation.figures import (SCORE_THRESHOLD, choose_example_frames, plot_ap_vs_time,
                                                plot_example_frames, plot_pr_curves, plot_training_curves)
from pcdet_memslidar.evaluation.report import HEADLINE, summarise_runs, write_report
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.checkpoint import load_params_from_file
from pcdet_memslidar.runtime.common import create_logger, get_device, set_random_seed
from pcdet_memslidar.runtime.eval_loop import eval_one_epoch, split_config
from pcdet_memslidar.runtime.experiment import check_learning_rate, positive_count
from pcdet_memslidar.runtime.train_loop import prepare_training, train_model
from pcdet_memslidar.sim.domains import get_domain
from pcdet_memslidar.sim.writer import SETTINGS_FILE, simulate_dataset
from pcdet_memslidar.utils.atomic import refuse_overlap, write_text
from pcdet_memslidar.utils.cores import available_cores
from pcdet_memslidar.utils.processes import exit_with_parent

MODELS = ("M1", "M2", "M3", "M4")
ORACLE = "oracle"  # trained in-domain: the ceiling of what a mix can reach on the industrial split
RUNS = (*MODELS, ORACLE)
PROFILES = ("smoke", "quick", "paper")
TEST_FRAMES = {"paper": 230, "quick": 100, "smoke": 8}  # frames of the test domain (the paper's ~230)
RUN_CONFIG = "config.json"  # the config a run folder's checkpoints were trained with
CURVE_FILE = "curve.json"  # per epoch: training loss, validation AP, training minutes
LIBRARIES = ("torch", "spconv", "numpy", "scipy", "open3d", "matplotlib", "easydict", "pyyaml")
BENCHMARK_RESULTS = Path("output/benchmark/model_benchmark.json")  # tools/benchmark_model.py, relative to the repo


def model_config(model: str, profile: str, data_root: Path | None, set_cfgs: list[str] | None = None):
    """The experiment config cfgs/<model>.yaml with `profile` applied, then DATA_PATH = data_root (if given) and
    the --set overrides [KEY, VALUE, ...]; checked as `memslidar train` checks it (grid, batch size, epochs, lr)."""
    overrides = (["DATA_CONFIG.DATA_PATH", str(data_root)] if data_root is not None else []) + list(set_cfgs or [])
    cfg = load_config(Path(global_cfg.ROOT_DIR) / "cfgs" / f"{model.lower()}.yaml", overrides, profile=profile)
    check_config_grid(cfg)
    check_learning_rate(cfg)
    for key in ("BATCH_SIZE_PER_GPU", "NUM_EPOCHS"):
        positive_count(None, f"--set OPTIMIZATION.{key}", cfg, key)
    return cfg


def frames_needed(cfgs: dict) -> dict[str, Source]:
    """{source name: the source with count = frames needed}: the largest count any model's mix takes of each
    source, and the test source with the profile's test frames."""
    needed: dict[str, Source] = {}

    def need(source: Source, count: int) -> None:
        known = needed.get(source.name)
        if known is not None and (known.root, known.domain, known.seed) != (source.root, source.domain, source.seed):
            raise ConfigError(f"source '{source.name}' is read from {known.root} ({known.domain}, seed {known.seed}) "
                              f"and from {source.root} ({source.domain}, seed {source.seed}): give one of them "
                              f"another NAME")
        needed[source.name] = Source(source.name, source.root, max(count, known.count if known else 0),
                                     source.domain, source.seed)

    for cfg in cfgs.values():
        for source in resolve_sources(cfg.DATA_CONFIG.MIX, Path(cfg.DATA_CONFIG.DATA_PATH)):
            need(source, source.count)
        test, = split_sources(cfg.DATA_CONFIG, "test", Path(cfg.DATA_CONFIG.DATA_PATH))
        need(test, TEST_FRAMES[cfg.PROFILE])
    return {name: source for name, source in needed.items() if source.count > 0}


def prepare_domain(source: Source, logger) -> None:
    """Simulate frames 0..count-1 of a bundled domain into the source's folder (complete frames are kept), unless
    the folder holds frames that were not simulated (imported recordings, no simulation.json): those are used as
    they are."""
    layout = KittiLayout(source.root)
    if layout.frame_ids() and not (source.root / SETTINGS_FILE).is_file():
        logger.info(f"{source.name}: using the {len(layout.frame_ids())} frames in {source.root} as they are "
                    f"(no {SETTINGS_FILE}: not simulated)")
        return
    simulate_dataset(get_domain(source.domain), source.count, source.root, seed=source.seed)


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


def read_curve(run_dir: Path) -> list[dict]:
    """The per-epoch entries of run_dir/curve.json ([] before the first epoch)."""
    path = run_dir / CURVE_FILE
    return json.loads(path.read_text()) if path.is_file() else []


def train_detector(cfg, run_dir: Path, seed: int, workers: int, logger, progress=None) -> Path:
    """Train cfg's SECOND into run_dir/ckpt (resuming from its newest checkpoint), with the AP on the mix's
    validation split after every epoch in run_dir/curve.json; returns the final checkpoint. progress(epoch) is
    called after each epoch."""
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
    val_cfg = split_config(cfg, "val")
    _, val_loader, _ = build_dataloader(val_cfg.DATA_CONFIG, cfg.CLASS_NAMES, cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU,
                                        dist=False, workers=workers, logger=logger, training=False)
    model, optimizer, scheduler, it, start_epoch = prepare_training(cfg, train_set, ckpt_dir, device,
                                                                    len(train_loader), epochs, logger)
    curve = [entry for entry in read_curve(run_dir) if entry["epoch"] <= start_epoch]
    clock = {"start": time.perf_counter(), "minutes": curve[-1]["minutes"] if curve else 0.0}

    def on_epoch_end(epoch: int, mean_loss: float) -> None:
        minutes = clock["minutes"] + (time.perf_counter() - clock["start"]) / 60
        result = eval_one_epoch(val_cfg, model, val_loader, epoch, logger, device)
        curve.append({"epoch": epoch, "minutes": round(minutes, 3), "loss": mean_loss,
                      "val_AP3D_R40": result["AP3D_R40"], "val_APBEV_R40": result["APBEV_R40"]})
        write_text(run_dir / CURVE_FILE, json.dumps(curve, indent=1) + "\n")
        clock.update(start=time.perf_counter(), minutes=minutes)  # validation time is not training time
        if progress is not None:
            progress(epoch)

    train_model(model, optimizer, train_loader, scheduler, cfg.OPTIMIZATION, start_epoch, epochs, it, rank=0,
                tb_log=None, ckpt_save_dir=ckpt_dir, device=device, train_sampler=sampler, logger=logger,
                use_tqdm_to_record=progress is not None, logger_iter_interval=len(train_loader),
                on_epoch_end=on_epoch_end)
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


def run_model(job: dict, progress=None) -> dict:
    """Train and test one (model, seed) job {model, seed, cfg, run_dir, gt_dir, out, workers, threads}; returns
    its run entry. Runs in the calling process or in a worker process of `reproduce` (then it logs to
    run_dir/log.txt only, and progress(epoch) reports its epochs)."""
    torch.set_num_threads(job["threads"])
    run_dir = Path(job["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    logger = create_logger(run_dir / "log.txt", name=f"pcdet_memslidar.{job['model']}.{job['seed']}",
                           console=progress is None)
    started = time.perf_counter()
    checkpoint = train_detector(job["cfg"], run_dir, job["seed"], job["workers"], logger, progress)
    trained = time.perf_counter()
    pred_dir, ms_per_frame = predict(job["cfg"], checkpoint, run_dir, job["workers"], logger)
    run = {"seed": job["seed"], **score_predictions(Path(job["gt_dir"]), pred_dir),
           "predictions": str(pred_dir.relative_to(job["out"])), "curve": read_curve(run_dir),
           "seconds": {"train": trained - started, "evaluate": time.perf_counter() - trained},
           "threads": job["threads"]}
    run["metrics"]["ms_per_frame"] = ms_per_frame
    logger.info(f"{job['model']} seed {job['seed']}: {HEADLINE} {run['metrics'][HEADLINE]}, "
                f"{ms_per_frame:.1f} ms/frame ({job['threads']} threads)")
    return run


def _worker_run(job: dict, queue) -> dict:
    """run_model in a worker process, reporting each finished epoch as (model, seed, epoch) on `queue`."""
    return run_model(job, progress=lambda epoch: queue.put((job["model"], job["seed"], epoch)))


@contextlib.contextmanager
def _environment(**variables: str):
    """Set environment variables for the processes started inside the block, then restore them."""
    saved = {name: os.environ.get(name) for name in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def run_jobs(jobs: list[dict], parallel: int, logger) -> list[dict]:
    """Run every job (in order, `parallel` at once in worker processes, or in this process when 1); one tqdm bar
    counts the epochs of all of them. Returns their run entries in job order."""
    total = sum(int(job["cfg"].OPTIMIZATION.NUM_EPOCHS) for job in jobs)
    if parallel <= 1:
        return [run_model(job) for job in jobs]
    context = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch thread pools
    pool = ProcessPoolExecutor(parallel, mp_context=context, initializer=exit_with_parent)  # ends with this one
    with context.Manager() as manager, pool, \
            tqdm.tqdm(total=total, desc=f"training ({parallel} at once)", unit="epoch", dynamic_ncols=True) as bar:
        queue = manager.Queue()
        with _environment(TQDM_DISABLE="1"):  # workers start on submit; their bars stay off (this one counts)
            futures = {pool.submit(_worker_run, job, queue): index for index, job in enumerate(jobs)}
        runs: list[dict | None] = [None] * len(jobs)
        pending = set(futures)
        while pending:
            done = {future for future in pending if future.done()}
            while not queue.empty():
                model, seed, epoch = queue.get()
                bar.set_postfix_str(f"{model} seed {seed} epoch {epoch}")
                bar.update()
            for future in done:
                job = jobs[futures[future]]
                runs[futures[future]] = future.result()  # a worker's exception is raised here
                logger.info(f"{job['model']} seed {job['seed']}: {HEADLINE} "
                            f"{runs[futures[future]]['metrics'][HEADLINE]:.4f} (log: {job['run_dir']}/log.txt)")
            pending -= done
            time.sleep(0.2)
    return runs


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
    """Points of the AP-vs-time figure: the models of this run and tools/benchmark_model.py's configurations."""
    shared = f" ({results['jobs']} models sharing the cores)" if results.get("jobs", 1) > 1 else ""
    entries = [{"name": name, "ms_per_frame": model["mean"]["ms_per_frame"], "ap": model["mean"][HEADLINE],
                "group": f"this run{shared}"} for name, model in results["models"].items()]
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
    """The figures of the report from the first seed's saved predictions and training curves; fills
    results['figures'] and results['example_frames']."""
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
    plot_training_curves(out / "training_curves.png", {name: run["curve"] for name, run in runs.items()})
    results["figures"] = {"examples": "fig3_examples.png", "pr_curves": "pr_curves.png",
                          "ap_vs_time": "ap_vs_time.png", "training_curves": "training_curves.png"}
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


def default_jobs() -> int:
    """Models trained at once: on a CPU the five models of a seed, one thread each (two cores train five one-thread
    processes at 95 % of the throughput of two, measured, and no core idles while a last model trains alone);
    one on a GPU."""
    return 1 if torch.cuda.is_available() else max(available_cores(), len(RUNS))


def reproduce(profile: str, seeds: int, out: Path, data_root: Path | None = None, workers: int = 0,
              command: str = "", set_cfgs: list[str] | None = None, jobs: int | None = None) -> dict:
    """Run the whole reproduction (module docstring) and return the results dict written to out/results.json."""
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile '{profile}'; use one of {', '.join(PROFILES)}")
    if seeds < 1:
        raise ConfigError(f"--seeds must be >= 1, got {seeds}")
    jobs = default_jobs() if jobs is None else jobs
    if jobs < 1:
        raise ConfigError(f"--jobs must be >= 1, got {jobs}")
    if workers < 0:
        raise ConfigError(f"--workers must be >= 0 (0: load data in the training process), got {workers}")
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    cfgs = {model: model_config(model, profile, data_root, set_cfgs) for model in RUNS}
    needed = frames_needed(cfgs)
    refuse_overlap(out, [source.root for source in needed.values()], "--out")
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "reproduce_log.txt")
    clock = StageClock(logger)

    for source in needed.values():  # 1. data
        with clock(f"data: {source.name}"):
            prepare_domain(source, logger)
    with clock("infos"):  # 2. info files and gt databases
        infos = {name: create_domain_infos(source) for name, source in needed.items()}

    test = cfgs[MODELS[0]].DATA_CONFIG.TEST_SOURCE.NAME  # 3. train and evaluate M1-M4 and the oracle
    test_layout = KittiLayout(needed[test].root)
    gt_dir, velodyne_dir = test_layout.training / "label_2", test_layout.training / "velodyne"
    parallel = min(jobs, seeds * len(RUNS))
    todo = [{"model": model, "seed": seed, "cfg": cfg, "run_dir": out / "models" / model / f"seed_{seed}",
             "gt_dir": gt_dir, "out": out, "workers": workers,
             "threads": max(1, available_cores() // parallel)} for seed in range(seeds) for model, cfg in cfgs.items()]
    with clock(f"train and evaluate {len(todo)} models ({parallel} at once)"):
        finished = run_jobs(todo, parallel, logger)
    runs: dict[str, list[dict]] = {model: [] for model in RUNS}
    for job, run in zip(todo, finished):
        runs[job["model"]].append(run)

    results = {  # 4. report
        "profile": profile, "overrides": list(set_cfgs or []), "seeds": list(range(seeds)), "command": command,
        "date": started.isoformat(timespec="seconds"), "jobs": parallel,
        "environment": environment(), "test_domain": test,
        "data": {name: {"path": str(needed[name].root), "frames": len(domain_infos), "domain": needed[name].domain,
                        "seed": needed[name].seed, "boxes": sum(len(info["annos"]["name"]) for info in domain_infos)}
                 for name, domain_infos in infos.items()},
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
                        help="sizes and epochs: smoke (seconds), quick (2-core CPU, ~25 min), paper (GPU)")
    parser.add_argument("--seeds", type=int, default=1, help="training seeds 0..K-1; the report gives mean and std")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/reproduce/<profile>)")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder of the data sources (default: the cfgs' DATA_PATH, data/memslidar)")
    parser.add_argument("--jobs", type=int, default=None,
                        help="models trained at once, each in its own process (default on a CPU: the five models of "
                             "a seed, or one per core if more; 1 on a GPU)")
    parser.add_argument("--workers", type=int, default=0,
                        help="data loader worker processes per model (0: in the training process, best on a CPU)")
    parser.add_argument("--set", dest="set_cfgs", default=None, nargs=argparse.REMAINDER,
                        help="overrides of all model configs: KEY.SUB VALUE ... (after the profile)")


def run(args: argparse.Namespace) -> int:
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "reproduce" / args.profile
    data_root = args.data_root.resolve() if args.data_root is not None else None
    command = " ".join(["memslidar reproduce", f"--profile {args.profile}", f"--seeds {args.seeds}",
                        *([f"--out {args.out}"] if args.out else []),
                        *([f"--data-root {args.data_root}"] if args.data_root else []),
                        *([f"--jobs {args.jobs}"] if args.jobs else []),
                        *(["--set", *args.set_cfgs] if args.set_cfgs else [])])
    results = reproduce(args.profile, args.seeds, out.resolve(), data_root, args.workers, command, args.set_cfgs,
                        args.jobs)
    for model, entry in results["models"].items():
        print(f"{model}: {HEADLINE} {entry['mean'][HEADLINE]}  ms/frame {entry['mean']['ms_per_frame']:.1f}")
    print(f"report: {out / 'report.md'}")
    return 0
