"""The input formats: one registry of what each format is and how its frames are read.

`memslidar import` (io.importer), `memslidar detect` (monitor.detect), site backgrounds (sim.site) and compositing
(sim.composite) take their lists of formats and their readers from FORMATS. A format is read in one of five ways:

    read_fields   a point cloud per file -> its (N,) columns by name (x, y, z, intensity, time: see
                  io.pointclouds.cloud_from_fields): .pcd, .ply, .npy, .bin; returns only
    read_pulses   a recording per file -> frames of every pulse of the scan pattern, with or without a return: .bfpc
    read_frames   a recording per file, or per folder (with is_recording telling such a folder), a topic (None: its
                  only one) and a time unit -> frames of returns with their recorded start times: ROS 2 bags
    read_layout   a folder layout -> its frames (with is_layout telling such a folder): the KITTI layout
    read_export   an unpacked annotation export and a box convention -> its labelled frames: CVAT's

Adding a format is a module with its reader and one line at the end of this file:

    register_format(InputFormat("xyz", (".xyz",), read_fields=read_xyz_fields, timed=False))
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.io import bfpc, cvat, layout, pointclouds, rosbag
from pcdet_memslidar.io.frames import PulseRecording, SourceFrame
from pcdet_memslidar.io.pointclouds import LoadedCloud, cloud_from_fields


@dataclass(frozen=True)
class InputFormat:
    """One input format: name (the value of --format), suffixes (lower-case file suffixes with the dot; none for a
    folder layout or an export), exactly one reader (module docstring), whether its points have a per-point time
    (timed) and whether it records the unit of those times (self_timed: --time-unit does not apply)."""

    name: str
    suffixes: tuple[str, ...] = ()
    read_fields: Callable[[Path], dict[str, np.ndarray]] | None = None
    read_pulses: Callable[[Path], PulseRecording] | None = None
    read_frames: Callable[[Path, str | None, float | None], list[SourceFrame]] | None = None
    is_recording: Callable[[Path], bool] | None = None
    read_layout: Callable[[Path], list[SourceFrame]] | None = None
    is_layout: Callable[[Path], bool] | None = None
    read_export: Callable[[Path, str], list[cvat.CvatFrame]] | None = None
    timed: bool = True
    self_timed: bool = False

    def __post_init__(self):
        readers = [self.read_fields, self.read_pulses, self.read_frames, self.read_layout, self.read_export]
        if sum(reader is not None for reader in readers) != 1:
            raise ValueError(f"format {self.name!r}: give exactly one of read_fields, read_pulses, read_frames, "
                             "read_layout, read_export")
        if (self.read_layout is None) != (self.is_layout is None):
            raise ValueError(f"format {self.name!r}: a folder layout needs both read_layout and is_layout")
        if self.is_recording is not None and self.read_frames is None:
            raise ValueError(f"format {self.name!r}: is_recording tells a folder that read_frames reads")
        if bool(self.suffixes) != any(reader is not None for reader in readers[:3]):
            raise ValueError(f"format {self.name!r}: a format of files has suffixes, a layout or an export none")
        if any(not suffix.startswith(".") or suffix != suffix.lower() for suffix in self.suffixes):
            raise ValueError(f"format {self.name!r}: give suffixes in lower case with the dot, e.g. '.pcd'")

    @property
    def pulses(self) -> bool:
        """Whether it carries every pulse of the scan pattern, with or without a return (else returns only)."""
        return self.read_pulses is not None

    @property
    def topics(self) -> bool:
        """Whether its recordings hold topics, of which one is read (--topic)."""
        return self.read_frames is not None

    def whole_folder(self, src: Path) -> bool:
        """Whether `src` is a folder that is one layout or one recording of this format (not a folder of its
        files)."""
        test = self.is_layout or self.is_recording
        return test is not None and src.is_dir() and test(src)

    @property
    def layout(self) -> bool:
        """Whether it is a folder layout."""
        return self.read_layout is not None

    @property
    def labelled(self) -> bool:
        """Whether it is an annotation export: its frames come with cuboids."""
        return self.read_export is not None


FORMATS: dict[str, InputFormat] = {}  # name -> format, in registration order (the order of the --format choices)


def register_format(fmt: InputFormat) -> InputFormat:
    """Add `fmt` to FORMATS; ValueError where its name or one of its suffixes is a registered format's."""
    if fmt.name in FORMATS:
        raise ValueError(f"format {fmt.name!r} is registered already: choose another name")
    for other in FORMATS.values():
        shared = sorted(set(other.suffixes) & set(fmt.suffixes))
        if shared:
            raise ValueError(f"format {fmt.name!r}: suffix {shared[0]} belongs to format {other.name!r}: choose "
                             "another")
    FORMATS[fmt.name] = fmt
    return fmt


