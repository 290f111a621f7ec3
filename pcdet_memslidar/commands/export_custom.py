"""`memslidar export-custom KITTI_ROOT OUT_ROOT`: a KITTI-layout dataset -> OpenPCDet's custom layout (io.custom)."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.io.custom import export_custom


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("kitti_root", type=Path, help="a KITTI-layout dataset, e.g. data/memslidar/sim")
    parser.add_argument("out_root", type=Path, help="folder to write in OpenPCDet's custom layout: new, empty or "
                                                    "an earlier export (replaced whole)")


def run(args: argparse.Namespace) -> int:
    count = export_custom(args.kitti_root, args.out_root)
    print(f"exported {count} frames from {args.kitti_root} to {args.out_root} (points/, labels/, ImageSets/)")
    return 0
