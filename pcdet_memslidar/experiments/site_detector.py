"""`memslidar site train`: a detector for one site from a recording of it empty, without annotating.

The story, one stage per line (each stage's wall time goes into the report):
1. split the background recording by time: its first frames are backgrounds for training, the last `holdout`
   share is held out (never seen in training);
2. data: people composited into the training backgrounds (`train`), optionally frames of a simulated scene mixed in
   (`sim`, a share of the training frames), people composited into the held-out backgrounds (`test`, another
   seed), and the held-out frames as they are (`empty`: nobody in them), all in their ground frame;
3. config: the shipped SECOND config with the site's grid (grid.fitted_range over the walkable area, for every
   profile) and these sources, written as <out>/site.yaml (it is also what `memslidar detect --cfg` takes);
4. train and test it (runs.run_model: AP 3D at IoU 0.5 on the composited held-out frames);
5. false alarms: `memslidar detect` over the empty held-out frames with this model and with each bundled
   checkpoint given (--compare): detections per frame at the tracker's min_score, confirmed tracks per minute;
6. figure and report: <out>/report.md, results.json, site_detections.png.
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import time
from pathlib import Path

import numpy as np
import yaml
from easydict import EasyDict

from pcdet_memslidar.config import CONFIG_DIR, cfg_from_yaml_file, load_config
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import Source, source_counts
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.figures import plot_frames
from pcdet_memslidar.evaluation.folders import read_label_folder
from pcdet_memslidar.experiments.report import HEADLINE, environment, json_safe, write_report
from pcdet_memslidar.experiments.runs import RUN_CONFIG, RUN_FILE, StageClock, run_model
from pcdet_memslidar.grid import fitted_range, xy_cell_multiple
from pcdet_memslidar.io.importer import import_frames, list_frames
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.monitor.detect import DetectOptions, detect, resolve_format
from pcdet_memslidar.monitor.tracker import TrackerConfig
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.runtime.train import final_checkpoint
from pcdet_memslidar.sim.composite import estimate_background_mount, read_background
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.site import BUNDLED_SITES, Background, Site, get_domain, load_site
from pcdet_memslidar.sim.writer import simulate_dataset
from pcdet_memslidar.utils.atomic import write_text
from pcdet_memslidar.utils.cores import available_cores

MODEL_CONFIG = CONFIG_DIR / "memslidar_models" / "second_person.yaml"
SITE_CONFIG = "site.yaml"
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
    train = dataclasses.replace(site, background=Background(site.background.recording, (first, cut)))
    test = dataclasses.replace(site, background=Background(site.background.recording, (cut, stop)))
    return train, test, (cut, stop)


def site_extent(site: Site) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) [m]: the walkable area and PERSON_MARGIN_M around it."""
    corners = np.asarray(site.walkable)
    low, high = corners.min(0) - PERSON_MARGIN_M, corners.max(0) + PERSON_MARGIN_M
    return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def site_config(site: Site, data_path: Path, mix: dict) -> dict:
    """The site's detector config (YAML-ready): the shipped SECOND with the site's grid in the paper setting and in
    every profile (grid.fitted_range), trained on the sources of `mix` (SitePlan.mix) and tested on `test`."""
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
    return {
        "_BASE_CONFIG_": str(MODEL_CONFIG),
        "DATA_CONFIG": {"DATA_PATH": str(data_path), "POINT_CLOUD_RANGE": profiles["paper"], "MIX": mix,
                        "TEST_SOURCE": {"NAME": "test", "COUNT": None},
                        "DATA_AUGMENTOR": {"DISABLE_AUG_LIST": SITE_DISABLED_AUGMENTATIONS}},
        "PROFILES": overrides,
    }


def write_empty_frames(site: Site, held: tuple[int, int], out: Path) -> int:
    """The held-out background frames as they are (nobody in them), in the site's ground frame, as a KITTI-layout
    folder `out` (memslidar import's writer); returns their number."""
    mount, recording = site.viewpoints[0].mount, Path(site.background.recording)
    fmt = resolve_format(recording, "auto")
    frames = list_frames(fmt, recording)[held[0]:held[1]]
    import_frames(frames, out, mount, {"source": "the site file", **dataclasses.asdict(mount)}, fmt, recording)
    return len(frames)


