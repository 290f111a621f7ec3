"""Import of real recordings (and their CVAT labels) into a KITTI-layout dataset in the ground frame
(`memslidar import`).

    list the source frames (lazily: each is read when it is written) with the reader of their format (io.formats)
    -> choose the mount: given (--mount), estimated from the ground plane (--estimate-ground) or none (the clouds
       are already normalised, as the paper's were before annotation)
    -> per frame: normalise points and cuboids, count what needs attention, write it (io.layout.write_frame)
    -> write the 70/30 split and the validation report
    all inside a temporary folder that replaces --out only when everything succeeded.
--out must be new, empty or an earlier import (replaced with --overwrite), and must not be or contain --src.
"""
from __future__ import annotations

import contextlib
import json
from collections import Counter
from pathlib import Path

import numpy as np

from pcdet_memslidar import __version__
from pcdet_memslidar.config import SCHEMA_FILE, cfg_from_yaml_file
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import cvat, ground
from pcdet_memslidar.io.formats import FORMATS, list_frames
from pcdet_memslidar.io.frames import SourceFrame
from pcdet_memslidar.io.kitti import MIN_BOX_POINTS
from pcdet_memslidar.io.layout import KittiLayout, write_frame, write_split
from pcdet_memslidar.utils.atomic import atomic_dir, check_output_folder, refuse_overlap, write_text
from pcdet_memslidar.utils.progress import progress_bar

GROUND_FRAMES = 5  # frames pooled for --estimate-ground (the sensor is static during a recording)
REPORT_NAME = "import_report.json"
COMMAND = "memslidar import"  # the owner of the folders it writes (see utils.atomic.atomic_dir)


def import_formats() -> list[str]:
    """The formats `memslidar import` reads (its --format choices): the registered ones but folder layouts (an
    import writes one)."""
    return [name for name, fmt in FORMATS.items() if not fmt.layout]


