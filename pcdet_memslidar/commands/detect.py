"""`memslidar detect` / tools/demo.py: a trained detector on recordings, with tracks and zone events
(monitor.detect). Takes OpenPCDet's demo.py flags (--cfg_file, --data_path, --ckpt, --ext) as well."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch

from pcdet_memslidar.commands.options import (
    add_mount_arguments,
    add_precision,
    add_profile,
    add_set,
    add_time_unit,
    add_topic,
)
from pcdet_memslidar.config import load_config
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.monitor.detect import FRAME_PERIOD_S, SUMMARY_FILE, DetectOptions, detect, detect_formats
from pcdet_memslidar.monitor.zones import read_zones
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.utils.cores import shorten_time_slice


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cfg", "--cfg_file", dest="cfg_file", required=True, help="the detector's config (YAML)")
    parser.add_argument("--ckpt", default=None,
                        help="its checkpoint (.pth); none for a detector without weights (BackgroundSubtraction)")
    parser.add_argument("--src", "--data_path", dest="src", required=True, type=Path,
                        help="a recording (.bfpc or a ROS 2 bag: rosbag2 folder or .mcap, many frames), a frame "
                             "file, a folder of frames or a KITTI-layout folder")
    parser.add_argument("--format", "--ext", dest="fmt", default="auto", type=lambda text: text.lstrip("."),
                        help=f"one of {', '.join(detect_formats())} (default auto: a KITTI-layout or "
                             "rosbag2 folder, or the files' suffix); --ext .bin as in OpenPCDet's demo.py")
    add_mount_arguments(parser)
    add_time_unit(parser)
    add_topic(parser)
    parser.add_argument("--zones", type=Path, default=None, help="zone file (YAML): named polygons with a level")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/detect/<src name>)")
    parser.add_argument("--batch-size", "--batch_size", type=int, default=None,
                        help="frames per forward pass (default: 1 on a CPU, fastest per frame there; 4 on a GPU)")
    parser.add_argument("--frame-period", type=float, default=FRAME_PERIOD_S,
                        help="seconds between frames of formats without time stamps (default %(default)s: the Cube 1 "
                             "at 200 lines)")
    parser.add_argument("--save-points", action="store_true",
                        help="also write each frame's points (points/*.bin); by default only detections are kept")
    parser.add_argument("--plot", action="store_true", help="a bird's-eye PNG per frame (plots/*.png)")
    parser.add_argument("--mcap", type=Path, default=None, metavar="FILE",
                        help="also write the detections, tracks, zones and events as an MCAP file of ROS 2 messages "
                             "for RViz and Foxglove (visualization_msgs MarkerArray, vision_msgs Detection3DArray); "
                             "points only with --save-points")
    add_precision(parser)
    add_profile(parser)
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    if args.fmt not in detect_formats():
        raise ConfigError(f"--format {args.fmt!r}: use one of {', '.join(detect_formats())}")
    if (args.batch_size is not None and args.batch_size < 1) or not 0 < args.frame_period < math.inf:
        raise ConfigError("--batch-size must be >= 1 and --frame-period a finite number of seconds > 0")
    cfg = load_config(args.cfg_file, args.set_cfgs, profile=args.profile)
    out = args.out or Path("output") / "detect" / args.src.name.split(".")[0]
    options = DetectOptions(src=args.src, out=out, fmt=args.fmt, mount=args.mount,
                            estimate_ground=args.estimate_ground,
                            zones=read_zones(args.zones) if args.zones else None, batch_size=args.batch_size,
                            frame_period_s=args.frame_period, save_points=args.save_points, plot=args.plot,
                            precision=args.precision, time_unit_s=args.time_unit_s, topic=args.topic,
                            mcap=args.mcap)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    shorten_time_slice()  # an edge box shares its cores
    summary = detect(cfg, args.ckpt, options, create_logger(), device)
    print(f"{summary['frames']} frames: {summary['detections']} detections, {summary['tracks']} tracks, "
          f"{summary['events']} zone events; {summary['frames_per_s']:.2f} frames/s on {device}")
    print(f"written: {out} (detections.jsonl, labels/, {SUMMARY_FILE})" + (f" and {args.mcap}" if args.mcap else ""))
    return 0
