"""`memslidar export-custom --src KITTI_ROOT --out OUT_ROOT`: a KITTI-layout dataset -> OpenPCDet's custom layout
(io.custom)."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.io.custom import export_custom


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--src", type=Path, required=True, help="a KITTI-layout dataset, e.g. data/memslidar/sim")
    parser.add_argument("--out", type=Path, required=True, help="folder to write in OpenPCDet's custom layout: new, "
                                                                "empty or an earlier export (replaced whole)")


def run(args: argparse.Namespace) -> int:
    count = export_custom(args.src, args.out)
    print(f"exported {count} frames from {args.src} to {args.out} (points/, labels/, ImageSets/)")
    return 0
