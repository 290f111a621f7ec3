"""Does a site's detector survive a turned sensor? The held-out people and empty frames of a `memslidar site train`
run, turned about the vertical by each yaw (what the sensor records after a bracket was bumped by that much), run
through `memslidar detect` with each detector's config (whose background model realigns the frames,
monitor.background_watch), scored against the unturned labels; yaw 0 is the same path without a turn.

    python tools/research/site_turned.py output/site/blickfeld_room [--yaw 0 1 4 10] [--sets test empty]

Prints, per detector and yaw: AP 3D / BEV R40 on the people set, detections per frame on the empty set, and the
turn detect found (its sensor_turned event). Writes the turned frames and detect's outputs under <run>/turned/.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from pcdet_memslidar.config import load_config
from pcdet_memslidar.experiments.results import score_run
from pcdet_memslidar.geometry.background import turn_about_vertical
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.monitor.detect import DetectOptions, detect


def turned_copy(source: Path, yaw_deg: float, out: Path) -> Path:
    """The frames of KITTI-layout folder `source` turned by yaw_deg [deg] (counter-clockwise seen from above) about
    the sensor's vertical, with their point times, as a KITTI-layout folder `out` (labels left out)."""
    layout, turned = KittiLayout(source), KittiLayout(out)
    for frame_id in layout.frame_ids():
        points = kitti.read_points(layout.velodyne(frame_id))
        times = layout.time_offset(frame_id)
        write_frame(turned, frame_id, turn_about_vertical(points, yaw_deg), [], np.zeros((0, 7)), {},
                    time_offset=kitti.read_point_times(times, len(points)) if times.is_file() else None)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a `memslidar site train` output folder")
    parser.add_argument("--yaw", type=float, nargs="+", default=[0.0, 1.0, 4.0, 10.0], help="turns [deg]")
    parser.add_argument("--people-set", default="test", help="held-out set with people (default %(default)s)")
    args = parser.parse_args()
    results = json.loads((args.run / "results.json").read_text())
    logger = logging.getLogger("site_turned")
    rows = []
    for yaw in args.yaw:
        folders = {name: turned_copy(args.run / "data" / name, -yaw, args.run / "turned" / f"{yaw:g}" / name)
                   for name in (args.people_set, "empty")}
        for detector, config in results["configs"].items():
            cfg = load_config(config, profile=results["profile"])
            outputs = {}
            for name, folder in folders.items():
                out = args.run / "turned" / f"{yaw:g}" / "detect" / name / detector
                outputs[name] = detect(cfg, results["checkpoints"][detector], DetectOptions(src=folder, out=out,
                                                                                           fmt="kitti"), logger)
                outputs[name]["labels"] = out / "labels"
            metrics = score_run(args.run / "data" / args.people_set / "training" / "label_2",
                                outputs[args.people_set]["labels"])["metrics"]
            found = [event["total_yaw_deg"] for event in outputs[args.people_set]["background_events"] or []
                     if event["type"] == "sensor_turned"]
            rows.append([detector, f"{yaw:g}", f"{metrics['AP3D_R40']:.3f}", f"{metrics['APBEV_R40']:.3f}",
                         f"{outputs['empty']['detections'] / outputs['empty']['frames']:.2f}",
                         f"{found[-1]:.2f}" if found else "-"])
    header = ["detector", "turn (deg)", f"AP 3D R40 ({args.people_set})", "AP BEV R40", "empty: detections / frame",
              "turn found (deg)"]
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in sorted(rows, key=lambda row: (row[0], float(row[1]))):
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
