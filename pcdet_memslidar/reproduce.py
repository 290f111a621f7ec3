"""`memslidar reproduce`: the paper's M1-M4 experiment end to end, one call.

The story, one stage per line (each stage's wall time goes into the report):
1. data: simulate the frames the profile needs of every source (cached: the simulator skips complete frames and
   refuses a folder made with other settings); a folder holding imported recordings (frames but no
   simulation.json) is used as it is, so real data replaces a simulated stand-in;
2. infos: info files and ground-truth databases of each source (rebuilt only when the frames changed);
3. per seed, M1-M4 (cfgs/m1.yaml ... m4.yaml, the same SECOND and hyper-parameters, Table 2 mixes) and the oracle
   (cfgs/oracle.yaml: industrial frames of another simulation seed, the same budget), and on request M5
   (cfgs/m5.yaml: pre-trained on sim, fine-tuned on real, at M3's compute): runtime.train with the validation AP
   of every epoch (resumes from the newest checkpoint; a finished model is read back from its run.json), then
   runtime.predict over the industrial split, saved as KITTI labels with scores. `jobs` models train at once, each
   in its own process on its share of the cores: on a CPU the sparse convolutions use one thread, so several
   one-thread trainings make better use of the cores than one training on all of them;
4. AP of the saved prediction labels against the industrial ground truth, figures, results.json and report.md in
   the output folder (evaluation.report).
Profiles (cfgs' PROFILES) change sizes, epochs, the grid and how many test frames are simulated
(DATA_CONFIG.TEST_SOURCE.COUNT); the test split is every frame of the test domain's folder.
"""
from __future__ import annotations

import contextlib
import datetime
import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

from pcdet_memslidar.config import CONFIG_DIR, load_config, profile_settings
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import (
    BUNDLED_DOMAINS,
    Source,
    check_count,
    resolve_sources,
    source_split,
    split_sources,
)
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.report import (
    HEADLINE,
    add_figures,
    environment,
    json_safe,
    model_entry,
    score_run,
    write_report,
)
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.eval_loop import prediction_folder
from pcdet_memslidar.runtime.predict import predict
from pcdet_memslidar.runtime.pretrain import split_stages
from pcdet_memslidar.runtime.train import train
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import SETTINGS_FILE, simulate_dataset
from pcdet_memslidar.utils.atomic import refuse_overlap, write_text
from pcdet_memslidar.utils.cores import available_cores
from pcdet_memslidar.utils.processes import exit_with_parent
from pcdet_memslidar.utils.progress import progress_bar

MODELS = ("M1", "M2", "M3", "M4")
ORACLE = "oracle"  # trained in-domain: the ceiling of what a mix can reach on the industrial split
RUNS = (*MODELS, ORACLE)  # what the reproduction trains unless told otherwise
FINETUNED = "M5"  # pre-trained on sim, fine-tuned on real at M3's compute (cfgs/m5.yaml): a question of the paper's
KNOWN_RUNS = (*MODELS, FINETUNED, ORACLE)  # in Table 3's order
RUN_CONFIG = "config.json"  # the config a run folder's checkpoints were trained with
CURVE_FILE = "curve.json"  # per epoch: training loss, validation AP, training minutes
RUN_FILE = "run.json"  # a finished run's entry (its scores on the test split), read back instead of run again


def model_config(model: str, profile: str, data_root: Path | None, set_cfgs: list[str] | None = None):
    """The experiment config cfgs/<model>.yaml with `profile` applied, then DATA_PATH = data_root (if given) and
    the --set overrides [KEY, VALUE, ...] (checked at load: grid, batch size, epochs, lr)."""
    overrides = (["DATA_CONFIG.DATA_PATH", str(data_root)] if data_root is not None else []) + list(set_cfgs or [])
    return load_config(CONFIG_DIR / f"{model.lower()}.yaml", overrides, profile=profile)