def get_format(name: str) -> InputFormat:
    """The registered format `name`; ConfigError naming the registered ones otherwise."""
    if name not in FORMATS:
        raise ConfigError(f"unknown format {name!r}; use one of {', '.join(FORMATS)}")
    return FORMATS[name]


def file_formats() -> list[InputFormat]:
    """The formats read from files by their suffix (a point cloud or a recording per file)."""
    return [fmt for fmt in FORMATS.values() if fmt.suffixes]


def format_of(src: Path, formats: Iterable[InputFormat], fix: str) -> InputFormat:
    """The one of `formats` that `src` is in: a folder that is one layout or recording (whole_folder), else the
    format of the file's suffix or of the suffixes of the folder's files; DataFormatError naming what was found and
    `fix` otherwise."""
    formats = list(formats)
    whole = next((fmt for fmt in formats if fmt.whole_folder(src)), None)
    if whole is not None:
        return whole
    files = [src] if src.is_file() else sorted(p for p in src.iterdir() if p.is_file()) if src.is_dir() else []
    found = {fmt.name: fmt for fmt in formats for path in files if path.suffix.lower() in fmt.suffixes}
    if len(found) != 1:
        seen = ", ".join(sorted({path.suffix or "(none)" for path in files})) or "nothing"
        raise DataFormatError(src, f"cannot tell the format (found {seen}): {fix}")
    return found.popitem()[1]


def format_files(src: Path, fmt: InputFormat) -> list[Path]:
    """`src` itself (a file, or a folder that is one recording), or the files with a suffix of `fmt` in the folder
    `src` in natural name order."""
    if src.is_file() or fmt.whole_folder(src):
        return [src]
    if not src.is_dir():
        raise DataFormatError(src, "not found: give a file or a folder of files")
    files = sorted((p for p in src.iterdir() if p.suffix.lower() in fmt.suffixes),
                   key=lambda p: cvat.natural_key(p.name))
    if not files:
        raise DataFormatError(src, f"no {' / '.join(fmt.suffixes)} files in this folder")
    return files


def read_point_cloud(path: str | Path, time_unit_s: float | None = None) -> LoadedCloud:
    """The cloud of a file of a format with one point cloud per file (read_fields), chosen by its suffix;
    time_unit_s: seconds per unit of its time field, which these formats do not record (None: the times have no
    unit, so no time offsets)."""
    path = Path(path)
    clouds = [fmt for fmt in FORMATS.values() if fmt.read_fields is not None]
    fmt = next((fmt for fmt in clouds if path.suffix.lower() in fmt.suffixes), None)
    if fmt is None:
        suffixes = ", ".join(suffix for fmt in clouds for suffix in fmt.suffixes)
        raise DataFormatError(path, f"unknown point-cloud suffix {path.suffix!r}; use one of {suffixes}")
    if not path.is_file():
        raise DataFormatError(path, "file not found")
    return cloud_from_fields(fmt.read_fields(path), path, time_unit_s)


def time_unit_clouds() -> str:
    """The formats whose per-point times may need --time-unit (timed, unit not always recorded) as text, e.g.
    'PCD, PLY, NPY and ROSBAG2'."""
    names = [fmt.name.upper() for fmt in FORMATS.values()
             if (fmt.read_fields or fmt.read_frames) and fmt.timed and not fmt.self_timed]
    return ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else "".join(names)


def check_time_unit(fmt: str, time_unit_s: float | None) -> None:
    """ConfigError where a time unit is given (--time-unit) for a format that has no time field or records its
    own unit."""
    format_ = get_format(fmt)
    if time_unit_s is not None and (not format_.timed or format_.self_timed):
        why = "has no per-point time" if not format_.timed else "records the unit of its point times"
        raise ConfigError(f"--time-unit is for {time_unit_clouds()} clouds: format {fmt} {why}; drop --time-unit")


