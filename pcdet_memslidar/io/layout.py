"""Our KITTI-layout datasets on disk (data/memslidar/<domain>/, see data/README.md) and their stable split.

    <root>/training/velodyne/<id>.bin     float32 x, y, z, intensity
    <root>/training/label_2/<id>.txt      KITTI labels for the virtual camera
    <root>/training/calib/<id>.txt        the virtual camera's calibration
    <root>/training/metadata/<id>.json    per-frame metadata (sorted keys)
    <root>/ImageSets/<name>.txt           train / val frame ids

Public API:
    KittiLayout(root): .velodyne(id), .label(id), .calib(id), .metadata(id), .image_set(name) -> Path;
                       .frame_ids() -> sorted list[str] of the frames with a velodyne file
    write_frame(layout, frame_id, points, names, boxes, metadata, calib=None) -> None
    read_frame(layout, frame_id) -> dict(frame_id, points, gt_names, gt_boxes, metadata, calib)
    is_layout(folder) -> bool; read_layout_frames(folder) -> list[SourceFrame]: a layout read as a recording
    stable_split(frame_ids, val_fraction=0.3, seed=0) -> (train_ids, val_ids)
    write_split(layout, val_fraction=0.3, seed=0) -> (train_ids, val_ids)
"""
from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.cvat import natural_key
from pcdet_memslidar.io.frames import SourceFrame
from pcdet_memslidar.io.pointclouds import LoadedCloud, cloud_from_fields, read_bin_fields
from pcdet_memslidar.utils.atomic import write_text

SPLIT_BLOCK = 10  # frames per block of the stable split