def frames_needed(cfgs: dict) -> dict[str, Source]:
    """{source name: the source with count = frames needed}: the largest count any model's mix takes of each
    source, and the test source's TEST_SOURCE.COUNT (null: its site file's number of frames, or None for a
    domain that is not simulated: the frames its folder holds)."""
    needed: dict[str, Source] = {}

    def need(source: Source, count: int | None) -> None:
        known = needed.get(source.name)
        if known is not None and (known.root, known.domain, known.seed) != (source.root, source.domain, source.seed):
            raise ConfigError(f"source '{source.name}' is read from {known.root} ({known.domain}, seed {known.seed}) "
                              f"and from {source.root} ({source.domain}, seed {source.seed}): give one of them "
                              f"another NAME")
        counts = [value for value in (count, known.count if known else None) if value is not None]
        needed[source.name] = Source(source.name, source.root, max(counts) if counts else None, source.domain,
                                     source.seed)

    for cfg in cfgs.values():
        for stage in filter(None, split_stages(cfg)):  # a pre-training stage reads its own sources (M5)
            for source in resolve_sources(stage.DATA_CONFIG.MIX, Path(cfg.DATA_CONFIG.DATA_PATH)):
                need(source, source.count)
        test, = split_sources(cfg.DATA_CONFIG, "test", Path(cfg.DATA_CONFIG.DATA_PATH))
        count = check_count(cfg.DATA_CONFIG.TEST_SOURCE.get("COUNT"), "DATA_CONFIG.TEST_SOURCE.COUNT")
        preset = count is None and test.domain in BUNDLED_DOMAINS
        need(test, get_domain(test.domain).default_frames if preset else count)
    return {name: source for name, source in needed.items() if source.count != 0}


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


def prepare_data(needed: dict[str, Source], clock, logger) -> dict[str, list[dict]]:
    """Stages 1 and 2 for the sources `needed` (frames_needed): their frames (prepare_domain), then their info files
    and ground-truth databases (rebuilt only when the frames changed); returns {source name: infos}."""
    for source in needed.values():
        with clock(f"data: {source.name}"):
            prepare_domain(source, logger)
    with clock("infos"):
        return {name: create_domain_infos(source) for name, source in needed.items()}


def table2_counts(cfg) -> dict[str, dict[str, int]]:
    """{source: {frames, train, val}} of a model's training set (Table 2 as built); a pre-training stage's sources
    (M5) as '<source> (pre-training)'."""
    counts = {}
    pretraining, training = split_stages(cfg)
    for stage, suffix in ((pretraining, " (pre-training)"), (training, "")):
        for source in resolve_sources(stage.DATA_CONFIG.MIX, Path(cfg.DATA_CONFIG.DATA_PATH)) if stage else []:
            frame_ids = KittiLayout(source.root).frame_ids() if source.count else []
            parts = {split: len(source_split(source, frame_ids, split, stage.DATA_CONFIG, source.root))
                     for split in ("train", "val")}
            counts[source.name + suffix] = {"frames": source.count, **parts}
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


def train_detector(cfg, run_dir: Path, seed: int, workers: int, logger, progress=None,
                   every_epoch: bool = True) -> Path:
    """runtime.train of cfg into run_dir (a run folder of another config is refused), with the loss and the AP on
    the mix's validation split after every epoch (every_epoch False: the AP after the last epoch only) in
    run_dir/curve.json; returns the final checkpoint. progress(epoch) is called after each epoch (and then the
    training logs lines instead of drawing bars)."""
    check_run_config(cfg, run_dir)
    curve = read_curve(run_dir)

    def record(epoch: int, mean_loss: float, val: dict, seconds: float) -> None:
        curve[:] = [entry for entry in curve if entry["epoch"] < epoch]  # entries of epochs trained again go
        minutes = (curve[-1]["minutes"] if curve else 0.0) + seconds / 60
        curve.append({"epoch": epoch, "minutes": round(minutes, 3), "loss": mean_loss,
                      "val_AP3D_R40": val and val["AP3D_R40"], "val_APBEV_R40": val and val["APBEV_R40"]})
        write_text(run_dir / CURVE_FILE, json.dumps(curve, indent=1) + "\n")
        if progress is not None:
            progress(epoch)

    val_interval = 1 if every_epoch else int(cfg.OPTIMIZATION.NUM_EPOCHS)
    return train(cfg, run_dir, logger, seed=seed, workers=workers, on_epoch=record, val_interval=val_interval,
                 use_tqdm_to_record=progress is not None)