def false_alarms(cfg, checkpoint: Path, empty: Path, out: Path, period_s: float, logger) -> dict:
    """`memslidar detect` over the empty frames: {frames, detections_per_frame (at the tracker's min_score),
    confirmed_tracks, tracks_per_minute, max_score}."""
    summary = detect(cfg, checkpoint, DetectOptions(src=empty, out=out, fmt="kitti", frame_period_s=period_s),
                     logger)
    scores = [detection["score"] for line in (out / "detections.jsonl").read_text().splitlines()
              for detection in json.loads(line)["detections"]]
    minutes = summary["frames"] * period_s / 60
    return {"frames": summary["frames"], "detections_per_frame": summary["detections"] / summary["frames"],
            "confirmed_tracks": summary["tracks"], "tracks_per_minute": summary["tracks"] / minutes,
            "max_score": max(scores, default=None), "detect_folder": str(out)}


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


def plot_site_frames(path: Path, data: Path, out: Path, predictions: Path, point_cloud_range) -> Path:
    """The figure: the last held-out empty frame with the site model's detections (left), and the composited
    held-out frame with the most people with its ground truth and predictions (right)."""
    empty, test = KittiLayout(data / "empty"), KittiLayout(data / "test")
    empty_id = empty.frame_ids()[-1]
    detections = read_label_folder(out / "detect_empty" / "site" / "labels", with_score=True)[empty_id]
    gt = read_label_folder(test.training / "label_2", with_score=False)
    test_id = max(sorted(gt), key=lambda frame_id: len(gt[frame_id]["name"]))
    predicted = read_label_folder(predictions, with_score=True)[test_id]
    shown = predicted["boxes_lidar"][predicted["score"] >= TRACKER_MIN_SCORE]
    return plot_frames(path, [
        (f"held-out empty frame {empty_id}: {len(detections['name'])} detections (green)",
         read_points(empty.velodyne(empty_id)), np.zeros((0, 7)), detections["boxes_lidar"]),
        (f"people composited into held-out frame {test_id}: ground truth (blue), detections >= "
         f"{TRACKER_MIN_SCORE} (green)", read_points(test.velodyne(test_id)), gt[test_id]["boxes_lidar"], shown)],
        point_cloud_range)


