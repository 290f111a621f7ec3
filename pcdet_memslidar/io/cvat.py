"""CVAT 3D-cuboid exports: "Sly Point Cloud Format 1.0" and "Kitti Raw Format 1.0" (both written by Datumaro).

Facts of the formats (from Datumaro's sly_pointcloud and kitti_raw plugins, which CVAT uses to export):
- Sly: <root>/meta.json, <root>/<dataset>/pointcloud/<name>.pcd and <root>/<dataset>/ann/<name>.pcd.json, whose
  "objects" name the class (classTitle) and whose "figures" hold cuboid_3d geometries: position (the cuboid's
  centre), rotation (Euler x, y, z [rad]) and dimensions (size along the box's own x, y, z) in the frame of the PCD.
- Kitti Raw: <root>/tracklet_labels.xml (a boost-serialised list of tracklets: objectType, h, w, l, first_frame and
  one pose per frame from first_frame on; CVAT writes every cuboid as its own one-pose tracklet),
  <root>/frame_list.txt ("index name" per line) and <root>/velodyne_points/data/<name>.pcd. Datumaro writes the
  cuboid's size along x, y, z into w, h, l (so h and w do not mean what KITTI raw says) and the cuboid's centre
  into tx, ty, tz; the KITTI raw devkit defines l, w, h along x, y, z and tx, ty, tz as the bottom centre.
  `convention="cvat"` (default) reads CVAT's exports, `convention="kitti"` files that follow the devkit.
- Rotations are three.js Euler angles in its default order 'XYZ': R = Rx(rx) @ Ry(ry) @ Rz(rz) (box -> cloud).
"""
from __future__ import annotations

import contextlib
import json
import re
import tempfile
import zipfile
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator
from xml.etree import ElementTree

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.kitti import CLASS_NAME, read_text

PERSON_NAMES = ("person", "pedestrian")  # accepted in any letter case
OUTSIDE_TRUNCATION = (2, 99)  # KITTI raw poses marked out of / behind the image: not a labelled frame


@dataclass
class CvatFrame:
    """One exported frame: its point-cloud file and its cuboids (M) in the frame of that cloud."""

    name: str
    cloud_path: Path
    labels: list[str]  # (M,) class names as exported
    centers: np.ndarray  # (M, 3) [m]
    rotations: np.ndarray  # (M, 3, 3) box -> cloud
    sizes: np.ndarray  # (M, 3) along the box's own x, y, z [m]


def euler_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """(3, 3) rotation of three.js Euler angles [rad] in order 'XYZ': Rx(rx) @ Ry(ry) @ Rz(rz)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    return (np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
            @ np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]))


@contextlib.contextmanager
def open_export(src: str | Path) -> Iterator[Path]:
    """Yield the folder of an export given as a folder or as CVAT's .zip (unpacked into a temporary folder)."""
    src = Path(src)
    if src.is_dir():
        yield src
        return
    if not zipfile.is_zipfile(src):
        raise DataFormatError(src, "neither a folder nor a zip archive: give the CVAT export (.zip) or its folder")
    with tempfile.TemporaryDirectory(prefix="memslidar-cvat-") as folder:
        try:
            with zipfile.ZipFile(src) as archive:
                archive.extractall(folder)
        except (zipfile.BadZipFile, EOFError, zlib.error) as error:  # bad CRC-32, damaged or cut-off member
            raise DataFormatError(src, f"corrupt zip archive ({error}): export it from CVAT or copy it again") from None
        yield Path(folder)


def person_mask(frames: list[CvatFrame], skip_unknown: bool, source: Path) -> tuple[list[np.ndarray], Counter]:
    """Per frame (M,) bool: which cuboids are persons; unknown class names raise, or are counted if skip_unknown."""
    masks = [np.array([name.lower() in PERSON_NAMES for name in frame.labels], dtype=bool) for frame in frames]
    unknown = Counter(name for frame, mask in zip(frames, masks) for name, ok in zip(frame.labels, mask) if not ok)
    if unknown and not skip_unknown:
        listed = ", ".join(f"{name!r} ({count})" for name, count in sorted(unknown.items()))
        raise DataFormatError(source, f"unknown label names {listed}; only person / pedestrian (any case) map to "
                                      f"{CLASS_NAME}: rename them in CVAT or pass --skip-unknown-labels to drop them")
    return masks, unknown


