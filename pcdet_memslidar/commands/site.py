"""`memslidar site check|train`: a site file's floor and field of view, and a detector for the site trained on
its empty recording with people composited into it (pcdet_memslidar.experiments.site_detector).

    memslidar site check --site FILE [--out DIR]
    memslidar site train --site FILE [--out DIR] [--profile quick] [--frames N] [--test-frames N] [--holdout F]
                         [--seed S] [--sim-share F --sim-site DOMAIN|FILE] [--compare REPRODUCE_OUT]
                         [--detectors background second second_background]
                         [--set KEY VALUE ...]
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from pcdet_memslidar.commands.options import add_profile, add_set
from pcdet_memslidar.config import cfg as global_cfg
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.figures import plot_ground_check
from pcdet_memslidar.experiments.results import HEADLINE
from pcdet_memslidar.experiments.site_detector import (
    DEFAULT_DETECTORS,
    SITE_DETECTORS,
    SitePlan,
    site_extent,
    train_site,
)
from pcdet_memslidar.experiments.site_report import NAMES
from pcdet_memslidar.sim.composite import estimate_background_mount, recording_points
from pcdet_memslidar.sim.site import load_site


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("check", "train"),
                        help="check: the mount and floor (a figure to look at) and the site's grid; train: "
                             "composite, train, test and report")
    parser.add_argument("--site", type=Path, required=True, help="the site file (YAML, with background:)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/site/<site name>)")
    add_profile(parser, default="quick")
    parser.add_argument("--frames", type=int, default=1200, help="composited training frames (default %(default)s, "
                                                                 "the quick profile's training-set size)")
    parser.add_argument("--test-frames", type=int, default=200,
                        help="composited held-out frames AP is measured on (default %(default)s)")
    parser.add_argument("--holdout", type=float, default=0.3,
                        help="share of the recording, at its end, held out from training (default %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the composited frames and the training")
    parser.add_argument("--sim-share", type=float, default=0.0,
                        help="share of the training frames simulated from --sim-site instead of composited "
                             "(default %(default)s: none)")
    parser.add_argument("--sim-site", default="sim",
                        help="a bundled domain (sim, real, industrial) or a site file the --sim-share frames come "
                             "from (default %(default)s)")
    parser.add_argument("--compare", type=Path, default=None,
                        help="a `memslidar reproduce` output folder: its seed-0 models' false alarms on the same "
                             "empty frames go into the report")
    parser.add_argument("--detectors", nargs="+", default=list(DEFAULT_DETECTORS), choices=SITE_DETECTORS,
                        help="which detectors to build and compare: background subtraction, SECOND, SECOND with each "
                             "point's background_depth (default: the first two)")
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    site = load_site(args.site, estimate_background_mount)
    out = args.out or Path(global_cfg.ROOT_DIR) / "output" / "site" / site.name
    if args.action == "check":
        mount = site.viewpoints[0].mount
        print(f"{args.site}: site '{site.name}', mount {dataclasses.asdict(mount)}")
        if site.walkable is not None:
            x0, y0, x1, y1 = site_extent(site)
            print(f"walkable area x {x0:.2f}..{x1:.2f} m, y {y0:.2f}..{y1:.2f} m (with a person's margin)")
        if site.background is not None:
            points = recording_points(site.background)
            walkable = None if site.walkable is None else np.array(site.walkable)
            figure = plot_ground_check(out / "ground_check.png", points, mount, f"{site.name}: is z = 0 the floor?",
                                       walkable=walkable)
            heights = mount.sensor_to_ground(points[:, :3])[:, 2]
            print(f"{np.mean(np.abs(heights) < 0.1):.1%} of the returns lie within 0.1 m of the floor; look at "
                  f"{figure}: the floor must lie on z = 0 in the side view")
        return 0
    for name in ("frames", "test_frames"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    command = " ".join(["memslidar site train", f"--site {args.site}", f"--profile {args.profile}",
                        f"--frames {args.frames}", f"--test-frames {args.test_frames}", f"--holdout {args.holdout}",
                        f"--seed {args.seed}", *([f"--out {args.out}"] if args.out else []),
                        *([f"--sim-share {args.sim_share} --sim-site {args.sim_site}"] if args.sim_share else []),
                        *([f"--compare {args.compare}"] if args.compare else []),
                        *([f"--detectors {' '.join(args.detectors)}"]
                          if args.detectors != list(DEFAULT_DETECTORS) else []),
                        *(["--set", *args.set_cfgs] if args.set_cfgs else [])])
    results = train_site(args.site, out.resolve(), SitePlan(args.frames, args.test_frames, args.holdout, args.seed,
                                                            args.sim_share, args.sim_site),
                         args.profile, args.compare, command, args.set_cfgs, tuple(args.detectors))
    empty, distractors = results["false_alarms"]["empty"], results["false_alarms"]["distractors"]
    for model, entry in empty.items():
        print(f"{NAMES.get(model, model)}: {entry['detections_per_frame']:.2f} detections / frame on the empty "
              f"held-out frames, {distractors[model]['detections_per_frame']:.2f} on distractors")
    for detector, scores in results["scores"].items():
        print(f"{NAMES[detector]}: {HEADLINE} {scores['test'][HEADLINE]:.4f} on people composited into the held-out "
              f"frames")
    print(f"report: {out / 'report.md'}")
    return 0