def train_site(site_file: Path, out: Path, plan: SitePlan, profile: str = "quick", compare: Path | None = None,
               command: str = "", set_cfgs: list[str] | None = None) -> dict:
    """Stages 1-6 of the module docstring; returns the results dict written to out/results.json."""
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    site = load_site(site_file, estimate_background_mount)
    mix = plan.mix()
    sim = simulated_site(plan.sim_site) if plan.sim_share else None
    train, test, held = split_background(site, plan.holdout)  # 1.
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "site_log.txt")
    clock = StageClock(logger)
    data = out / "data"
    with clock("data"):  # 2.
        counts = {**source_counts(EasyDict(mix)), "test": plan.test_frames}
        parts = {"train": (train, plan.seed), "sim": (sim, plan.seed + 2), "test": (test, plan.seed + 1)}
        for name, count in counts.items():
            simulate_dataset(parts[name][0], count, data / name, seed=parts[name][1], workers=available_cores())
            create_domain_infos(Source(name, data / name, count))
        if not KittiLayout(data / "empty").frame_ids():
            write_empty_frames(site, held, data / "empty")
    config_path = out / SITE_CONFIG  # 3.
    write_text(config_path, yaml.safe_dump(site_config(site, data, mix), sort_keys=False))
    cfg = load_config(config_path, set_cfgs, profile=profile)
    run_dir = out / "model"
    with clock("train and test"):  # 4.
        run = run_model({"model": "site", "seed": plan.seed, "cfg": cfg, "run_dir": run_dir,
                         "gt_dir": data / "test" / "training" / "label_2", "out": out, "workers": 0,
                         "threads": available_cores(), "every_epoch": True})
    period = get_pattern(site.pattern).frame_period_s
    with clock("false alarms"):  # 5.
        alarms = {"site": false_alarms(cfg, final_checkpoint(cfg, run_dir), data / "empty",
                                       out / "detect_empty" / "site", period, logger)}
        for model, (model_cfg, checkpoint) in (bundled_checkpoints(compare) if compare else {}).items():
            alarms[model] = false_alarms(model_cfg, checkpoint, data / "empty", out / "detect_empty" / model,
                                         period, logger)
    results = {"site": site.name, "site_file": str(site_file), "profile": profile, "command": command,
               "date": started.isoformat(timespec="seconds"), "environment": environment(),
               "plan": dataclasses.asdict(plan), "background": site.background.recording,
               "held_out_frames": list(held), "mount": dataclasses.asdict(site.viewpoints[0].mount),
               "point_cloud_range": list(cfg.DATA_CONFIG.POINT_CLOUD_RANGE), "config": str(config_path),
               "checkpoint": str(final_checkpoint(cfg, run_dir)), "test": run["metrics"], "curve": run["curve"],
               "false_alarms": alarms, "min_score": TRACKER_MIN_SCORE, "frame_period_s": period}
    with clock("figures"):  # 6.
        results["figure"] = str(plot_site_frames(out / "site_detections.png", data, out, out / run["predictions"],
                                                 cfg.DATA_CONFIG.POINT_CLOUD_RANGE))
    results["stages"], results["wall_seconds"] = clock.seconds, time.perf_counter() - wall_start
    report_path, _ = write_report(results, out, render_site_report)
    logger.info(f"{HEADLINE} {run['metrics'][HEADLINE]:.4f}; report: {report_path}")
    return json_safe(results)


def render_site_report(results: dict) -> str:
    """report.md of a `site train` run."""
    alarms = results["false_alarms"]
    rows = "\n".join(f"| {model} | {entry['frames']} | {entry['detections_per_frame']:.2f} | "
                     f"{entry['confirmed_tracks']} | {entry['tracks_per_minute']:.1f} | "
                     f"{'-' if entry['max_score'] is None else format(entry['max_score'], '.2f')} |"
                     for model, entry in alarms.items())
    metrics, machine = results["test"], results["environment"]["machine"]
    lines = [
        f"# Site detector: {results['site']}", "",
        f"{results['date']}, {machine['cpu']} ({machine['cores']} cores); command: `{results['command']}`; "
        f"profile {results['profile']}; wall time {results['wall_seconds'] / 60:.1f} min.", "",
        f"Background: `{results['background']}`; frames {results['held_out_frames'][0]} to "
        f"{results['held_out_frames'][1] - 1} held out (never trained on). Mount {results['mount']}. "
        f"Grid (POINT_CLOUD_RANGE) {results['point_cloud_range']}.", "",
        "## False alarms on the held-out empty frames", "",
        f"Nobody is in these frames: every detection at score >= {results['min_score']} (the tracker's min_score) "
        f"is a false alarm. They span {alarms['site']['frames'] * results['frame_period_s']:.2f} s of the recording: "
        "tracks per minute extrapolate from that.", "",
        "| model | frames | detections / frame | confirmed tracks | tracks / minute | highest score |",
        "|---|---|---|---|---|---|", rows, "",
        "## People composited into the held-out frames", "",
        f"AP 3D at IoU 0.5 (R40): **{metrics['AP3D_R40']:.4f}**; AP BEV (R40) {metrics['APBEV_R40']:.4f}; "
        f"AP 3D (R11) {metrics['AP3D_R11']:.4f}.", "",
        f"![held-out frame]({Path(results['figure']).name})", "",
        "## Detect on new recordings of the site", "",
        f"    memslidar detect --cfg {results['config']} --profile {results['profile']} --ckpt "
        f"{results['checkpoint']} --src NEW_RECORDING --mount {results['mount']['height']},"
        f"{results['mount']['tilt_deg']},{results['mount']['roll_deg']} --zones ZONES.yaml --out OUT", ""]
    return "\n".join(lines)