def natural_key(name: str) -> list:
    """Sort key that orders embedded numbers by value: frame_2 before frame_10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _cuboids(path: Path, where: list[str], labels, centers, rotations, sizes) -> tuple:
    """Arrays of M cuboids; DataFormatError naming `where[i]` for a non-finite value or a size <= 0."""
    centers = np.array(centers, dtype=np.float64).reshape(-1, 3)
    sizes = np.array(sizes, dtype=np.float64).reshape(-1, 3)
    rotations = np.array(rotations, dtype=np.float64).reshape(-1, 3, 3)
    for i in range(len(centers)):
        if not (np.isfinite(centers[i]).all() and np.isfinite(rotations[i]).all() and np.isfinite(sizes[i]).all()):
            raise DataFormatError(path, f"{where[i]}: NaN or infinite position / rotation / size")
        if (sizes[i] <= 0).any():
            raise DataFormatError(path, f"{where[i]}: non-positive box size {sizes[i].tolist()}; fix the cuboid in "
                                        "CVAT")
    return list(labels), centers, rotations, sizes


# ---------------------------------------------------------------- Sly Point Cloud Format 1.0
def _sly_name(cloud: Path) -> str:
    """`<dataset>/<cloud name>` of <root>/<dataset>/pointcloud/<cloud name>.pcd."""
    return f"{cloud.parent.parent.name}/{cloud.stem}"


def read_sly_export(root: str | Path) -> list[CvatFrame]:
    """Frames of an unpacked "Sly Point Cloud Format 1.0" export, named `<dataset>/<cloud name>` (a project export
    holds one dataset folder per task, whose clouds may share names) and sorted by name; clouds without an
    annotation file have no cuboids; an annotation without its cloud raises."""
    root = Path(root)
    if not (root / "meta.json").is_file():
        raise DataFormatError(root / "meta.json", "missing: not a Sly Point Cloud export (export from CVAT with "
                                                  "'Sly Point Cloud Format 1.0')")
    frames = {}
    for cloud in sorted(root.glob("*/pointcloud/*.pcd")):
        name = _sly_name(cloud)
        frames[name] = CvatFrame(name, cloud, [], np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    for ann_path in sorted(root.glob("*/ann/*.json")):
        cloud = ann_path.parent.parent / "pointcloud" / ann_path.name[:-len(".json")]
        if not cloud.is_file():
            raise DataFormatError(ann_path, f"frame-list mismatch: its point cloud {cloud} is missing from the export")
        try:
            ann = json.loads(read_text(ann_path))
            if not isinstance(ann, dict):
                raise TypeError(f"the file holds a JSON {type(ann).__name__}, not an object with 'objects' and "
                                "'figures'")
            classes = {obj["key"]: obj["classTitle"] for obj in ann.get("objects", [])}
            figures = [f for f in ann.get("figures", []) if f.get("geometryType", "cuboid_3d") == "cuboid_3d"]
            for figure in figures:
                if figure["objectKey"] not in classes:
                    raise KeyError(f"objectKey {figure['objectKey']!r} of a figure names no object")
            where = [f"figure {figure.get('key', i)}" for i, figure in enumerate(figures)]
            geometry = [[[float(f["geometry"][part][axis]) for axis in "xyz"]
                         for part in ("position", "rotation", "dimensions")] for f in figures]
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as error:
            raise DataFormatError(ann_path, f"not a Sly point-cloud annotation ({type(error).__name__}: "
                                            f"{error})") from None
        labels, centers, rotations, sizes = _cuboids(
            ann_path, where, [classes[f["objectKey"]] for f in figures], [g[0] for g in geometry],
            [euler_xyz(*g[1]) for g in geometry], [g[2] for g in geometry])
        name = _sly_name(cloud)
        frames[name] = CvatFrame(name, cloud, labels, centers, rotations, sizes)
    if not frames:
        raise DataFormatError(root, "no point clouds (*/pointcloud/*.pcd) in the Sly export")
    return [frames[name] for name in sorted(frames, key=natural_key)]


# ---------------------------------------------------------------- Kitti Raw Format 1.0
def _frame_names(root: Path) -> dict[int, str]:
    """{frame index: name} from frame_list.txt, else from velodyne_points/data/*.pcd in name order."""
    listing = root / "frame_list.txt"
    if not listing.is_file():
        clouds = sorted((root / "velodyne_points" / "data").glob("*.pcd"), key=lambda p: natural_key(p.stem))
        return {int(p.stem) if p.stem.isdigit() else i: p.stem for i, p in enumerate(clouds)}
    names, first_line = {}, {}  # first_line: ("frame index", index) or ("name", name) -> the line listing it
    for number, line in enumerate(read_text(listing).splitlines(), start=1):
        if line.strip() and not line.startswith("#"):
            index, _, name = line.strip().partition(" ")
            name = name.strip()
            if not index.isdecimal() or not name:
                raise DataFormatError(listing, f"expected 'INDEX NAME', got {line!r}", line=number)
            for key in (("frame index", int(index)), ("name", name)):
                if key in first_line:
                    raise DataFormatError(listing, f"{key[0]} {key[1]!r} is listed again (first on line "
                                                   f"{first_line[key]}); every frame needs its own index and name",
                                          line=number)
                first_line[key] = number
            names[int(index)] = name
    return names


def _number(path: Path, element: ElementTree.Element, tag: str, where: str) -> float:
    node = element.find(tag)
    try:
        return float(node.text)
    except (AttributeError, TypeError, ValueError):
        raise DataFormatError(path, f"{where}: missing or non-numeric <{tag}>") from None


def read_kitti_raw_export(root: str | Path, convention: str = "cvat") -> list[CvatFrame]:
    """Frames of an unpacked "Kitti Raw Format 1.0" export, sorted by frame index (see the module doc for
    `convention`); every frame in frame_list.txt is returned, labelled or not."""
    if convention not in ("cvat", "kitti"):
        raise ValueError(f"convention must be 'cvat' or 'kitti', got {convention!r}")
    root = Path(root)
    xml_path = root / "tracklet_labels.xml"
    if not xml_path.is_file():
        raise DataFormatError(xml_path, "missing: not a Kitti Raw export (export from CVAT with 'Kitti Raw Format "
                                        "1.0')")
    try:
        tracklets = ElementTree.parse(xml_path).getroot().find("tracklets")
    except ElementTree.ParseError as error:
        raise DataFormatError(xml_path, f"malformed XML: {error}", line=error.position[0]) from None
    if tracklets is None:
        raise DataFormatError(xml_path, "no <tracklets> element under the root")
    names = _frame_names(root)
    cuboids: dict[int, list] = {index: [] for index in names}
    for t, tracklet in enumerate(tracklets.findall("item")):
        label = (tracklet.findtext("objectType") or "").strip()
        h, w, l = (_number(xml_path, tracklet, tag, f"tracklet {t}") for tag in ("h", "w", "l"))
        first = (tracklet.findtext("first_frame") or "").strip()
        if not first.isdecimal():
            raise DataFormatError(xml_path, f"tracklet {t}: <first_frame> {first!r} must be a frame index (an "
                                            "integer >= 0)")
        first = int(first)
        poses = tracklet.find("poses")
        for p, pose in enumerate([] if poses is None else poses.findall("item")):
            where = f"tracklet {t} ({label}) pose {p}"
            truncation = pose.findtext("truncation")
            if truncation is not None and truncation.strip().lstrip("-").isdigit() \
                    and int(truncation) in OUTSIDE_TRUNCATION:
                continue
            t_xyz, r_xyz = ([_number(xml_path, pose, tag, where) for tag in tags]
                            for tags in (("tx", "ty", "tz"), ("rx", "ry", "rz")))
            rotation = euler_xyz(*r_xyz)
            size = [w, h, l] if convention == "cvat" else [l, w, h]
            # KITTI raw: the pose is the bottom centre; the centre lies half the height up the box's own z axis
            center = t_xyz if convention == "cvat" else np.asarray(t_xyz) + rotation[:, 2] * h / 2
            if first + p not in cuboids:
                raise DataFormatError(xml_path, f"frame-list mismatch: {where} is on frame {first + p}, which "
                                                f"frame_list.txt / velodyne_points/data do not list")
            cuboids[first + p].append((label, where, center, rotation, size))
    frames = []
    for index in sorted(names):
        cloud = root / "velodyne_points" / "data" / f"{names[index]}.pcd"
        if not cloud.is_file():
            raise DataFormatError(cloud, f"frame-list mismatch: frame {index} is listed but its point cloud is missing")
        items = cuboids[index]
        labels, centers, rotations, sizes = _cuboids(
            xml_path, [c[1] for c in items], [c[0] for c in items], [c[2] for c in items], [c[3] for c in items],
            [c[4] for c in items])
        frames.append(CvatFrame(Path(names[index]).name, cloud, labels, centers, rotations, sizes))
    listed = {frame.cloud_path.resolve() for frame in frames}
    unlisted = [p for p in (root / "velodyne_points" / "data").rglob("*.pcd") if p.resolve() not in listed]
    if unlisted:
        raise DataFormatError(unlisted[0], f"frame-list mismatch: {len(unlisted)} point cloud(s) in "
                                           "velodyne_points/data are not in frame_list.txt")
    if not frames:
        raise DataFormatError(root, "no frames: frame_list.txt and velodyne_points/data/*.pcd are empty")
    return frames
