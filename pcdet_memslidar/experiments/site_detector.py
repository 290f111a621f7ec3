"""`memslidar site train`: detectors for one site from a recording of it empty, without annotating.

Three detectors (SITE_DETECTORS), side by side on the same frames; the first two unless asked (DEFAULT_DETECTORS):
- `background`: background subtraction (models.background_subtraction), what a site engineer would build;
- `second`: SECOND trained on composited frames, as the bundled models but on the site's own background;
- `second_background`: the same SECOND with each point's background_depth (geometry.background) as a feature.

The story, one stage per line (each stage's wall time goes into the report):
1. (a site with a scene instead of a recording: its empty recording is simulated first, <out>/empty_recording/)
   split the background recording by time: its first frames are backgrounds for training, the last `holdout`
   share is held out (never seen in training); the background model is learned from the training frames only
   (<out>/background.npz);
2. data: people (and distractors: boxes, pallets, carts, a forklift, open doors, posts, never labelled) composited
   into the training backgrounds (`train`), optionally frames of a simulated scene mixed in (`sim`, a share of the
   training frames); on the held-out backgrounds, with other seeds: people (`test`), people in pairs (`pairs`),
   people beside distractors (`test_distractors`), distractors and nobody (`distractors`), and the held-out frames
   as they are (`empty`), all in their ground frame;
3. configs: the shipped SECOND config with the site's grid (grid.fitted_range over the walkable area, for every
   profile) and these sources, one per detector: <out>/site.yaml (second), site_background.yaml,
   site_classical.yaml (what `memslidar detect --cfg` takes); the classical detector's settings are chosen on the
   validation part of `train` (experiments.site_classical);
4. train the learned detectors (one on every core, or two at once, one core each) and test every detector
   (runs.run_model: AP 3D at IoU 0.5 on each composited held-out set, with bootstrap intervals over its frames);
5. false alarms: `memslidar detect` over the empty held-out frames and the distractor frames with each detector and
   each bundled checkpoint given (--compare): detections per frame at the tracker's min_score, confirmed tracks per
   minute, frames per second;
6. figure and report: <out>/report.md, results.json, site_detections.png.
"""
from __future__ import annotations

import copy
import dataclasses
import datetime
import json
import time
from pathlib import Path

import numpy as np
import yaml
from easydict import EasyDict

from pcdet_memslidar.config import CONFIG_DIR, cfg_from_yaml_file, load_config
from pcdet_memslidar.datasets.dataset import BACKGROUND_FEATURE
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import Source, source_counts
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.bootstrap import ap_interval, frame_matches
from pcdet_memslidar.evaluation.figures import plot_frames
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.experiments.report import write_report
from pcdet_memslidar.experiments.results import environment, frame_predictions, json_safe, score_run
from pcdet_memslidar.experiments.runs import RUN_CONFIG, RUN_FILE, StageClock, run_jobs, run_model
from pcdet_memslidar.experiments.site_classical import choose_settings
from pcdet_memslidar.experiments.site_report import render_site_report
from pcdet_memslidar.geometry.background import BackgroundModel
from pcdet_memslidar.grid import fitted_range, xy_cell_multiple
from pcdet_memslidar.io.formats import list_frames
from pcdet_memslidar.io.importer import import_frames
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.models import is_learned
from pcdet_memslidar.monitor.detect import DetectOptions, detect, resolve_format
from pcdet_memslidar.monitor.tracker import TrackerConfig
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.eval_loop import prediction_folder
from pcdet_memslidar.runtime.predict import predict
from pcdet_memslidar.runtime.train import final_checkpoint
from pcdet_memslidar.sim.composite import estimate_background_mount, read_background
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.site import BUNDLED_SITES, Site, get_domain, load_site
from pcdet_memslidar.sim.writer import simulate_dataset, simulate_empty_recording
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores

MODEL_CONFIG = CONFIG_DIR / "memslidar_models" / "second_person.yaml"
SITE_DETECTORS = ("background", "second", "second_background")  # the module docstring's three
# second_background's val AP is second's within the seed spread, for a second training (docs/sites.md)
DEFAULT_DETECTORS = ("background", "second")
SITE_CONFIGS = {"second": "site.yaml", "second_background": "site_background.yaml", "background": "site_classical.yaml"}
FIGURE_DETECTOR = "second"  # the detector the figure shows (where it was trained)
BACKGROUND_FILE = "background.npz"
EMPTY_RECORDING_FRAMES = 20  # frames of a scene site's simulated empty recording (8 s at the paper's 0.4 s)
DISTRACTORS = (1, 3)  # distractors per frame of the held-out distractor sets
TRAIN_DISTRACTORS = (0, 2)  # distractors per training frame, unless the site file sets `distractors`
PEOPLE_SETS = ("test", "pairs", "test_distractors")  # held-out composited sets AP is measured on
NOBODY_SETS = ("empty", "distractors")  # held-out sets without people: every detection is a false alarm
PERSON_MARGIN_M = 0.4  # the grid reaches this far beyond the walkable area (half a person)
Z_RANGES = {"paper": (-0.5, 2.5)}  # z of the shipped paper grid; the profiles' z is theirs
# Augmentations a site detector goes without: pasted people (gt_sampling) keep what they hide and may stand inside
# furniture, where composited ones are ray-cast; a static sensor never sees its site mirrored or turned (and an
# asymmetric room turned about the sensor leaves its grid). Training settings of the quick profile for a site, chosen
# on the validation part of the composited training frames (docs/sites.md, "How the site recipe was chosen").
SITE_DISABLED_AUGMENTATIONS = ["gt_sampling", "random_world_flip", "random_world_rotation"]
SITE_QUICK_OPTIMIZATION = {"LR": 0.0005, "NUM_EPOCHS": 16}
TRACKER_MIN_SCORE = TrackerConfig().min_score  # detections below it are neither tracked nor reported


@dataclasses.dataclass(frozen=True)
class SitePlan:
    """What `site train` makes: frames per set, the split of the background recording, and the share of the
    training frames that come from a simulated site (`sim_site`: a bundled domain or a site file) instead."""

    train_frames: int
    test_frames: int
    holdout: float
    seed: int
    sim_share: float = 0.0
    sim_site: str = "sim"

    def mix(self) -> dict:
        """DATA_CONFIG.MIX of the training frames: the composited `train` source and, with a sim_share, `sim`."""
        if not 0 <= self.sim_share < 1:
            raise ConfigError(f"--sim-share must be at least 0 and below 1 (the share of training frames from "
                              f"--sim-site), got {self.sim_share}")
        sources = [{"NAME": "train", "RATIO": 1.0 - self.sim_share}]
        if self.sim_share:
            sources.append({"NAME": "sim", "RATIO": self.sim_share})
        return {"TOTAL": self.train_frames, "SOURCES": sources}


def simulated_site(name_or_file: str) -> Site:
    """A bundled domain by name ('sim' | 'real' | 'industrial'), else the site file at that path."""
    return get_domain(name_or_file) if name_or_file in BUNDLED_SITES else load_site(name_or_file)


def split_background(site: Site, holdout: float) -> tuple[Site, Site, tuple[int, int]]:
    """(training site, held-out site, held-out (first, stop) frame indices of the recording): the recording's frames
    in time order, the last max(1, round(holdout x n)) held out."""
    if site.background is None:
        raise ConfigError(f"site '{site.name}' has no background recording: `site train` needs `background:` (a "
                          f"recording of the empty site)")
    if not 0 < holdout < 1:
        raise ConfigError(f"--holdout must be between 0 and 1 (the share of the recording held out), got {holdout}")
    first, stop = site.background.frames or (0, len(read_background(site.background, site.pattern)))
    held = max(1, round(holdout * (stop - first)))
    if stop - first - held < 1:
        raise ConfigError(f"{site.background.recording}: {stop - first} frames cannot be split into training and "
                          f"held-out frames: record more frames of the empty site")
    cut = stop - held
    train = dataclasses.replace(site, background=dataclasses.replace(site.background, frames=(first, cut)))
    test = dataclasses.replace(site, background=dataclasses.replace(site.background, frames=(cut, stop)))
    return train, test, (cut, stop)


