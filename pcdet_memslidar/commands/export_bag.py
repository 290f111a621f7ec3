"""`memslidar export-bag --src KITTI_ROOT --out BAG`: a KITTI-layout dataset (simulated or imported) -> a ROS 2 bag of
sensor_msgs/msg/PointCloud2 messages (io.rosbag.export_bag), e.g. to try `memslidar detect` or a ROS tool on
simulated frames."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.io.formats import list_frames
from pcdet_memslidar.io.rosbag import STORAGES, export_bag
from pcdet_memslidar.monitor.detect import FRAME_PERIOD_S


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--src", type=Path, required=True, help="a KITTI-layout dataset, e.g. data/memslidar/sim")
    parser.add_argument("--out", type=Path, required=True,
                        help="rosbag2 folder to write (metadata.yaml and <name>.mcap or .db3): new, empty or an "
                             "earlier export (replaced whole)")
    parser.add_argument("--storage", choices=list(STORAGES), default="mcap",
                        help="the bag's storage plugin (default %(default)s)")
    parser.add_argument("--topic", default="/points", help="topic of the messages (default %(default)s)")
    parser.add_argument("--frame-id", default="lidar", help="header.frame_id of the messages (default %(default)s)")
    parser.add_argument("--frame-period", type=float, default=FRAME_PERIOD_S,
                        help="seconds between the frames' stamps, from 0 (default %(default)s: the Cube 1 at 200 "
                             "lines, as `memslidar detect` assumes for the KITTI layout)")


def run(args: argparse.Namespace) -> int:
    if not 0 < args.frame_period < math.inf:
        raise ConfigError("--frame-period must be a finite number of seconds > 0")
    count = export_bag(list_frames("kitti", args.src), args.out, args.frame_period, args.storage, args.topic,
                       args.frame_id)
    print(f"exported {count} frames from {args.src} to {args.out} ({args.storage}; topic {args.topic}, "
          "sensor_msgs/msg/PointCloud2)")
    return 0
