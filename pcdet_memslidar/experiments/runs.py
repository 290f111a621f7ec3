"""Training runs: one (config, seed) trained, tested on the test split and scored into its run folder, and many at
once in worker processes with one progress bar; the stage clock of an experiment's log. Used by every experiment
(reproduce, sweeps, site_detector) and tools/benchmark_model.py.

A run folder <runs>/<name>/seed_<k> holds config.json (the config its checkpoints come from; another config is
refused), curve.json (loss and validation AP per epoch), ckpt/, eval/ (predictions on the test split) and, once
finished, run.json (its scores), which is read back instead of training again.
"""
from __future__ import annotations

import contextlib
import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.experiments.results import HEADLINE, json_safe, score_run
from pcdet_memslidar.models import is_learned
from pcdet_memslidar.policy import apply_process_policy, thread_share
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.eval_loop import prediction_folder
from pcdet_memslidar.runtime.experiment import Process, local_process
from pcdet_memslidar.runtime.predict import predict
from pcdet_memslidar.runtime.train import train
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores
from pcdet_memslidar.utils.processes import exit_with_parent
from pcdet_memslidar.utils.progress import progress_bar

RUN_CONFIG = "config.json"  # the config a run folder's checkpoints were trained with
CURVE_FILE = "curve.json"  # per epoch: training loss, validation AP, training minutes
RUN_FILE = "run.json"  # a finished run's entry (its scores on the test split), read back instead of run again


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
                   every_epoch: bool = True, process: Process | None = None) -> Path:
    """runtime.train of cfg into run_dir (a run folder of another config is refused) in `process` (default: this
    process alone), with the loss and the AP on the mix's validation split after every epoch (every_epoch False: the
    AP after the last epoch only) in run_dir/curve.json; returns the final checkpoint. progress(epoch) is called after
    each epoch (and then the training logs lines instead of drawing bars)."""
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
    return train(cfg, run_dir, logger, process, seed=seed, workers=workers, on_epoch=record,
                 val_interval=val_interval, use_tqdm_to_record=progress is not None)


def run_model(job: dict, progress=None) -> dict:
    """Train and test one (model, seed) job {model, seed, cfg, run_dir, gt_dir, out, workers, threads,
    every_epoch (validate after every epoch, else after the last)}; returns
    its run entry, also kept in run_dir/run.json: a finished run of the same config is read back from there (its
    entry then says read_back: True). Runs in the calling process or in a worker process of `reproduce` (then it
    logs to run_dir/log.txt only, and progress(epoch) reports its epochs). The process runs on job["threads"] torch
    threads, with their execution policy."""
    process = local_process(job["threads"])
    cfg, run_dir = job["cfg"], Path(job["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    learned = is_learned(cfg.MODEL)  # a detector without weights is only tested, again whenever asked: it is cheap
    if learned:
        check_run_config(cfg, run_dir)
    if learned and (run_dir / RUN_FILE).is_file():
        run = json.loads((run_dir / RUN_FILE).read_text())
        for entry in run["curve"] if progress is not None else []:
            progress(entry["epoch"])
        return {**run, "read_back": True}  # the report's wall time then says it covers no training of this run
    logger = create_logger(run_dir / "log.txt", name=f"pcdet_memslidar.{job['model']}.{job['seed']}",
                           console=progress is None)
    started = time.perf_counter()
    checkpoint = (train_detector(cfg, run_dir, job["seed"], job["workers"], logger, progress, job["every_epoch"],
                                 process) if learned else None)
    trained = time.perf_counter()
    result = predict(cfg, checkpoint, run_dir / "eval", logger, process, workers=job["workers"])
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
    apply_process_policy()  # the OpenMP wait hint, in the environment the workers inherit (their libgomp reads it)
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


def default_jobs(models: int) -> int:
    """Models trained at once: on a CPU the `models` models of a seed, one thread each, so that they share the cores
    and no core idles while a last model trains alone (a step's time on one and two threads:
    docs/benchmarks.md#training-speed); one on a GPU."""
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
             "out": out, "workers": workers, "threads": thread_share(parallel),
             "every_epoch": every_epoch}
            for seed in range(seeds) for name, cfg in cfgs.items()]