class KittiLayout:
    """Paths of one KITTI-layout dataset rooted at `root` (frames live in training/)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.training = self.root / "training"

    def velodyne(self, frame_id: str) -> Path:
        return self.training / "velodyne" / f"{frame_id}.bin"

    def time_offset(self, frame_id: str) -> Path:
        """training/time_offset/<id>.bin: float32 per-point time offsets [s] from the frame's first pulse (written by
        `memslidar simulate`; optional)."""
        return self.training / "time_offset" / f"{frame_id}.bin"

    def label(self, frame_id: str) -> Path:
        return self.training / "label_2" / f"{frame_id}.txt"

    def calib(self, frame_id: str) -> Path:
        return self.training / "calib" / f"{frame_id}.txt"

    def metadata(self, frame_id: str) -> Path:
        return self.training / "metadata" / f"{frame_id}.json"

    def image_set(self, name: str) -> Path:
        return self.root / "ImageSets" / f"{name}.txt"

    def frame_ids(self) -> list[str]:
        """Sorted ids of the frames that have a velodyne file (a frame's velodyne file is written last)."""
        return sorted(path.stem for path in (self.training / "velodyne").glob("*.bin"))

    def __repr__(self) -> str:
        return f"KittiLayout({str(self.root)!r})"


def _check_frame_id(frame_id: str) -> str:
    frame_id = str(frame_id)
    if not frame_id or frame_id != frame_id.strip() or len(frame_id.split()) != 1 or "/" in frame_id:
        raise ValueError(f"invalid frame id {frame_id!r}: use a single word without '/', e.g. '000042'")
    return frame_id


def _json_value(value):
    """JSON form of numpy arrays, numpy scalars and paths inside metadata."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"metadata value of type {type(value).__name__} is not JSON-serialisable")


def write_frame(layout: KittiLayout, frame_id: str, points: np.ndarray, names, boxes: np.ndarray,
                metadata: dict, calib: Calibration | None = None, time_offset: np.ndarray | None = None) -> None:
    """Write one frame: (N, 4) points [x, y, z, intensity], (M,) names and (M, 7) LiDAR boxes [x, y, z_center,
    dx, dy, dz, heading], a JSON-serialisable metadata dict, the calib (default: the virtual camera) and, if given,
    the (N,) time offsets [s] of the points (training/time_offset, named in the metadata's time_offset_file).

    Each file is written atomically and the velodyne file last, so an interrupted write never shows up as a frame
    in frame_ids().
    """
    frame_id = _check_frame_id(frame_id)
    calib = calib or Calibration.virtual()
    if time_offset is not None:
        if len(time_offset) != len(points):
            raise ValueError(f"frame {frame_id}: {len(time_offset)} time offsets for {len(points)} points")
        metadata = dict(metadata, time_offset_file=str(layout.time_offset(frame_id).relative_to(layout.root)))
        kitti.write_point_times(layout.time_offset(frame_id), time_offset)
    # one line: json's C encoder (an indent falls back to its pure-Python encoder, 5x slower)
    metadata_text = json.dumps(metadata, sort_keys=True, default=_json_value, allow_nan=False) + "\n"
    write_text(layout.metadata(frame_id), metadata_text)
    kitti.write_calib(layout.calib(frame_id), calib)
    kitti.write_label(layout.label(frame_id), kitti.label_from_boxes(names, boxes, calib))
    kitti.write_points(layout.velodyne(frame_id), points)


def read_frame(layout: KittiLayout, frame_id: str) -> dict:
    """One frame as dict(frame_id, points (N, 4) float32, gt_names (M,) str, gt_boxes (M, 7) float32 LiDAR boxes,
    metadata dict ({} when the frame has no metadata file), calib Calibration)."""
    frame_id = _check_frame_id(frame_id)
    calib = kitti.read_calib(layout.calib(frame_id))
    label = kitti.read_label(layout.label(frame_id))
    metadata_path = layout.metadata(frame_id)
    metadata = {}
    if metadata_path.is_file():
        try:
            metadata = json.loads(metadata_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as error:
            raise DataFormatError(metadata_path, f"invalid JSON ({error.msg})", error.lineno) from None
    return dict(frame_id=frame_id, points=kitti.read_points(layout.velodyne(frame_id)), gt_names=label.name,
                gt_boxes=kitti.boxes_from_label(label, calib).astype(np.float32), metadata=metadata, calib=calib)


def is_layout(folder: Path) -> bool:
    """Whether `folder` is a KITTI-layout dataset (training/velodyne/ in it) or the training/ folder of one."""
    return (folder / "training" / "velodyne").is_dir() or (folder / "velodyne").is_dir()


def read_layout_frames(folder: Path) -> list[SourceFrame]:
    """The frames of a KITTI-layout dataset `folder` (or of its training/ folder) in natural name order, read as a
    recording (io.formats' 'kitti'), each with its points' time offsets [s] where the layout has them
    (training/time_offset/, as `memslidar simulate` and `import` write)."""
    velodyne = folder / "training" / "velodyne" if (folder / "training").is_dir() else folder / "velodyne"
    if not velodyne.is_dir():
        raise DataFormatError(velodyne, "not found: give a KITTI-layout folder (training/velodyne/*.bin)")
    files = sorted((p for p in velodyne.iterdir() if p.suffix.lower() == ".bin"), key=lambda p: natural_key(p.name))
    if not files:
        raise DataFormatError(velodyne, "no .bin files in this folder")
    return [SourceFrame(path.name, functools.partial(_read_velodyne, path)) for path in files]


def _read_velodyne(path: Path) -> LoadedCloud:
    """A velodyne file's cloud with the time offsets [s] of ../time_offset/<name> where that file exists, dropped
    with the invalid points they belong to."""
    fields = read_bin_fields(path)
    times = path.parent.parent / "time_offset" / path.name
    if not times.is_file():
        return cloud_from_fields(fields, path)
    return cloud_from_fields({**fields, "time_offset": kitti.read_point_times(times, len(fields["x"]))}, path,
                             time_unit_s=1.0)


def _slot_rank(seed: int, block: int) -> np.ndarray:
    """(SPLIT_BLOCK,) rank of each slot of `block` in a permutation seeded by (seed, block), numpy-independent."""
    keys = [hashlib.sha256(f"{seed}:{block}:{slot}".encode()).digest() for slot in range(SPLIT_BLOCK)]
    order = sorted(range(SPLIT_BLOCK), key=keys.__getitem__)
    rank = np.empty(SPLIT_BLOCK, dtype=np.int64)
    rank[order] = np.arange(SPLIT_BLOCK)
    return rank


def stable_split(frame_ids, val_fraction: float = 0.3, seed: int = 0) -> tuple[list[str], list[str]]:
    """Split frame ids into (train, val), both sorted: consecutive blocks of 10 sorted ids, each with exactly
    round(10 * val_fraction) val frames chosen by a permutation seeded by (seed, block index).

    A frame's side depends only on its position in the sorted order, so appending frames whose ids sort after the
    existing ones (e.g. 000230, 000231, ...) never moves an existing frame: a frame in a partial last block takes
    the side of its slot, which stays the same when the block fills up.
    """
    val_slots = round(val_fraction * SPLIT_BLOCK)
    if not 0 <= val_fraction <= 1 or abs(val_slots - val_fraction * SPLIT_BLOCK) > 1e-9:
        raise ValueError(f"val_fraction must be a multiple of 0.1 in [0, 1] (blocks of 10 frames), got {val_fraction}")
    frame_ids = sorted(str(frame_id) for frame_id in frame_ids)
    if len(set(frame_ids)) != len(frame_ids):
        raise ValueError("frame ids repeat")
    train, val = [], []
    for index, frame_id in enumerate(frame_ids):
        block, slot = divmod(index, SPLIT_BLOCK)
        if slot == 0:
            rank = _slot_rank(seed, block)
        (val if rank[slot] < val_slots else train).append(frame_id)
    return train, val


def write_split(layout: KittiLayout, val_fraction: float = 0.3, seed: int = 0) -> tuple[list[str], list[str]]:
    """stable_split of the layout's frames, written to ImageSets/train.txt and val.txt; returns (train, val)."""
    train, val = stable_split(layout.frame_ids(), val_fraction, seed)
    kitti.write_image_set(layout.image_set("train"), train)
    kitti.write_image_set(layout.image_set("val"), val)
    return train, val
