"""Info files and the ground-truth database of each domain (what `memslidar create-infos` writes).

Per domain folder (KITTI layout, see data/README.md):
    memslidar_infos.pkl     {'fingerprint': str, 'infos': [per-frame info, sorted by frame id]}; an info is
                            {'frame_id', 'point_cloud': {'num_features': 4, 'lidar_idx'},
                             'annos': {'name' (M,) str, 'gt_boxes_lidar' (M, 7) float32, 'num_points_in_gt' (M,) int32}}
    gt_database/<frame>_<class>_<i>.bin   float32 (K, 4) points of object i, relative to its box centre
    memslidar_dbinfos.pkl   {class: [{'name', 'path' (relative to the domain folder), 'frame_id', 'gt_idx',
                             'box3d_lidar' (7,), 'num_points_in_gt', 'difficulty'}]}
The fingerprint (frame ids, point-file sizes, label contents) tells whether the infos still match the frames.
"""
from __future__ import annotations

import hashlib
import pickle
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from pcdet_memslidar.datasets.mixing import Source, make_frames_command
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.io.layout import KittiLayout, read_frame
from pcdet_memslidar.utils.atomic import OWNER_FILE, atomic_dir, check_output_folder, mark_output, write_bytes
from pcdet_memslidar.utils.progress import progress_bar

INFO_FILE = "memslidar_infos.pkl"
DBINFO_FILE = "memslidar_dbinfos.pkl"
DATABASE_DIR = "gt_database"
DATABASE_FILE = re.compile(r".+_.+_\d+\.bin")  # <frame id>_<class>_<object index>.bin, one object's points
COMMAND = "memslidar create-infos"  # the writer named in the gt database's marker (utils.atomic.atomic_dir)
CREATE_COMMAND = "`memslidar create-infos --cfg <the config you train or test with>`"
REBUILD_COMMAND = "`memslidar create-infos --cfg <the config you train or test with> --force`"


def layout_fingerprint(layout: KittiLayout) -> str:
    """Hash of the frame ids, their point-file sizes and their label files' contents."""
    digest = hashlib.sha256()
    for frame_id in layout.frame_ids():
        label = layout.label(frame_id)
        digest.update(f"{frame_id}:{layout.velodyne(frame_id).stat().st_size}:".encode())
        digest.update(label.read_bytes() if label.is_file() else b"<no label>")
    return digest.hexdigest()


def _check_domain(source: Source) -> KittiLayout:
    layout = KittiLayout(source.root)
    if not layout.frame_ids():
        command = make_frames_command(source, source.count)
        raise DataFormatError(layout.training / "velodyne", f"source '{source.name}' has no frames: make them with "
                                                            f"{command}")
    return layout


def _read_pickle(path: Path, source: Source, what: str, keys: tuple[str, ...] = ()) -> dict:
    """The dict pickled in `path` (with `keys`); DataFormatError naming the file and the command that rebuilds it
    when it is truncated, corrupt or not what create-infos writes."""
    try:
        stored = pickle.loads(path.read_bytes())
    except Exception as error:  # a damaged pickle fails with many error types
        reason = f"truncated or corrupt: {type(error).__name__}: {error}"
    else:
        missing = [key for key in keys if key not in stored] if isinstance(stored, dict) else None
        if missing == []:
            return stored
        reason = f"not what create-infos writes: a {type(stored).__name__}{f' without {missing}' if missing else ''}"
    raise DataFormatError(path, f"{what} of source '{source.name}' cannot be read ({reason}): rebuild it with "
                                f"{REBUILD_COMMAND}")


def _read_infos(info_path: Path, source: Source) -> dict:
    """{'fingerprint', 'infos'} of an info file; DataFormatError when it cannot be read."""
    return _read_pickle(info_path, source, "info file", ("fingerprint", "infos"))


def _adopt_unmarked_database(database: Path) -> None:
    """Mark a gt database written before folders carried their writer's marker (utils.atomic.OWNER_FILE) as
    create-infos' own, so that a rebuild may replace it: only when it holds nothing but create-infos' object files."""
    if (database.is_dir() and not (database / OWNER_FILE).exists()
            and all(entry.is_file() and DATABASE_FILE.fullmatch(entry.name) for entry in database.iterdir())):
        mark_output(database, COMMAND)


def create_domain_infos(source: Source, force: bool = False) -> list[dict]:
    """Write (or keep, when up to date and not `force`) the infos and gt database of `source`'s folder; an info
    file that cannot be read is rebuilt."""
    layout = _check_domain(source)
    info_path = source.root / INFO_FILE
    fingerprint = layout_fingerprint(layout)
    if info_path.is_file() and not force:
        try:
            stored = _read_infos(info_path, source)
        except DataFormatError as error:
            print(f"{error}; rebuilding it")
        else:
            if stored["fingerprint"] == fingerprint:
                return stored["infos"]
    _adopt_unmarked_database(source.root / DATABASE_DIR)
    check_output_folder(source.root / DATABASE_DIR, COMMAND)  # before the old info file goes
    info_path.unlink(missing_ok=True)
    infos, db_infos = [], defaultdict(list)
    with atomic_dir(source.root / DATABASE_DIR, COMMAND) as database:
        for frame_id in progress_bar(layout.frame_ids(), desc=f"infos + gt database of {source.name}", leave=False):
            frame = read_frame(layout, frame_id)
            points, boxes, names = frame["points"], frame["gt_boxes"], np.asarray(frame["gt_names"])
            inside = points_in_boxes_mask(points, boxes)
            infos.append({
                "frame_id": frame_id,
                "point_cloud": {"num_features": points.shape[1], "lidar_idx": frame_id},
                "annos": {"name": names, "gt_boxes_lidar": boxes.astype(np.float32),
                          "num_points_in_gt": inside.sum(axis=0).astype(np.int32)},
            })
            for index, (name, box) in enumerate(zip(names, boxes)):
                object_points = points[inside[:, index]].astype(np.float32)
                object_points[:, :3] -= box[:3]
                file_name = f"{frame_id}_{name}_{index}.bin"
                object_points.tofile(database / file_name)
                db_infos[str(name)].append({
                    "name": str(name), "path": f"{DATABASE_DIR}/{file_name}", "frame_id": frame_id, "gt_idx": index,
                    "box3d_lidar": box.astype(np.float32), "num_points_in_gt": int(len(object_points)),
                    "difficulty": 0,
                })
    write_bytes(source.root / DBINFO_FILE, pickle.dumps(dict(db_infos)))
    write_bytes(info_path, pickle.dumps({"fingerprint": fingerprint, "infos": infos}))
    return infos


def load_domain_infos(source: Source) -> list[dict]:
    """The infos of `source`'s folder; DataFormatError with the command to run when missing or out of date."""
    layout = _check_domain(source)
    info_path = source.root / INFO_FILE
    if not info_path.is_file():
        raise DataFormatError(info_path, f"info file of source '{source.name}' is missing: run {CREATE_COMMAND}")
    stored = _read_infos(info_path, source)
    if stored["fingerprint"] != layout_fingerprint(layout):
        raise DataFormatError(info_path, f"info file of source '{source.name}' no longer matches the frames in "
                                         f"{source.root} (frames were added or changed): run {CREATE_COMMAND}")
    return stored["infos"]


def load_db_infos(source: Source) -> dict:
    """The gt database infos {class: [...]} of `source`'s folder."""
    path = source.root / DBINFO_FILE
    if not path.is_file():
        raise DataFormatError(path, f"gt database of source '{source.name}' is missing: run {CREATE_COMMAND}")
    return _read_pickle(path, source, "gt database")
