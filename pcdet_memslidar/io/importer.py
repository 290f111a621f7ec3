"""Import of real recordings (and their CVAT labels) into a KITTI-layout dataset in the ground frame
(`memslidar import`).

    list the source frames (lazily: each is read when it is written)
    -> choose the mount: given (--mount), estimated from the ground plane (--estimate-ground) or none (the clouds
       are already normalised, as the paper's were before annotation)
    -> per frame: normalise points and cuboids, count what needs attention, write it (io.layout.write_frame)
    -> write the 70/30 split and the validation report
    all inside a temporary folder that replaces --out only when everything succeeded.
--out must be new, empty or an earlier import (replaced with --overwrite), and must not be or contain --src.
"""
from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from pcdet_memslidar import __version__
from pcdet_memslidar.config import SCHEMA_FILE, cfg_from_yaml_file
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import cvat, ground
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.kitti import MIN_BOX_POINTS
from pcdet_memslidar.io.layout import KittiLayout, write_frame, write_split
from pcdet_memslidar.io.pointclouds import LoadedCloud, read_point_cloud
from pcdet_memslidar.utils.atomic import atomic_dir, check_output_folder, refuse_overlap, write_text
from pcdet_memslidar.utils.progress import progress_bar

FORMATS = ("bfpc", "pcd", "ply", "npy", "bin", "cvat-sly", "cvat-kitti-raw")
UNTIMED_FORMATS = ("bin",)  # formats without a per-point time field
SELF_TIMED_FORMATS = ("bfpc", "kitti")  # formats that record their time unit (KITTI layout: training/time_offset [s])
GROUND_FRAMES = 5  # frames pooled for --estimate-ground (the sensor is static during a recording)
REPORT_NAME = "import_report.json"
COMMAND = "memslidar import"  # the owner of the folders it writes (see utils.atomic.atomic_dir)


@dataclass
class SourceFrame:
    """One frame to import: its name in the source, a loader of its cloud, its cuboids (None: no labels) and its
    start time [s] since the recording's first frame (None: the format does not say)."""

    name: str
    load: Callable[[], LoadedCloud]
    cuboids: cvat.CvatFrame | None = None
    time_s: float | None = None


def _bfpc_frames(src: Path) -> list[SourceFrame]:
    """Frames of one .bfpc recording or of every .bfpc in a folder, timed from the first one's start; a pulse
    without return counts as dropped."""
    frames, first_start_ns = [], None
    for path in _files(src, ".bfpc"):
        recording = read_bfpc(path)
        for index, frame in enumerate(recording.frames):
            first_start_ns = frame.start_time_ns if first_start_ns is None else first_start_ns
            strongest = frame.first_returns()
            cloud = LoadedCloud(points=frame.points[strongest], time=frame.time_offset[frame.return_pulse[strongest]],
                                dropped=int((~frame.returned).sum()), has_intensity=True, time_unit_s=1.0)
            frames.append(SourceFrame(f"{path.name}#{index}", lambda cloud=cloud: cloud,
                                      time_s=(frame.start_time_ns - first_start_ns) * 1e-9))
    return frames


def _files(src: Path, suffix: str) -> list[Path]:
    """`src` itself, or the files with `suffix` in the folder `src` in natural name order."""
    if src.is_file():
        return [src]
    if not src.is_dir():
        raise DataFormatError(src, "not found: give a file or a folder of files")
    files = sorted((p for p in src.iterdir() if p.suffix.lower() == suffix), key=lambda p: cvat.natural_key(p.name))
    if not files:
        raise DataFormatError(src, f"no {suffix} files in this folder")
    return files


def check_time_unit(fmt: str, time_unit_s: float | None) -> None:
    """ConfigError where a time unit is given (--time-unit) for a format that has no time field or records its
    own unit."""
    if time_unit_s is not None and fmt in UNTIMED_FORMATS + SELF_TIMED_FORMATS:
        why = "has no per-point time" if fmt in UNTIMED_FORMATS else "records the unit of its point times"
        raise ConfigError(f"--time-unit is for PCD, PLY and NPY clouds: format {fmt} {why}; drop --time-unit")


def list_frames(fmt: str, src: Path, export_root: Path | None = None, convention: str = "cvat",
                time_unit_s: float | None = None) -> list[SourceFrame]:
    """The source frames of `src` in format `fmt` (for CVAT formats, `export_root` is the unpacked export);
    time_unit_s: seconds per unit of the clouds' time field, for formats that do not record it."""
    check_time_unit(fmt, time_unit_s)
    if fmt == "bfpc":
        return _bfpc_frames(src)
    if fmt in ("pcd", "ply", "npy", "bin"):
        return [SourceFrame(path.name, lambda path=path: read_point_cloud(path, time_unit_s))
                for path in _files(src, "." + fmt)]
    exported = (cvat.read_sly_export(export_root) if fmt == "cvat-sly"
                else cvat.read_kitti_raw_export(export_root, convention))
    return [SourceFrame(frame.name, lambda frame=frame: read_point_cloud(frame.cloud_path, time_unit_s), frame)
            for frame in exported]


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
                   point_cloud_range=None, overwrite: bool = True, time_unit_s: float | None = None) -> dict:
    """Import `src` (format `fmt`, one of FORMATS) into a KITTI-layout dataset at `out`; return the report.
    point_cloud_range: the range of the report's out-of-range count (default: detector_range()). time_unit_s:
    seconds per unit of PCD / PLY / NPY time fields (their time offsets are written only with it).
    `out` must be new, empty or an earlier import (replaced only if `overwrite`) and must not be or contain `src`:
    OutputError otherwise."""
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format {fmt!r}; use one of {', '.join(FORMATS)}")
    if mount is not None and estimate_ground:
        raise ConfigError("give either a mount or estimate_ground, not both")
    src, out = Path(src), Path(out)
    refuse_overlap(out, [src], "--out")
    check_output_folder(out, COMMAND)
    if not overwrite and out.is_dir() and any(out.iterdir()):
        raise OutputError(f"--out {out} holds an earlier import; pass --overwrite to replace it, or choose a new "
                          "folder")
    if fmt.startswith("cvat"):
        with cvat.open_export(src) as root:
            frames = list_frames(fmt, src, root, convention, time_unit_s)
            mount, entry = choose_mount(frames, mount, estimate_ground)
            return import_frames(frames, out, mount, entry, fmt, src, skip_unknown, point_cloud_range)
    frames = list_frames(fmt, src, time_unit_s=time_unit_s)
    mount, entry = choose_mount(frames, mount, estimate_ground)
    return import_frames(frames, out, mount, entry, fmt, src, skip_unknown, point_cloud_range)