def site_extent(site: Site) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) [m]: the walkable area and PERSON_MARGIN_M around it."""
    corners = np.asarray(site.walkable)
    low, high = corners.min(0) - PERSON_MARGIN_M, corners.max(0) + PERSON_MARGIN_M
    return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def learn_background(site: Site) -> BackgroundModel:
    """The background model (geometry.background) of the frames of site.background, on the site's scan pattern."""
    pattern = get_pattern(site.pattern)
    directions, _, _ = pattern.pulses()
    frames = [frame.points[frame.returned, :3] for frame in read_background(site.background, site.pattern)]
    return BackgroundModel.learn(directions, frames, site.viewpoints[0].mount, np.radians(pattern.angle_spacing_deg))


def site_config(site: Site, data_path: Path, mix: dict, background: Path, detector: str = "second",
                classical: dict | None = None) -> dict:
    """The config (YAML-ready) of one of SITE_DETECTORS: the shipped SECOND with the site's grid in the paper
    setting and in every profile (grid.fitted_range), trained on the sources of `mix` (SitePlan.mix), tested on
    `test`; every detector names the site's `background` model (detect watches the sensor with it); the background
    detectors take background_depth as a point feature; `background` is MODEL.NAME BackgroundSubtraction with the
    settings `classical`."""
    base = cfg_from_yaml_file(MODEL_CONFIG)
    extent, profiles = site_extent(site), {}
    for name in ("paper", *base.PROFILES):
        cfg = load_config(MODEL_CONFIG, profile=name)
        voxel = next(step.VOXEL_SIZE for step in cfg.DATA_CONFIG.DATA_PROCESSOR
                     if step.NAME == "transform_points_to_voxels")
        z_range = Z_RANGES.get(name, cfg.DATA_CONFIG.POINT_CLOUD_RANGE[2::3])
        profiles[name] = fitted_range(extent, z_range, voxel[0], xy_cell_multiple(cfg.MODEL))
    overrides = {name: {"DATA_CONFIG": {"POINT_CLOUD_RANGE": profiles[name], "MIX": {"TOTAL": mix["TOTAL"]}}}
                 for name in base.PROFILES}
    overrides["quick"]["OPTIMIZATION"] = SITE_QUICK_OPTIMIZATION
    data_config = {"DATA_PATH": str(data_path), "POINT_CLOUD_RANGE": profiles["paper"], "MIX": mix,
                   "TEST_SOURCE": {"NAME": "test", "COUNT": None}, "BACKGROUND_MODEL": str(background),
                   "DATA_AUGMENTOR": {"DISABLE_AUG_LIST": SITE_DISABLED_AUGMENTATIONS}}
    config = {"_BASE_CONFIG_": str(MODEL_CONFIG), "DATA_CONFIG": data_config, "PROFILES": overrides}
    if detector in ("background", "second_background"):
        features = ["x", "y", "z", "intensity", BACKGROUND_FEATURE]
        data_config["POINT_FEATURE_ENCODING"] = {"used_feature_list": features, "src_feature_list": features}
    if detector == "background":
        config["MODEL"] = {"NAME": "BackgroundSubtraction", "BACKGROUND_SUBTRACTION": classical or {}}
    return config


def write_site_config(out: Path, detector: str, config: dict, set_cfgs, profile: str):
    """Write <out>/SITE_CONFIGS[detector] and return it loaded (with set_cfgs and the profile)."""
    path = out / SITE_CONFIGS[detector]
    write_text(path, yaml.safe_dump(config, sort_keys=False))
    return load_config(path, set_cfgs, profile=profile)


