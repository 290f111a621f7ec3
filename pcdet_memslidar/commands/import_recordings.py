"""`memslidar import`: real recordings and CVAT 3D cuboids (the formats of io.formats) -> a KITTI-layout dataset
(io.importer), with the validation report printed."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcdet_memslidar.commands.options import add_mount_arguments, add_time_unit, add_topic
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.io.importer import REPORT_NAME, import_dataset, import_formats


def format_report(report: dict) -> str:
    """Human-readable summary of an import report."""
    mount = report["mount"]
    lines = [f"imported {report['frames']} frames ({report['format']}) from {report['source']} into {report['out']}",
             f"  mount: {mount['source']}" + (f": height {mount['height']:.3f} m, tilt {mount['tilt_deg']:.2f} deg, "
                                             f"roll {mount['roll_deg']:.2f} deg" if "height" in mount else "")]
    if "inliers" in mount:
        lines.append(f"  ground plane: {mount['inliers']} inliers, RMS {100 * mount['rms_m']:.2f} cm")
    lines += [f"  frames without labels:            {report['frames_without_labels']}",
              f"  boxes:                            {report['boxes']}",
              f"  boxes with < {report['min_box_points']} points:            {report['boxes_under_min_points']}",
              f"  points:                           {report['points']}",
              f"  points out of range {report['point_cloud_range']}: {report['points_out_of_range']}",
              f"  dropped NaN / zero / no-return:   {report['dropped_invalid_points']}",
              f"  max box levelling [deg]:          {report['max_box_levelling_deg']:.2f}",
              f"  split: {report['train_frames']} train / {report['val_frames']} val"]
    if report["skipped_unknown_labels"]:
        lines.append(f"  skipped unknown labels: {report['skipped_unknown_labels']}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", required=True, choices=import_formats(), help="source format")
    parser.add_argument("--src", required=True, type=Path,
                        help="a file, a folder of files, a ROS 2 bag (rosbag2 folder or .mcap), or a CVAT export "
                             "(folder or .zip)")
    parser.add_argument("--out", type=Path, default=Path("data/memslidar/real"),
                        help="dataset folder to create (default: %(default)s)")
    add_mount_arguments(parser)
    add_time_unit(parser)
    add_topic(parser)
    parser.add_argument("--skip-unknown-labels", action="store_true",
                        help="drop (and count) cuboids whose label is not person / pedestrian instead of failing")
    parser.add_argument("--kitti-raw-convention", choices=("cvat", "kitti"), default="cvat",
                        help="cvat: sizes and centre as CVAT/Datumaro write them; kitti: the KITTI raw devkit's")
    parser.add_argument("--point-cloud-range", type=float, nargs=6, default=None,
                        metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                        help="range for the out-of-range count [m] (default: POINT_CLOUD_RANGE of the dataset config)")
    parser.add_argument("--overwrite", action="store_true", help="replace --out if it holds an earlier import")


def run(args: argparse.Namespace) -> int:
    try:
        report = import_dataset(args.format, args.src, args.out, args.mount, args.estimate_ground,
                                args.skip_unknown_labels, args.kitti_raw_convention, args.point_cloud_range,
                                overwrite=args.overwrite, time_unit_s=args.time_unit_s, topic=args.topic)
    except (DataFormatError, ConfigError, ValueError) as error:  # OutputError is a ValueError too
        print(f"error: {error}\n(nothing was written to {args.out})", file=sys.stderr)
        return 2 if isinstance(error, OutputError) else 1
    print(format_report(report))
    print(f"report: {args.out / REPORT_NAME}")
    return 0