def check_topic(fmt: str, topic: str | None) -> None:
    """ConfigError where a topic is given (--topic) for a format whose recordings hold no topics."""
    if topic is not None and not get_format(fmt).topics:
        names = " and ".join(name for name, format_ in FORMATS.items() if format_.topics)
        raise ConfigError(f"--topic is for {names} recordings: format {fmt} has no topics; drop --topic")


def list_frames(fmt: str, src: str | Path, time_unit_s: float | None = None, convention: str = "cvat",
                topic: str | None = None) -> list[SourceFrame]:
    """The frames of `src` in format `fmt` (a name in FORMATS) in recording order. For an annotation export `src`
    is the unpacked export (cvat.open_export) and `convention` its box convention (cvat.read_kitti_raw_export);
    time_unit_s: seconds per unit of the clouds' time field, for formats that do not (always) record it; topic: the
    topic to read, for formats whose recordings hold topics (None: their only point-cloud topic)."""
    check_time_unit(fmt, time_unit_s)
    check_topic(fmt, topic)
    format_, src = get_format(fmt), Path(src)
    if format_.layout:
        return format_.read_layout(src)
    if format_.labelled:
        return [SourceFrame(frame.name, functools.partial(read_point_cloud, frame.cloud_path, time_unit_s), frame)
                for frame in format_.read_export(src, convention)]
    files = format_files(src, format_)
    if format_.read_fields is None:  # recordings of many frames
        return _recorded_frames(format_, files, topic, time_unit_s)
    return [SourceFrame(path.name, functools.partial(read_point_cloud, path, time_unit_s)) for path in files]


def _recorded_frames(fmt: InputFormat, files: list[Path], topic: str | None, time_unit_s: float | None
                     ) -> list[SourceFrame]:
    """The frames of the recordings `files` (read_frames or read_pulses), timed from the first frame's recorded
    start."""
    frames = [frame for path in files for frame in (
        fmt.read_frames(path, topic, time_unit_s) if fmt.read_frames else _strongest_returns(fmt.read_pulses(path)))]
    first_ns = frames[0].stamp_ns if frames else 0
    return [dataclasses.replace(frame, time_s=(frame.stamp_ns - first_ns) * 1e-9) for frame in frames]


def _strongest_returns(recording: PulseRecording) -> list[SourceFrame]:
    """The frames of a recording of pulses as their strongest returns with their pulses' times [s], each decoded
    when loaded; a pulse without return counts as dropped."""
    return [SourceFrame(name, functools.partial(_strongest_cloud, recording, index), stamp_ns=stamp_ns)
            for index, (name, stamp_ns) in enumerate(zip(recording.names, recording.start_times_ns))]


def _strongest_cloud(recording: PulseRecording, index: int) -> LoadedCloud:
    """Frame `index` of the recording: the strongest return of each pulse that has one, at its pulse's time [s]."""
    frame = recording.load(index)
    returned = frame.returned
    return LoadedCloud(points=frame.points[returned], time=frame.time_offset[returned],
                       dropped=int((~returned).sum()), has_intensity=True, time_unit_s=1.0)


register_format(InputFormat("bfpc", (".bfpc",), read_pulses=bfpc.read_pulses, self_timed=True))
register_format(InputFormat("pcd", (".pcd",), read_fields=pointclouds.read_pcd_fields))
register_format(InputFormat("ply", (".ply",), read_fields=pointclouds.read_ply_fields))
register_format(InputFormat("npy", (".npy",), read_fields=pointclouds.read_npy_fields))
register_format(InputFormat("bin", (".bin",), read_fields=pointclouds.read_bin_fields, timed=False))
register_format(InputFormat("rosbag2", rosbag.BAG_SUFFIXES, read_frames=rosbag.read_bag, is_recording=rosbag.is_bag))
register_format(InputFormat("kitti", read_layout=layout.read_layout_frames, is_layout=layout.is_layout,
                            self_timed=True))  # time offsets [s] in training/time_offset/
register_format(InputFormat("cvat-sly", read_export=lambda root, convention: cvat.read_sly_export(root)))
register_format(InputFormat("cvat-kitti-raw", read_export=cvat.read_kitti_raw_export))
