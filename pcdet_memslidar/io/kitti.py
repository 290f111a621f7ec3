"""KITTI object-format files: velodyne points, label_2 labels, calib, ImageSets; and label <-> LiDAR boxes.

Public API:
    read_points(path) -> (N, 4) float32 [x, y, z, intensity]        write_points(path, points)
    read_label(path) -> KittiLabel                                    write_label(path, label)
    object_line(path, name) -> int | None                             check_class_case(path, names, class_names)
    boxes_from_label(label, calib) -> (M, 7) float64 LiDAR boxes [x, y, z_center, dx, dy, dz, heading]
    label_from_boxes(names, boxes, calib, scores=None) -> KittiLabel
    read_calib(path) -> Calibration                                   write_calib(path, calib)
    read_image_set(path) -> list[str]                                 write_image_set(path, frame_ids)

A label line is `type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry [score]`: the location is the bottom
centre of the box in the rectified camera frame, ry the rotation around the camera's y axis. In the LiDAR frame
(OpenPCDet): dx = l, dy = w, dz = h, z_center = bottom + h / 2, heading = -(ry + pi / 2).
Every write is atomic; malformed input raises DataFormatError naming the file and line.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.boxes import (
    boxes_camera_to_lidar,
    boxes_lidar_to_camera,
    boxes_to_corners_3d,
    normalize_heading,
)
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.utils.atomic import write_bytes, write_text

POINT_BYTES = 16  # float32 x, y, z, intensity
IMAGE_SIZE = (1242, 375)  # (width, height) [px] of the virtual camera's image, as KITTI's
DONT_CARE = "DontCare"  # KITTI's ignore regions: sizes -1 are allowed on these lines only
CLASS_NAME = "Pedestrian"  # our one class, under KITTI's name (longer names break OpenPCDet's KITTI mapping)
KITTI_CLASSES = ("Car", "Van", "Truck", CLASS_NAME, "Person_sitting", "Cyclist", "Tram", "Misc", DONT_CARE)
MIN_BOX_POINTS = 5  # a person with fewer points is not labelled (simulated or imported; kept in the metadata)


def read_text(path: Path) -> str:
    """The text of a UTF-8 file, without the byte-order mark some editors write first."""
    if not path.is_file():
        raise DataFormatError(path, "file not found")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise DataFormatError(path, f"not a UTF-8 text file ({error.reason})") from None


# ---------------------------------------------------------------------------------------------------- points
def _check_points(path, points: np.ndarray) -> np.ndarray:
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 4:
        raise DataFormatError(path, f"points must have shape (N, 4) [x, y, z, intensity], got {points.shape}")
    if not np.isfinite(points).all():  # one fast pass; locate the bad rows only when there are some
        bad = ~np.isfinite(points).all(axis=1)
        raise DataFormatError(path, f"{bad.sum()} point(s) with NaN or inf, first at point index "
                                    f"{np.flatnonzero(bad)[0]}; drop invalid returns before writing")
    return points


def read_points(path: str | Path) -> np.ndarray:
    """(N, 4) float32 [x, y, z, intensity] from a KITTI velodyne .bin file."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "point file not found")
    data = path.read_bytes()
    if len(data) % POINT_BYTES:
        raise DataFormatError(path, f"size {len(data)} bytes is not a multiple of {POINT_BYTES} "
                                    "(float32 x, y, z, intensity per point): truncated or not a velodyne .bin file")
    return _check_points(path, np.frombuffer(data, dtype="<f4").reshape(-1, 4).copy())


def write_point_times(path: str | Path, times: np.ndarray) -> None:
    """(N,) time offsets [s] of a frame's points -> a training/time_offset .bin file (float32), atomically."""
    write_bytes(Path(path), np.ascontiguousarray(times, dtype="<f4"))


