"""OpenPCDet's custom dataset layout, and the export of our KITTI layout into it.

    <root>/points/<id>.npy        (N, 4) float32 [x, y, z, intensity]
    <root>/labels/<id>.txt        one box per line: `x y z dx dy dz heading name` (LiDAR frame, z = centre)
    <root>/ImageSets/train.txt    frame ids, one per line (and val.txt)

Public API:
    read_custom_points(path) -> (N, 4) float32            write_custom_points(path, points)
    read_custom_label(path) -> (names (M,) str, boxes (M, 7) float32)
    write_custom_label(path, names, boxes)
    export_custom(kitti_root, out_root) -> int (frames written)   (`memslidar export-custom`)
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout, read_frame, stable_split
from pcdet_memslidar.utils.atomic import atomic_dir, refuse_overlap, write_bytes, write_text
from pcdet_memslidar.utils.progress import progress_bar

COMMAND = "memslidar export-custom"  # the owner of the folders it writes (see utils.atomic.atomic_dir)


def read_custom_points(path: str | Path) -> np.ndarray:
    """(N, 4) float32 [x, y, z, intensity] from a custom-layout .npy file."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "point file not found")
    try:
        points = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise DataFormatError(path, f"not a numeric .npy array ({error})") from None
    if points.ndim != 2 or points.shape[1] != 4 or not np.issubdtype(points.dtype, np.number):
        raise DataFormatError(path, f"expected an (N, 4) numeric array [x, y, z, intensity], "
                                    f"got {points.dtype} {points.shape}")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise DataFormatError(path, f"{bad.sum()} point(s) with NaN or inf, first at index {np.flatnonzero(bad)[0]}")
    return points.astype(np.float32)


def write_custom_points(path: str | Path, points: np.ndarray) -> None:
    """Write (N, 4) points [x, y, z, intensity] as a float32 .npy file (atomic)."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 4 or not np.isfinite(points).all():
        raise DataFormatError(path, f"points must be a finite (N, 4) array, got shape {points.shape}")
    buffer = io.BytesIO()
    np.save(buffer, points.astype(np.float32), allow_pickle=False)
    write_bytes(path, buffer.getvalue())


def read_custom_label(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(names (M,) str, boxes (M, 7) float32 [x, y, z_center, dx, dy, dz, heading]) of a custom label file."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "label file not found")
    names, boxes = [], []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        columns = line.split()
        if not columns:
            continue
        if len(columns) != 8:
            raise DataFormatError(path, f"expected 8 columns `x y z dx dy dz heading name`, got {len(columns)}", number)
        try:
            box = [float(text) for text in columns[:7]]
        except ValueError:
            raise DataFormatError(path, "columns 1-7 must be numbers (x y z dx dy dz heading)", number) from None
        if not np.isfinite(box).all():
            raise DataFormatError(path, "NaN or inf value; write finite numbers", number)
        if min(box[3:6]) < 0:
            raise DataFormatError(path, f"negative size dx dy dz = {' '.join(columns[3:6])}", number)
        names.append(columns[7])
        boxes.append(box)
    return (np.array(names, dtype=str) if names else np.zeros(0, dtype="<U10"),
            np.array(boxes, dtype=np.float32).reshape(-1, 7))


def write_custom_label(path: str | Path, names, boxes: np.ndarray) -> None:
    """Write (M,) names and (M, 7) LiDAR boxes as a custom label file (atomic)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    if len(names) != len(boxes):
        raise DataFormatError(path, f"{len(names)} names for {len(boxes)} boxes")
    if not np.isfinite(boxes).all() or (boxes[:, 3:6] < 0).any():
        raise DataFormatError(path, "boxes must be finite with sizes >= 0")
    lines = []
    for name, box in zip(names, boxes):
        if not str(name) or len(str(name).split()) != 1:
            raise DataFormatError(path, f"class name {str(name)!r} must be one word")
        lines.append(" ".join(f"{value:.4f}" for value in box) + f" {name}\n")
    write_text(path, "".join(lines))


def export_custom(kitti_root: str | Path, out_root: str | Path) -> int:
    """Convert our KITTI layout at `kitti_root` into OpenPCDet's custom layout at `out_root`, written atomically;
    `out_root` must be new, empty or an earlier export (replaced whole), and must not be or contain `kitti_root`
    (OutputError). ImageSets train/val are copied; when the KITTI layout has none, stable_split's are written.
    Returns the number of frames."""
    refuse_overlap(out_root, [kitti_root], "--out")
    layout = KittiLayout(kitti_root)
    frame_ids = layout.frame_ids()
    if not frame_ids:
        raise DataFormatError(layout.training / "velodyne", "no frames (*.bin) to export")
    if layout.image_set("train").is_file() and layout.image_set("val").is_file():
        splits = {name: kitti.read_image_set(layout.image_set(name)) for name in ("train", "val")}
    else:
        splits = dict(zip(("train", "val"), stable_split(frame_ids)))
    with atomic_dir(out_root, COMMAND) as tmp:
        for frame_id in progress_bar(frame_ids, desc=f"export {Path(out_root).name}", unit="frame"):
            frame = read_frame(layout, frame_id)
            write_custom_points(tmp / "points" / f"{frame_id}.npy", frame["points"])
            write_custom_label(tmp / "labels" / f"{frame_id}.txt", frame["gt_names"], frame["gt_boxes"])
        for name, ids in splits.items():
            kitti.write_image_set(tmp / "ImageSets" / f"{name}.txt", ids)
    return len(frame_ids)