def choose_mount(frames: list[SourceFrame], mount: Mount | None, estimate: bool) -> tuple[Mount | None, dict]:
    """The mount to normalise with and its report entry; estimated from the first GROUND_FRAMES frames
    (DataFormatError naming them and --mount where they show no floor)."""
    if mount is not None:
        return mount, {"source": "given", "height": mount.height, "tilt_deg": mount.tilt_deg,
                       "roll_deg": mount.roll_deg}
    if not estimate:
        return None, {"source": "none (clouds stored as they are: already in the ground frame)"}
    used = frames[:GROUND_FRAMES]
    points = np.concatenate([frame.load().points for frame in used])
    try:
        estimate_ = ground.estimate_ground(points[:: max(1, len(points) // 200_000)])
    except ValueError as error:
        where = used[0].name if len(used) == 1 else f"{used[0].name} to {used[-1].name}"
        raise DataFormatError(where, f"--estimate-ground: {error}") from None
    return estimate_.mount, {"source": "estimated from the ground plane", **estimate_.as_dict()}


def _frame_report(points: np.ndarray, boxes: np.ndarray, point_cloud_range: np.ndarray) -> tuple[dict, np.ndarray]:
    """Counts of one normalised frame, and the (M,) number of points in each box."""
    inside = np.all((points[:, :3] >= point_cloud_range[:3]) & (points[:, :3] <= point_cloud_range[3:]), axis=1)
    counts = points_in_boxes_mask(points[:, :3], boxes).sum(axis=0) if len(boxes) else np.zeros(0, np.int64)
    return {"points": int(len(points)), "points_out_of_range": int((~inside).sum()), "boxes": int(len(boxes)),
            "boxes_under_min_points": int((counts < MIN_BOX_POINTS).sum())}, counts


def detector_range() -> list[float]:
    """POINT_CLOUD_RANGE [x0, y0, z0, x1, y1, z1] [m] of the shipped detector's dataset config (its paper
    profile): the range an import counts the points outside of."""
    return list(cfg_from_yaml_file(SCHEMA_FILE).DATA_CONFIG.POINT_CLOUD_RANGE)


def import_frames(frames: list[SourceFrame], out: Path, mount: Mount | None, mount_entry: dict, fmt: str,
                  src: Path, skip_unknown: bool = False, point_cloud_range=None) -> dict:
    """Normalise and write `frames` into a fresh dataset at `out` (replaced whole on success: see
    utils.atomic.atomic_dir) with io.layout's train/val split; return the report. point_cloud_range: the range of
    the out-of-range count (default: detector_range())."""
    labelled = [frame.cuboids for frame in frames if frame.cuboids is not None]
    masks, unknown = cvat.person_mask(labelled, skip_unknown, src)
    person = iter(masks)
    point_cloud_range = np.asarray(detector_range() if point_cloud_range is None else point_cloud_range,
                                   dtype=np.float64)
    report = {"format": fmt, "source": str(src), "out": str(out), "package_version": __version__,
              "mount": mount_entry, "point_cloud_range": point_cloud_range.tolist(), "min_box_points": MIN_BOX_POINTS,
              "skipped_unknown_labels": dict(sorted(unknown.items())), "per_frame": []}
    with atomic_dir(out, COMMAND) as tmp:
        layout = KittiLayout(tmp)
        for index, frame in enumerate(progress_bar(frames, desc="import", unit="frame")):
            frame_id = f"{index:06d}"
            cloud = frame.load()
            points = cloud.points if mount is None else ground.normalise_points(cloud.points, mount)
            boxes, levelling = np.zeros((0, 7)), np.zeros(0)
            if frame.cuboids is not None:
                keep = next(person)
                c = frame.cuboids
                boxes, levelling = ground.normalise_boxes(c.centers[keep], c.rotations[keep], c.sizes[keep],
                                                          mount or Mount(0.0, 0.0))
            entry, box_points = _frame_report(points, boxes, point_cloud_range)
            entry.update(frame_id=frame_id, source=frame.name, labelled=frame.cuboids is not None,
                         dropped_invalid_points=cloud.dropped,
                         max_box_levelling_deg=float(levelling.max()) if len(levelling) else 0.0)
            metadata = {"source": frame.name, "source_format": fmt, "mount": mount_entry,
                        "num_points_in_gt": box_points, "package_version": __version__, "labelled": entry["labelled"],
                        "has_intensity": cloud.has_intensity, "dropped_invalid_points": cloud.dropped}
            if cloud.time is not None:
                metadata["point_time"] = np.round(cloud.time, 7)
            write_frame(layout, frame_id, points, [cvat.CLASS_NAME] * len(boxes), boxes, metadata,
                        time_offset=cloud.time_offsets())
            report["per_frame"].append(entry)
        train, val = write_split(layout)
        report.update(_totals(report["per_frame"]), train_frames=len(train), val_frames=len(val))
        write_text(tmp / REPORT_NAME, json.dumps(report, indent=1) + "\n")
    return report


def _totals(per_frame: list[dict]) -> dict:
    total = Counter()
    for entry in per_frame:
        total.update({key: entry[key] for key in ("points", "points_out_of_range", "boxes", "boxes_under_min_points",
                                                   "dropped_invalid_points")})
    return {"frames": len(per_frame),
            "frames_without_labels": sum(not e["labelled"] or not e["boxes"] for e in per_frame),
            **dict(total), "max_box_levelling_deg": max((e["max_box_levelling_deg"] for e in per_frame), default=0.0)}


def import_dataset(fmt: str, src: str | Path, out: str | Path, mount: Mount | None = None,
                   estimate_ground: bool = False, skip_unknown: bool = False, convention: str = "cvat",
                   point_cloud_range=None, overwrite: bool = True, time_unit_s: float | None = None,
                   topic: str | None = None) -> dict:
    """Import `src` (format `fmt`, one of import_formats()) into a KITTI-layout dataset at `out`; return the report.
    point_cloud_range: the range of the report's out-of-range count (default: detector_range()). time_unit_s:
    seconds per unit of the clouds' time fields where their format does not record it (their time offsets are
    written only with it). topic: the point-cloud topic of a ROS 2 bag (None: its only one). `out` must be new,
    empty or an earlier import (replaced only if `overwrite`) and must not be or contain `src`: OutputError
    otherwise."""
    if fmt not in import_formats():
        raise ConfigError(f"unknown format {fmt!r}; use one of {', '.join(import_formats())}")
    if mount is not None and estimate_ground:
        raise ConfigError("give either a mount or estimate_ground, not both")
    src, out = Path(src), Path(out)
    refuse_overlap(out, [src], "--out")
    check_output_folder(out, COMMAND)
    if not overwrite and out.is_dir() and any(out.iterdir()):
        raise OutputError(f"--out {out} holds an earlier import; pass --overwrite to replace it, or choose a new "
                          "folder")
    with cvat.open_export(src) if FORMATS[fmt].labelled else contextlib.nullcontext(src) as root:
        frames = list_frames(fmt, root, time_unit_s, convention, topic)
        mount, entry = choose_mount(frames, mount, estimate_ground)
        return import_frames(frames, out, mount, entry, fmt, src, skip_unknown, point_cloud_range)
