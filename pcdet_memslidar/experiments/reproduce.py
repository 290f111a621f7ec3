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
4. AP of the saved prediction labels against the industrial ground truth with bootstrap intervals over the test
   frames, figures, results.json and report.md in the output folder (experiments.results, experiments.report);
5. the untouched seed: every run's final checkpoint also predicts an industrial split simulated with
   FINAL_TEST_SEED (<DATA_PATH>/<test>_final), scored for one table of the report and nothing else: no selection
   rule, tool or analysis reads it (a test split that is looked at while choosing settings stops being unseen).
Profiles (cfgs' PROFILES) change sizes, epochs, the grid and how many test frames are simulated
(DATA_CONFIG.TEST_SOURCE.COUNT); the test split is every frame of the test domain's folder.
"""
from __future__ import annotations

import copy
import datetime
import time
from pathlib import Path

from easydict import EasyDict

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
from pcdet_memslidar.experiments.report import write_report
from pcdet_memslidar.experiments.results import add_figures, add_intervals, environment, model_entry, score_run
from pcdet_memslidar.experiments.runs import StageClock, check_run_options, run_jobs, runs_at_once, training_jobs
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models.detector import DENSE_HEADS
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.eval_loop import prediction_folder
from pcdet_memslidar.runtime.predict import predict
from pcdet_memslidar.runtime.pretrain import split_stages
from pcdet_memslidar.runtime.train import final_checkpoint
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import SETTINGS_FILE, simulate_dataset
from pcdet_memslidar.utils.atomic import refuse_overlap

MODELS = ("M1", "M2", "M3", "M4")
ORACLE = "oracle"  # trained in-domain: the ceiling of what a mix can reach on the industrial split
RUNS = (*MODELS, ORACLE)  # what the reproduction trains unless told otherwise
FINETUNED = "M5"  # pre-trained on sim, fine-tuned on real at M3's compute (cfgs/m5.yaml): a question of the paper's
KNOWN_RUNS = (*MODELS, FINETUNED, ORACLE)  # in Table 3's order
FINAL_TEST_SEED = 2026  # the untouched test split's simulation seed (stage 5); the usual test split is seed 0
PAPER_HEAD = "anchor"  # SECOND's, the head cfgs/m1.yaml ... oracle.yaml are written for


def head_configs() -> dict[str, Path]:
    """The heads a reproduction trains: the short_name of each registered dense head (models.detector.DENSE_HEADS)
    that has a model_config -> that model config, which gives the experiment configs their MODEL."""
    return {head.short_name: CONFIG_DIR / head.model_config for head in DENSE_HEADS.values()
            if getattr(head, "model_config", None)}


def run_id(model: str, head: str) -> str:
    """The name of `model` (of KNOWN_RUNS) trained with `head` (of head_configs()) in results and output folders:
    'M3' with the paper's anchor head, 'M3-center' with the center head."""
    return model if head == PAPER_HEAD else f"{model}-{head}"


def model_config(model: str, profile: str, data_root: Path | None, set_cfgs: list[str] | None = None,
                 head: str = PAPER_HEAD):
    """The experiment config cfgs/<model>.yaml (for a head other than the paper's with the MODEL of its model
    config, head_configs()) with `profile` applied, then DATA_PATH = data_root (if given) and the --set overrides
    [KEY, VALUE, ...] (checked at load: grid, batch size, epochs, lr)."""
    overrides = (["DATA_CONFIG.DATA_PATH", str(data_root)] if data_root is not None else []) + list(set_cfgs or [])
    return load_config(CONFIG_DIR / f"{model.lower()}.yaml", overrides, profile=profile,
                       model_config=None if head == PAPER_HEAD else head_configs()[head])


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


def is_imported(source: Source) -> bool:
    """Whether the source's folder holds frames that were not simulated (imported recordings: no simulation.json)."""
    return bool(KittiLayout(source.root).frame_ids()) and not (source.root / SETTINGS_FILE).is_file()


def prepare_domain(source: Source, logger) -> None:
    """Simulate frames 0..count-1 of a bundled domain into the source's folder (complete frames are kept), unless
    the folder holds imported recordings (is_imported): those are used as they are."""
    if is_imported(source):
        logger.info(f"{source.name}: using the {len(KittiLayout(source.root).frame_ids())} frames in {source.root} "
                    f"as they are (no {SETTINGS_FILE}: not simulated)")
        return
    simulate_dataset(get_domain(source.domain), source.count, source.root, seed=source.seed)


def final_test_source(test: Source) -> Source | None:
    """The untouched test split (stage 5): the test source's domain simulated with FINAL_TEST_SEED, as many frames,
    in a folder beside it; None where the test split is not simulated (imported recordings have no other seed)."""
    if test.domain not in BUNDLED_DOMAINS or is_imported(test):
        return None
    name = f"{test.name}_final"
    return Source(name, test.root.with_name(name), test.count, test.domain, FINAL_TEST_SEED)


def score_final_test(jobs: list[dict], final: Source, out: Path, logger) -> dict[str, list[dict]]:
    """Stage 5: {model: [run entry per seed: metrics of the final checkpoint on the untouched split, predictions]}."""
    gt_dir = KittiLayout(final.root).training / "label_2"
    runs: dict[str, list[dict]] = {}
    for job in jobs:
        cfg = copy.deepcopy(job["cfg"])
        cfg.DATA_CONFIG.TEST_SOURCE = EasyDict({"NAME": final.name, "PATH": str(final.root), "DOMAIN": final.domain,
                                                "SEED": final.seed, "COUNT": None})
        result_dir = Path(job["run_dir"]) / "final_test"
        predict(cfg, final_checkpoint(cfg, job["run_dir"]), result_dir, logger)
        pred_dir = prediction_folder(result_dir) / final.name
        runs.setdefault(job["model"], []).append(
            {"seed": job["seed"], **score_run(gt_dir, pred_dir), "predictions": str(pred_dir.relative_to(out))})
    return runs


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


def reproduce(profile: str, seeds: int, out: Path, data_root: Path | None = None, workers: int = 0,
              command: str = "", set_cfgs: list[str] | None = None, jobs: int | None = None,
              benchmark_file: Path | None = None, models: tuple[str, ...] = RUNS,
              heads: tuple[str, ...] = (PAPER_HEAD,)) -> dict:
    """Run the whole reproduction (module docstring) of `models` (of KNOWN_RUNS), each with every head of `heads`
    (of head_configs(); runs named by run_id), and return the results dict written to out/results.json.
    benchmark_file: tools/benchmark_model.py's results, drawn beside this run's models in the AP-vs-time figure when
    it exists."""
    unknown = [model for model in models if model not in KNOWN_RUNS]
    if unknown or not models:
        raise ConfigError(f"--models {' '.join(models)}: choose from {' '.join(KNOWN_RUNS)}")
    known_heads = head_configs()
    if not heads or any(head not in known_heads for head in heads):
        raise ConfigError(f"--heads {' '.join(heads)}: choose from {' '.join(known_heads)}")
    models = tuple(model for model in KNOWN_RUNS if model in models)
    heads = tuple(head for head in known_heads if head in heads)
    jobs = check_run_options(seeds, jobs, workers, len(models) * len(heads))
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    planned = [(run_id(model, head), model, head) for head in heads for model in models]
    bases = {name: model for name, model, _ in planned}  # run id -> M1 ... oracle
    cfgs = {name: model_config(model, profile, data_root, set_cfgs, head) for name, model, head in planned}
    needed = frames_needed(cfgs)
    test = next(iter(cfgs.values())).DATA_CONFIG.TEST_SOURCE.NAME
    final = final_test_source(needed[test])
    if final is not None:
        needed[final.name] = final
    refuse_overlap(out, [source.root for source in needed.values()], "--out")
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "reproduce_log.txt")
    clock = StageClock(logger)

    infos = prepare_data(needed, clock, logger)  # 1. data, 2. infos

    test_layout = KittiLayout(needed[test].root)  # 3. train and evaluate M1-M4 and the oracle
    gt_dir, velodyne_dir = test_layout.training / "label_2", test_layout.training / "velodyne"
    parallel = runs_at_once(seeds * len(cfgs), jobs)
    todo = training_jobs(cfgs, seeds, out / "models", gt_dir, out, workers, parallel)
    with clock(f"train and evaluate {len(todo)} models ({parallel} at once)"):
        finished = run_jobs(todo, parallel, logger)
    runs: dict[str, list[dict]] = {name: [] for name in cfgs}
    for job, run in zip(todo, finished):
        runs[job["model"]].append(run)

    results = {  # 4. report
        "profile": profile, "profile_settings": profile_settings(next(iter(cfgs.values()))),
        "overrides": list(set_cfgs or []), "seeds": list(range(seeds)), "heads": list(heads), "command": command,
        "date": started.isoformat(timespec="seconds"), "jobs": parallel,
        "environment": environment(), "test_domain": test,
        "data": {name: {"path": str(needed[name].root), "frames": len(domain_infos), "domain": needed[name].domain,
                        "seed": needed[name].seed, "boxes": sum(len(info["annos"]["name"]) for info in domain_infos)}
                 for name, domain_infos in infos.items()},
        "models": {model: model_entry(str(Path(cfgs[model].CFG_FILE).relative_to(CONFIG_DIR.parent)),
                                      table2_counts(cfgs[model]), model_runs, cfgs[model].MODEL.NAME,
                                      bases[model])
                   for model, model_runs in runs.items()},
    }
    with clock("figures"):
        add_figures(results, {model: model_runs[0] for model, model_runs in runs.items()}, gt_dir, velodyne_dir, out,
                    benchmark_file)
        add_intervals(results, gt_dir, out)
    if final is not None:  # 5. the untouched seed
        with clock("untouched test seed"):
            final_runs = score_final_test(todo, final, out, logger)
            results["final_test"] = {
                "test_domain": final.domain, "seed": final.seed, "path": str(final.root), "seeds": results["seeds"],
                "models": {name: model_entry(entry["cfg"], entry["counts"], final_runs[name], entry["detector"],
                                             entry["model"]) for name, entry in results["models"].items()}}
            (out / "final_test").mkdir(exist_ok=True)
            add_intervals(results["final_test"], KittiLayout(final.root).training / "label_2", out,
                          figure_dir=out / "final_test")
    results["stages"] = clock.seconds
    results["wall_seconds"] = time.perf_counter() - wall_start
    report_path, json_path = write_report(results, out)
    logger.info(f"report: {report_path}; results: {json_path}")
    return results