def test_sets(plan: SitePlan, test: Site) -> dict[str, tuple[Site, int, int]]:
    """{name: (site, frames, seed)} of the composited held-out sets (stage 2): people, people in pairs (at least
    two, half of them walking side by side, the others as close as 0.5 m), people beside distractors, distractors
    and nobody."""
    pairs = dataclasses.replace(test, people=(2, max(3, test.people[1])), group_probability=0.5, min_separation_m=0.5)
    beside = dataclasses.replace(test, distractors=DISTRACTORS)
    alone = dataclasses.replace(test, people=(0, 0), distractors=DISTRACTORS)
    side_sets = max(1, plan.test_frames // 2)
    return {"test": (test, plan.test_frames, plan.seed + 1), "pairs": (pairs, side_sets, plan.seed + 3),
            "test_distractors": (beside, side_sets, plan.seed + 4), "distractors": (alone, side_sets, plan.seed + 5)}


def write_empty_frames(site: Site, held: tuple[int, int], out: Path) -> int:
    """The held-out background frames as they are (nobody in them), in the site's ground frame, as a KITTI-layout
    folder `out` (memslidar import's writer); returns their number."""
    mount, recording = site.viewpoints[0].mount, Path(site.background.recording)
    fmt = resolve_format(recording, "auto")
    frames = list_frames(fmt, recording)[held[0]:held[1]]
    import_frames(frames, out, mount, {"source": "the site file", **dataclasses.asdict(mount)}, fmt, recording)
    return len(frames)


def detections_on(cfg, checkpoint: Path | None, frames: Path, out: Path, period_s: float, logger) -> dict:
    """`memslidar detect` over a folder of frames in which no one is: {frames, seconds (of recording),
    detections_per_frame (at the tracker's min_score), detections_per_minute, confirmed_tracks, tracks_per_minute,
    max_score, frames_per_s (the whole detect loop, this process's threads)}."""
    summary = detect(cfg, checkpoint, DetectOptions(src=frames, out=out, fmt="kitti", frame_period_s=period_s),
                     logger)
    scores = [detection["score"] for line in (out / "detections.jsonl").read_text().splitlines()
              for detection in json.loads(line)["detections"]]
    minutes = summary["frames"] * period_s / 60
    return {"frames": summary["frames"], "seconds": summary["frames"] * period_s,
            "detections_per_frame": summary["detections"] / summary["frames"],
            "detections_per_minute": summary["detections"] / minutes, "confirmed_tracks": summary["tracks"],
            "tracks_per_minute": summary["tracks"] / minutes, "max_score": max(scores, default=None),
            "frames_per_s": summary["frames_per_s"], "detect_folder": str(out)}


def bundled_checkpoints(reproduce_out: Path) -> dict[str, tuple[EasyDict, Path]]:
    """{model: (config, final checkpoint)} of the seed-0 runs of a `memslidar reproduce` output folder."""
    models = {}
    for run_dir in sorted((reproduce_out / "models").glob("*/seed_0")):
        if (run_dir / RUN_FILE).is_file():
            cfg = EasyDict(json.loads((run_dir / RUN_CONFIG).read_text()))
            models[run_dir.parent.name] = (cfg, final_checkpoint(cfg, run_dir))
    if not models:
        raise ConfigError(f"--compare {reproduce_out}: no finished seed-0 model runs in {reproduce_out}/models (run "
                          f"`memslidar reproduce` first, or leave out --compare)")
    return models


def plot_site_frames(path: Path, data: Path, out: Path, detector: str, predictions: Path, point_cloud_range) -> Path:
    """The figure of `detector`: the last held-out empty frame with its detections (left), the last distractor frame
    (middle), and the composited held-out frame with the most people with its ground truth and predictions
    (right)."""
    panels = []
    for name in ("empty", "distractors"):
        layout = KittiLayout(data / name)
        frame_id = layout.frame_ids()[-1]
        detections = read_label_folder(out / "detect" / name / detector / "labels", with_score=True)
        boxes = detections[sorted(detections)[-1]]["boxes_lidar"] if detections else np.zeros((0, 7))
        what = "held-out empty frame" if name == "empty" else "distractors, nobody"
        panels.append((f"{what} {frame_id}: {len(boxes)} detections (green)", read_points(layout.velodyne(frame_id)),
                       np.zeros((0, 7)), boxes))
    test = KittiLayout(data / "test")
    gt = read_label_folder(test.training / "label_2", with_score=False)
    test_id = max(sorted(gt), key=lambda frame_id: len(gt[frame_id]["name"]))
    predicted = read_label_folder(predictions, with_score=True)[test_id]
    shown = predicted["boxes_lidar"][predicted["score"] >= TRACKER_MIN_SCORE]
    panels.append((f"people composited into held-out frame {test_id}: ground truth (blue), detections >= "
                   f"{TRACKER_MIN_SCORE} (green)", read_points(test.velodyne(test_id)), gt[test_id]["boxes_lidar"],
                   shown))
    return plot_frames(path, panels, point_cloud_range)


def held_out_scores(cfgs: dict, runs: dict, data: Path, out: Path, logger) -> dict:
    """{detector: {set: metrics with 'interval' {AP3D_R40, APBEV_R40}}} on every composited held-out set with people
    (the first, `test`, from the runs; the others predicted here), intervals by bootstrap over each set's frames."""
    scores = {}
    for detector, cfg in cfgs.items():
        run_dir = out / "models" / detector
        checkpoint = final_checkpoint(cfg, run_dir) if is_learned(cfg.MODEL) else None
        scores[detector] = {}
        for name in PEOPLE_SETS:
            if name == "test":
                pred_dir = out / runs[detector]["predictions"]
            else:
                set_cfg = copy.deepcopy(cfg)
                set_cfg.DATA_CONFIG.TEST_SOURCE = EasyDict({"NAME": name, "COUNT": None})
                predict(set_cfg, checkpoint, run_dir / f"eval_{name}", logger)
                pred_dir = prediction_folder(run_dir / f"eval_{name}") / name
            gt_dir = data / name / "training" / "label_2"
            entry = score_run(gt_dir, pred_dir)["metrics"]
            gt = read_label_folder(gt_dir, with_score=False)
            matches = frame_matches([gt[frame] for frame in sorted(gt)], frame_predictions(pred_dir, sorted(gt)))
            entry["interval"] = {f"AP{kind}_R40": list(ap_interval([matches[kind]])) for kind in ("3D", "BEV")}
            entry["predictions"] = str(pred_dir)
            scores[detector][name] = entry
    return scores


def train_site(site_file: Path, out: Path, plan: SitePlan, profile: str = "quick", compare: Path | None = None,
               command: str = "", set_cfgs: list[str] | None = None,
               detectors: tuple[str, ...] = DEFAULT_DETECTORS) -> dict:
    """Stages 1-6 of the module docstring for `detectors` (a subset of SITE_DETECTORS); returns the results dict
    written to out/results.json."""
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    unknown = sorted(set(detectors) - set(SITE_DETECTORS))
    if unknown or not detectors:
        raise ConfigError(f"--detectors {' '.join(detectors)}: choose from {', '.join(SITE_DETECTORS)}")
    out.mkdir(parents=True, exist_ok=True)
    site = simulate_empty_recording(load_site(site_file, estimate_background_mount), EMPTY_RECORDING_FRAMES,
                                    out / "empty_recording", plan.seed)
    mix = plan.mix()
    compared = bundled_checkpoints(compare) if compare else {}  # refused before any work when missing
    sim = simulated_site(plan.sim_site) if plan.sim_share else None
    if sim is not None and set(detectors) - {"second"}:
        raise ConfigError("--sim-share: simulated frames have no site background, which the background detectors "
                          "read; train them without it, or pass --detectors second")
    train, test, held = split_background(site, plan.holdout)  # 1.
    if train.distractors == (0, 0):
        train = dataclasses.replace(train, distractors=TRAIN_DISTRACTORS)
    logger = create_logger(out / "site_log.txt")
    clock = StageClock(logger)
    data, background_path = out / "data", out / BACKGROUND_FILE
    with clock("background"):
        background = learn_background(train)
        background.save(background_path)
    with clock("data"):  # 2.
        parts = {"train": (train, source_counts(EasyDict(mix))["train"], plan.seed),
                 **test_sets(plan, test)}
        if sim is not None:
            parts["sim"] = (sim, source_counts(EasyDict(mix))["sim"], plan.seed + 2)
        for name, (part, count, seed) in parts.items():
            simulate_dataset(part, count, data / name, seed=seed, workers=available_cores())
            create_domain_infos(Source(name, data / name, count))
        if not KittiLayout(data / "empty").frame_ids():
            write_empty_frames(site, held, data / "empty")
    configs, classical, trials = {}, None, []  # 3.
    if "background" in detectors:
        with clock("classical settings"):
            probe = write_site_config(out, "background", site_config(site, data, mix, background_path, "background"),
                                      set_cfgs, profile)
            classical, trials = choose_settings(probe, logger)
    for detector in detectors:
        configs[detector] = write_site_config(
            out, detector, site_config(site, data, mix, background_path, detector, classical), set_cfgs, profile)
    with clock("train and test"):  # 4.
        jobs = [{"model": detector, "seed": plan.seed, "cfg": cfg, "run_dir": out / "models" / detector,
                 "gt_dir": data / "test" / "training" / "label_2", "out": out, "workers": 0, "every_epoch": True,
                 "threads": 1 if len([d for d in detectors if d != "background"]) > 1 else available_cores()}
                for detector, cfg in configs.items()]
        learned = [job for job in jobs if is_learned(job["cfg"].MODEL)]
        runs = dict(zip([job["model"] for job in learned], run_jobs(learned, min(len(learned), 2), logger)))
        for job in jobs:
            if job["model"] not in runs:
                runs[job["model"]] = run_model({**job, "threads": available_cores()})
        scores = held_out_scores(configs, runs, data, out, logger)
    period = get_pattern(site.pattern).frame_period_s
    checkpoints = {detector: final_checkpoint(cfg, out / "models" / detector) if is_learned(cfg.MODEL) else None
                   for detector, cfg in configs.items()}
    with clock("false alarms"):  # 5.
        alarms = {name: {} for name in NOBODY_SETS}
        for name in NOBODY_SETS:
            for model, (model_cfg, checkpoint) in {**{d: (configs[d], checkpoints[d]) for d in configs},
                                                   **compared}.items():
                alarms[name][model] = detections_on(model_cfg, checkpoint, data / name, out / "detect" / name / model,
                                                    period, logger)
    results = {"site": site.name, "site_file": str(site_file), "profile": profile, "command": command,
               "date": started.isoformat(timespec="seconds"), "environment": environment(),
               "plan": dataclasses.asdict(plan), "background": site.background.recording,
               "background_model": {"file": str(background_path), "frames": background.frames,
                                    "margin_m": background.margin_m, "margin_per_m": background.margin_per_m,
                                    "no_background_share": float(np.isinf(background.range).mean())},
               "held_out_frames": list(held), "mount": dataclasses.asdict(site.viewpoints[0].mount),
               "point_cloud_range": list(next(iter(configs.values())).DATA_CONFIG.POINT_CLOUD_RANGE),
               "detectors": list(detectors), "configs": {d: str(out / SITE_CONFIGS[d]) for d in detectors},
               "checkpoints": {d: checkpoints[d] and str(checkpoints[d]) for d in detectors},
               "classical": {"settings": classical, "trials": trials},
               "scores": scores, "curves": {d: runs[d]["curve"] for d in detectors},
               "ms_per_frame": {d: runs[d]["metrics"]["ms_per_frame"] for d in detectors},
               "read_back": {job["model"]: bool(runs[job["model"]].get("read_back")) for job in learned},
               "false_alarms": alarms, "min_score": TRACKER_MIN_SCORE, "frame_period_s": period}
    shown = FIGURE_DETECTOR if FIGURE_DETECTOR in scores else detectors[0]
    with clock("figures"):  # 6.
        results["figure"] = str(plot_site_frames(out / "site_detections.png", data, out, shown,
                                                 Path(scores[shown]["test"]["predictions"]),
                                                 results["point_cloud_range"]))
    results["stages"], results["wall_seconds"] = clock.seconds, time.perf_counter() - wall_start
    report_path, _ = write_report(results, out, render_site_report)
    logger.info(f"report: {report_path}")
    return json_safe(results)