def read_point_times(path: str | Path, num_points: int) -> np.ndarray:
    """(num_points,) float32 time offsets [s] of a frame's points from a training/time_offset .bin file."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "time offset file not found")
    data = path.read_bytes()
    if len(data) != 4 * num_points:
        raise DataFormatError(path, f"{len(data) / 4:g} time offsets for {num_points} points: the frame's velodyne "
                                    "file and this one differ; write the frame again")
    times = np.frombuffer(data, dtype="<f4").copy()
    if not np.isfinite(times).all():
        raise DataFormatError(path, "NaN or inf time offsets: write the frame again")
    return times


def write_points(path: str | Path, points: np.ndarray) -> None:
    """Write (N, 4) [x, y, z, intensity] points as little-endian float32 to a velodyne .bin file (atomic)."""
    points = _check_points(path, points)
    write_bytes(path, np.ascontiguousarray(points, dtype="<f4"))


# ---------------------------------------------------------------------------------------------------- labels
@dataclass
class KittiLabel:
    """The objects of one label_2 file (M objects), named as OpenPCDet's KITTI annos.

    name (M,) str; truncated (M,) float; occluded (M,) int; alpha (M,) rad; bbox (M, 4) [x1, y1, x2, y2] px;
    dimensions (M, 3) [l, h, w] m (OpenPCDet's order; the file stores h w l); location (M, 3) bottom centre in the
    rectified camera frame [m]; rotation_y (M,) rad; score (M,) or None when the file has no score column.
    """

    name: np.ndarray
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bbox: np.ndarray
    dimensions: np.ndarray
    location: np.ndarray
    rotation_y: np.ndarray
    score: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.name)


def _parse_label_line(path: Path, number: int, line: str) -> tuple[str, list[float]]:
    columns = line.split()
    if len(columns) not in (15, 16):
        raise DataFormatError(path, f"expected 15 columns (type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry) "
                                    f"or 16 (plus score), got {len(columns)}", number)
    try:
        values = [float(text) for text in columns[1:]]
    except ValueError:
        bad = next(text for text in columns[1:] if not _is_float(text))
        raise DataFormatError(path, f"non-numeric value {bad!r}; columns 2-{len(columns)} must be numbers",
                              number) from None
    if not np.isfinite(values).all():
        raise DataFormatError(path, "NaN or inf value; write finite numbers", number)
    if values[1] != int(values[1]):
        raise DataFormatError(path, f"occluded must be an integer (0-3), got {columns[2]}", number)
    if min(values[7:10]) < 0 and columns[0] != DONT_CARE:
        raise DataFormatError(path, f"negative size h w l = {' '.join(columns[8:11])}; sizes must be >= 0", number)
    return columns[0], values


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _label_from_rows(names: list[str], rows: np.ndarray, with_score: bool) -> KittiLabel:
    rows = rows.reshape(-1, 15 if with_score else 14)
    return KittiLabel(
        name=np.array(names, dtype=str) if names else np.zeros(0, dtype="<U10"),
        truncated=rows[:, 0].copy(),
        occluded=rows[:, 1].astype(np.int64),
        alpha=rows[:, 2].copy(),
        bbox=rows[:, 3:7].copy(),
        dimensions=rows[:, [9, 7, 8]].copy(),  # file h w l -> l h w
        location=rows[:, 10:13].copy(),
        rotation_y=rows[:, 13].copy(),
        score=rows[:, 14].copy() if with_score else None,
    )


def read_label(path: str | Path) -> KittiLabel:
    """Objects of a KITTI label_2 file (ground truth, or predictions with a 16th score column)."""
    path = Path(path)
    names, rows, with_score, first = [], [], None, None
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        name, values = _parse_label_line(path, number, line)
        if with_score is None:
            with_score, first = len(values) == 15, number
        elif with_score != (len(values) == 15):
            raise DataFormatError(path, f"score column present on some lines only (line {first} has "
                                        f"{15 if with_score else 14} numbers); use it on all lines or none", number)
        names.append(name)
        rows.append(values)
    return _label_from_rows(names, np.array(rows, dtype=np.float64), bool(with_score))


def object_line(path: str | Path, name: str) -> int | None:
    """1-based line of the first object named `name` in the label file `path` (None if there is none)."""
    lines = read_text(Path(path)).splitlines()
    return next((number for number, text in enumerate(lines, start=1) if text.split()[:1] == [name]), None)


def check_class_case(path: str | Path, names, class_names) -> None:
    """DataFormatError naming `path`:line for an object of the label file `path` (its names (M,)) whose class is one
    of `class_names` in another case ('pedestrian'): names are case-sensitive, so it would silently not count."""
    wanted = {str(name).lower(): str(name) for name in class_names}
    for name in sorted(set(map(str, names)) - set(wanted.values())):
        if name.lower() in wanted:
            raise DataFormatError(path, f"class {name!r} is not {wanted[name.lower()]!r} (class names are "
                                        f"case-sensitive), so its objects would not count; rename it to "
                                        f"{wanted[name.lower()]}", object_line(path, name))


def write_label(path: str | Path, label: KittiLabel) -> None:
    """Write `label` as a KITTI label_2 file (with a score column when label.score is not None), atomically."""
    numbers = np.column_stack([label.truncated, label.alpha, np.reshape(label.bbox, (-1, 4)),
                               np.reshape(label.dimensions, (-1, 3))[:, [1, 2, 0]], np.reshape(label.location, (-1, 3)),
                               label.rotation_y] + ([label.score] if label.score is not None else [])).astype(float)
    finite = np.isfinite(numbers).all(axis=1)
    lines = []
    for i, (name, row) in enumerate(zip(label.name, numbers.tolist())):
        name = str(name)
        if not name or any(char.isspace() for char in name):
            raise DataFormatError(path, f"object {i}: class name {name!r} must be one word")
        if not finite[i]:
            raise DataFormatError(path, f"object {i} ({name}): NaN or inf value")
        h, w, l = row[6:9]
        if min(h, w, l) < 0 and name != DONT_CARE:
            raise DataFormatError(path, f"object {i} ({name}): negative size l h w = {l} {h} {w}")
        line = (f"{name} {row[0]:.2f} {int(label.occluded[i])} {row[1]:.4f} "
                + " ".join(f"{v:.2f}" for v in row[2:6]) + " " + " ".join(f"{v:.4f}" for v in row[6:13]))
        if label.score is not None:
            line += f" {row[13]:.6f}"
        lines.append(line + "\n")
    write_text(path, "".join(lines))


# ---------------------------------------------------------------------------------------------------- boxes
def boxes_from_label(label: KittiLabel, calib: Calibration) -> np.ndarray:
    """(M, 7) LiDAR boxes [x, y, z_center, dx, dy, dz, heading] of `label`; heading in [-pi, pi)."""
    camera = np.column_stack([label.location.reshape(-1, 3), label.dimensions.reshape(-1, 3), label.rotation_y])
    return boxes_camera_to_lidar(camera, calib)


def _image_bbox(boxes: np.ndarray, calib: Calibration) -> np.ndarray:
    """(M, 4) [x1, y1, x2, y2] px: the 2D box of the corners of (M, 7) LiDAR boxes that lie in front of the camera,
    projected and clipped to the image; zeros for a box entirely behind the camera."""
    corners = calib.lidar_to_rect(boxes_to_corners_3d(boxes).reshape(-1, 3)).reshape(-1, 8, 3)
    pixels = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2) @ calib.P2.T
    in_front = corners[:, :, 2] > 0.1
    pixels = pixels[:, :, :2] / np.where(in_front, pixels[:, :, 2], 1.0)[:, :, None]
    low = np.where(in_front[:, :, None], pixels, np.inf).min(axis=1)
    high = np.where(in_front[:, :, None], pixels, -np.inf).max(axis=1)
    bbox = np.clip(np.hstack([low, high]), 0, [*IMAGE_SIZE, *IMAGE_SIZE])
    bbox[~in_front.any(axis=1)] = 0.0
    return bbox


def label_from_boxes(names, boxes: np.ndarray, calib: Calibration, scores: np.ndarray | None = None) -> KittiLabel:
    """The KittiLabel of (M, 7) LiDAR boxes [x, y, z_center, dx, dy, dz, heading] named `names` (M,); `scores`
    (M,) for predictions. truncated and occluded are 0; bbox is the projection into the virtual image."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    names = np.array([str(name) for name in names], dtype=str) if len(names) else np.zeros(0, dtype="<U10")
    if len(names) != len(boxes) or (scores is not None and len(scores) != len(boxes)):
        raise ValueError(f"names ({len(names)}), boxes ({len(boxes)}) and scores must have the same length")
    camera = boxes_lidar_to_camera(boxes, calib)
    location, dimensions, rotation_y = camera[:, :3], camera[:, 3:6], camera[:, 6]
    alpha = normalize_heading(rotation_y - np.arctan2(location[:, 0], location[:, 2]))
    return KittiLabel(name=names, truncated=np.zeros(len(boxes)), occluded=np.zeros(len(boxes), dtype=np.int64),
                      alpha=alpha, bbox=_image_bbox(boxes, calib), dimensions=dimensions,
                      location=location, rotation_y=rotation_y,
                      score=None if scores is None else np.asarray(scores, dtype=np.float64).copy())


# ---------------------------------------------------------------------------------------------------- calib
_CALIB_SIZES = {"P0": 12, "P1": 12, "P2": 12, "P3": 12, "R0_rect": 9, "Tr_velo_to_cam": 12, "Tr_imu_to_velo": 12}


def read_calib(path: str | Path) -> Calibration:
    """Calibration (P2, R0_rect, Tr_velo_to_cam) of a KITTI calib file."""
    path = Path(path)
    values = {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        key = key.strip()
        if not sep or key not in _CALIB_SIZES:
            raise DataFormatError(path, f"expected 'KEY: numbers' with KEY one of {', '.join(_CALIB_SIZES)}", number)
        try:
            numbers = np.array([float(text) for text in rest.split()])
        except ValueError:
            raise DataFormatError(path, f"{key}: non-numeric value", number) from None
        if len(numbers) != _CALIB_SIZES[key]:
            raise DataFormatError(path, f"{key}: expected {_CALIB_SIZES[key]} numbers, got {len(numbers)}", number)
        if not np.isfinite(numbers).all():
            raise DataFormatError(path, f"{key}: NaN or inf value", number)
        values[key] = numbers
    missing = [key for key in ("P2", "R0_rect", "Tr_velo_to_cam") if key not in values]
    if missing:
        raise DataFormatError(path, f"missing {', '.join(missing)}; a KITTI calib file needs P2, R0_rect and "
                                    "Tr_velo_to_cam (write_calib(path, Calibration.virtual()) writes one)")
    return Calibration(P2=values["P2"].reshape(3, 4), R0=values["R0_rect"].reshape(3, 3),
                       V2C=values["Tr_velo_to_cam"].reshape(3, 4))


def write_calib(path: str | Path, calib: Calibration) -> None:
    """Write `calib` as a KITTI calib file (P0-P3 all P2, Tr_imu_to_velo identity), atomically."""
    write_text(path, _calib_text(*(np.asarray(matrix, dtype=np.float64).tobytes()
                                   for matrix in (calib.P2, calib.R0, calib.V2C))))


@functools.lru_cache(maxsize=8)
def _calib_text(p2: bytes, r0: bytes, v2c: bytes) -> str:
    """The calib file of P2 (3, 4), R0 (3, 3) and V2C (3, 4) given as float64 bytes (cached: the frames of a
    dataset share one camera)."""
    p2, r0, v2c = (np.frombuffer(matrix) for matrix in (p2, r0, v2c))
    matrices = {"P0": p2, "P1": p2, "P2": p2, "P3": p2, "R0_rect": r0, "Tr_velo_to_cam": v2c,
                "Tr_imu_to_velo": np.eye(3, 4).ravel()}
    return "".join(f"{key}: " + " ".join(f"{v:.12e}" for v in matrix.tolist()) + "\n"
                   for key, matrix in matrices.items())


# ---------------------------------------------------------------------------------------------------- ImageSets
def read_image_set(path: str | Path) -> list[str]:
    """Frame ids of an ImageSets file, one per line, in file order."""
    path = Path(path)
    ids, seen = [], {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        frame_id = line.strip()
        if not frame_id:
            continue
        if len(frame_id.split()) != 1:
            raise DataFormatError(path, f"expected one frame id per line, got {frame_id!r}", number)
        if frame_id in seen:
            raise DataFormatError(path, f"frame id {frame_id} repeats line {seen[frame_id]}", number)
        seen[frame_id] = number
        ids.append(frame_id)
    return ids


def write_image_set(path: str | Path, frame_ids) -> None:
    """Write frame ids one per line (atomic)."""
    frame_ids = [str(frame_id) for frame_id in frame_ids]
    bad = [frame_id for frame_id in frame_ids if len(frame_id.split()) != 1 or frame_id != frame_id.strip()]
    if bad:
        raise DataFormatError(path, f"invalid frame id {bad[0]!r}: ids are single words")
    if len(set(frame_ids)) != len(frame_ids):
        raise DataFormatError(path, "frame ids repeat")
    write_text(path, "".join(f"{frame_id}\n" for frame_id in frame_ids))