def run_model(job: dict, progress=None) -> dict:
    """Train and test one (model, seed) job {model, seed, cfg, run_dir, gt_dir, out, workers, threads,
    every_epoch (validate after every epoch, else after the last)}; returns
    its run entry, also kept in run_dir/run.json: a finished run of the same config is read back from there. Runs
    in the calling process or in a worker process of `reproduce` (then it logs to run_dir/log.txt only, and
    progress(epoch) reports its epochs)."""
    torch.set_num_threads(job["threads"])
    cfg, run_dir = job["cfg"], Path(job["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    check_run_config(cfg, run_dir)
    if (run_dir / RUN_FILE).is_file():
        run = json.loads((run_dir / RUN_FILE).read_text())
        for entry in run["curve"] if progress is not None else []:
            progress(entry["epoch"])
        return run
    logger = create_logger(run_dir / "log.txt", name=f"pcdet_memslidar.{job['model']}.{job['seed']}",
                           console=progress is None)
    started = time.perf_counter()
    checkpoint = train_detector(cfg, run_dir, job["seed"], job["workers"], logger, progress, job["every_epoch"])
    trained = time.perf_counter()
    result = predict(cfg, checkpoint, run_dir / "eval", logger, workers=job["workers"])
    pred_dir = prediction_folder(run_dir / "eval") / cfg.DATA_CONFIG.TEST_SOURCE.NAME
    ms_per_frame = float(result["infer_time_ms"])
    run = {"seed": job["seed"], **score_run(Path(job["gt_dir"]), pred_dir),
           "predictions": str(pred_dir.relative_to(job["out"])), "curve": read_curve(run_dir),
           "seconds": {"train": trained - started, "evaluate": time.perf_counter() - trained},
           "threads": job["threads"]}
    run["metrics"]["ms_per_frame"] = ms_per_frame
    logger.info(f"{job['model']} seed {job['seed']}: {HEADLINE} {run['metrics'][HEADLINE]}, "
                f"{ms_per_frame:.1f} ms/frame ({job['threads']} threads)")
    run = json_safe(run)
    write_text(run_dir / RUN_FILE, json.dumps(run, indent=1) + "\n")
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
    """Run every job (in order, `parallel` at once in worker processes, or in this process when 1); one progress bar
    (or, off a terminal, one log line per epoch) counts the epochs of all of them. Returns their run entries in job
    order."""
    total = sum(int(job["cfg"].OPTIMIZATION.NUM_EPOCHS) for job in jobs)
    if parallel <= 1:
        return [run_model(job) for job in jobs]
    context = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch thread pools
    pool = ProcessPoolExecutor(parallel, mp_context=context, initializer=exit_with_parent)  # ends with this one
    with context.Manager() as manager, pool, \
            progress_bar(total=total, desc=f"training ({parallel} at once)", unit="epoch") as bar:
        queue = manager.Queue()
        with _environment(TQDM_DISABLE="1"):  # workers start on submit; their bars stay off (this one counts)
            futures = {pool.submit(_worker_run, job, queue): index for index, job in enumerate(jobs)}
        runs: list[dict | None] = [None] * len(jobs)
        pending, epochs_done = set(futures), 0
        while pending:
            done = {future for future in pending if future.done()}
            while not queue.empty():
                model, seed, epoch = queue.get()
                epochs_done += 1
                bar.set_postfix_str(f"{model} seed {seed} epoch {epoch}")
                bar.update()
                if bar.disable:  # no bar (a log file or a pipe): one line per epoch instead
                    logger.info(f"{model} seed {seed}: epoch {epoch} done ({epochs_done}/{total} epochs of all models)")
            for future in done:
                job = jobs[futures[future]]
                runs[futures[future]] = future.result()  # a worker's exception is raised here
                logger.info(f"{job['model']} seed {job['seed']}: {HEADLINE} "
                            f"{runs[futures[future]]['metrics'][HEADLINE]:.4f} (log: {job['run_dir']}/log.txt)")
            pending -= done
            time.sleep(0.2)
    return runs


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


def default_jobs(models: int = len(RUNS)) -> int:
    """Models trained at once: on a CPU the `models` models of a seed, one thread each (two cores train five
    one-thread processes at 95 % of the throughput of two, measured, and no core idles while a last model trains
    alone); one on a GPU."""
    return 1 if torch.cuda.is_available() else max(available_cores(), models)


def runs_at_once(runs: int, jobs: int) -> int:
    """How many of `runs` equal runs to train at once, at most `jobs`: the fewest per wave that still takes the
    ceil(runs / jobs) waves, so the last wave is as full as the others (11 runs, 5 jobs: 4 + 4 + 3 rather than
    5 + 5 + 1, where one run would train alone on one core while the others idle)."""
    waves = math.ceil(runs / jobs)
    return math.ceil(runs / waves)


def check_run_options(seeds: int, jobs: int | None, workers: int, models: int) -> int:
    """The number of runs to train at once (`jobs`; None: default_jobs(models)) after checking --seeds, --jobs and
    --workers; ConfigError naming the option and its value otherwise."""
    if seeds < 1:
        raise ConfigError(f"--seeds must be >= 1, got {seeds}")
    jobs = default_jobs(models) if jobs is None else jobs
    if jobs < 1:
        raise ConfigError(f"--jobs must be >= 1, got {jobs}")
    if workers < 0:
        raise ConfigError(f"--workers must be >= 0 (0: load data in the training process), got {workers}")
    return jobs


def training_jobs(cfgs: dict, seeds: int, runs_dir: Path, gt_dir: Path, out: Path, workers: int,
                  parallel: int, every_epoch: bool = True) -> list[dict]:
    """run_jobs' jobs: every config of cfgs {name: cfg} for seeds 0..seeds-1, seed by seed, each in
    runs_dir/<name>/seed_<k> on its share of the cores (`parallel` runs at once), validated after every epoch
    (every_epoch) or after the last one only."""
    return [{"model": name, "seed": seed, "cfg": cfg, "run_dir": runs_dir / name / f"seed_{seed}", "gt_dir": gt_dir,
             "out": out, "workers": workers, "threads": max(1, available_cores() // parallel),
             "every_epoch": every_epoch}
            for seed in range(seeds) for name, cfg in cfgs.items()]


def reproduce(profile: str, seeds: int, out: Path, data_root: Path | None = None, workers: int = 0,
              command: str = "", set_cfgs: list[str] | None = None, jobs: int | None = None,
              benchmark_file: Path | None = None, models: tuple[str, ...] = RUNS) -> dict:
    """Run the whole reproduction (module docstring) of `models` (of KNOWN_RUNS) and return the results dict written
    to out/results.json. benchmark_file: tools/benchmark_model.py's results, drawn beside this run's models in the
    AP-vs-time figure when it exists."""
    unknown = [model for model in models if model not in KNOWN_RUNS]
    if unknown or not models:
        raise ConfigError(f"--models {' '.join(models)}: choose from {' '.join(KNOWN_RUNS)}")
    models = tuple(model for model in KNOWN_RUNS if model in models)
    jobs = check_run_options(seeds, jobs, workers, len(models))
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    cfgs = {model: model_config(model, profile, data_root, set_cfgs) for model in models}
    needed = frames_needed(cfgs)
    refuse_overlap(out, [source.root for source in needed.values()], "--out")
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "reproduce_log.txt")
    clock = StageClock(logger)

    infos = prepare_data(needed, clock, logger)  # 1. data, 2. infos

    test = next(iter(cfgs.values())).DATA_CONFIG.TEST_SOURCE.NAME  # 3. train and evaluate M1-M4 and the oracle
    test_layout = KittiLayout(needed[test].root)
    gt_dir, velodyne_dir = test_layout.training / "label_2", test_layout.training / "velodyne"
    parallel = runs_at_once(seeds * len(models), jobs)
    todo = training_jobs(cfgs, seeds, out / "models", gt_dir, out, workers, parallel)
    with clock(f"train and evaluate {len(todo)} models ({parallel} at once)"):
        finished = run_jobs(todo, parallel, logger)
    runs: dict[str, list[dict]] = {model: [] for model in models}
    for job, run in zip(todo, finished):
        runs[job["model"]].append(run)

    results = {  # 4. report
        "profile": profile, "profile_settings": profile_settings(next(iter(cfgs.values()))),
        "overrides": list(set_cfgs or []), "seeds": list(range(seeds)), "command": command,
        "date": started.isoformat(timespec="seconds"), "jobs": parallel,
        "environment": environment(), "test_domain": test,
        "data": {name: {"path": str(needed[name].root), "frames": len(domain_infos), "domain": needed[name].domain,
                        "seed": needed[name].seed, "boxes": sum(len(info["annos"]["name"]) for info in domain_infos)}
                 for name, domain_infos in infos.items()},
        "models": {model: model_entry(str(Path(cfgs[model].CFG_FILE).relative_to(CONFIG_DIR.parent)),
                                      table2_counts(cfgs[model]), model_runs) for model, model_runs in runs.items()},
    }
    with clock("figures"):
        add_figures(results, {model: model_runs[0] for model, model_runs in runs.items()}, gt_dir, velodyne_dir, out,
                    benchmark_file)
    results["stages"] = clock.seconds
    results["wall_seconds"] = time.perf_counter() - wall_start
    report_path, json_path = write_report(results, out)
    logger.info(f"report: {report_path}; results: {json_path}")
    return results
