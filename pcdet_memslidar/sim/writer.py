"""Write a simulated domain as a KITTI-layout dataset: deterministic, resumable, sharded, parallel.

    <out>/simulation.json                  site, seed, package version and their fingerprint
    <out>/training/velodyne|label_2|calib|metadata/<id>   via pcdet_memslidar.io.layout.write_frame
    <out>/training/time_offset/<id>.bin    float32 (N,) time of each point [s] from the frame start, same order
                                           as the velodyne file
    <out>/ImageSets/train.txt, val.txt     the stable 70/30 split, written once all frames exist

Frame i is made from the seed sequence (seed, i) only, so any split of the frames over workers, shards or
interrupted runs gives byte-identical files. A frame is complete once its velodyne file exists (written last) and
every file of it is whole: complete frames are skipped, damaged ones made again. An output folder made with other
settings is refused (fingerprint mismatch). Worker processes end when their parent dies.
In one process, FRAME_THREADS frames are made at a time, in threads.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

import pcdet_memslidar
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.io.kitti import read_label, write_points
from pcdet_memslidar.io.layout import KittiLayout, write_frame, write_split
from pcdet_memslidar.sim.bodies import BANK_PATH
from pcdet_memslidar.sim.composite import composite_frame, recording_sha256
from pcdet_memslidar.sim.frame import Frame, simulate_frame, simulate_sequence
from pcdet_memslidar.sim.memory import keep_freed_memory
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.sensor import get_sensor
from pcdet_memslidar.sim.site import Background, Site, Viewpoint
from pcdet_memslidar.utils.atomic import atomic_dir, write_text
from pcdet_memslidar.utils.processes import bounded_map, exit_with_parent
from pcdet_memslidar.utils.progress import progress_bar

SETTINGS_FILE = "simulation.json"
SEQUENCE_COMMAND = "memslidar simulate --sequence"  # the owner of the sequence folders it writes
EMPTY_RECORDING_COMMAND = "memslidar site train"  # the owner of a scene site's simulated empty recording
FRAME_THREADS = 2  # frames made at a time by one process
MAX_FRAMES = 10 ** 6  # frame ids have six digits


def frame_id(index: int) -> str:
    return f"{index:06d}"


def domain_settings(site: Site, seed: int, sequence_length: int | None = None) -> dict:
    """Everything that makes a domain's frames (or one sequence of sequence_length frames), with its sha256
    fingerprint under 'fingerprint'."""
    settings = dict(domain=site.to_dict(), pattern=dataclasses.asdict(get_pattern(site.pattern)),
                    sensor=dataclasses.asdict(get_sensor(site.sensor)), seed=int(seed),
                    package_version=pcdet_memslidar.__version__,
                    body_bank_sha256=hashlib.sha256(BANK_PATH.read_bytes()).hexdigest())
    if site.background is not None:
        settings["background_sha256"] = recording_sha256(site.background)
    if sequence_length is not None:
        settings["sequence_length"] = int(sequence_length)
    text = json.dumps(settings, sort_keys=True, default=float)
    settings["fingerprint"] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return json.loads(json.dumps(settings, default=float))


def parse_shard(text: str) -> tuple[int, int]:
    """'I/N' -> (I, N), 0 <= I < N."""
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise ConfigError(f"--shard must look like I/N (e.g. 0/4), got '{text}'") from None
    if not 0 <= index < count:
        raise ConfigError(f"--shard {text}: need 0 <= I < N")
    return index, count


def write_simulated_frame(layout: KittiLayout, index: int, frame: Frame, fingerprint: str) -> None:
    """Write frame `index`: its time offsets first, then the KITTI files (velodyne last)."""
    write_frame(layout, frame_id(index), frame.points, frame.names, frame.boxes,
                dict(frame.metadata, fingerprint=fingerprint), time_offset=frame.time_offset)


def make_frame(site: Site, seed: int, index: int, threads: int = 0) -> Frame:
    """Frame `index` of `site` with dataset seed `seed`: simulated, or composited into its background recording."""
    if site.background is not None:
        return composite_frame(site, seed, index, threads=threads)
    return simulate_frame(site, seed, index, threads=threads)


def _write_one(args) -> int:
    """Make and write frame `index`; returns its number of points."""
    site, seed, index, root, fingerprint, threads = args
    frame = make_frame(site, seed, index, threads=threads)
    write_simulated_frame(KittiLayout(root), index, frame, fingerprint)
    return len(frame.points)


def _check_settings(root: Path, settings: dict) -> None:
    """Write <root>/simulation.json, or refuse a folder made with other settings or by something else."""
    path = root / SETTINGS_FILE
    if path.is_file():
        try:
            existing = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"invalid JSON ({error.msg}); delete the folder to regenerate",
                                  error.lineno) from None
        if existing.get("fingerprint") != settings["fingerprint"]:
            raise DataFormatError(path, f"this folder holds data made with other settings (fingerprint "
                                        f"{existing.get('fingerprint')}, asked for {settings['fingerprint']}: "
                                        f"domain, seed, sensor, pattern or package version differ); choose "
                                        f"another --out or delete the folder to regenerate")
    elif root.is_dir() and any(not entry.name.startswith(".") for entry in root.iterdir()):
        raise OutputError(f"{root} holds files that `memslidar simulate` did not make (no {SETTINGS_FILE}); "
                          f"choose another --out, or move them away yourself")
    else:
        write_text(path, json.dumps(settings, sort_keys=True, indent=1) + "\n")


def _complete_frames(layout: KittiLayout, frames: int, shard: tuple[int, int], fingerprint: str) -> tuple[set, int]:
    """Indices of the frames of `shard` that are on disk whole (metadata of these settings, label, calib, and as many
    time offsets as points), and how many others are on disk damaged (to be made again)."""
    complete, damaged = set(), 0
    for name in layout.frame_ids():
        if not name.isdigit() or int(name) >= frames or int(name) % shard[1] != shard[0]:
            continue
        try:
            stored = json.loads(layout.metadata(name).read_text(encoding="utf-8")).get("fingerprint")
            points = layout.velodyne(name).stat().st_size
            whole = (points % 16 == 0 and layout.time_offset(name).stat().st_size * 4 == points
                     and layout.calib(name).is_file())
            read_label(layout.label(name))
        except (OSError, ValueError):  # missing or unreadable file, invalid JSON, malformed label
            stored, whole = fingerprint, False
        if stored != fingerprint:
            raise DataFormatError(layout.metadata(name), f"frame made with other settings (fingerprint {stored}, "
                                                         f"asked for {fingerprint}); delete the folder")
        if whole:
            complete.add(int(name))
        else:
            damaged += 1
    return complete, damaged


def _start_worker() -> None:
    keep_freed_memory()
    exit_with_parent()


def simulate_dataset(site: Site, frames: int, out: str | Path, seed: int = 0, workers: int = 1,
                     shard: tuple[int, int] = (0, 1), progress: bool = True) -> dict:
    """Make frames 0..frames-1 of `site` (those of `shard` (I, N): index % N == I) under `out`.

    Frames already on disk whole are skipped; damaged ones (a truncated file, a missing label, ...) are made again.
    Returns dict(written, skipped, remade, points, complete, fingerprint): complete = all frames exist and
    ImageSets are written."""
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1 (1 = in this process), got {workers}")
    if not 1 <= frames <= MAX_FRAMES:
        raise ConfigError(f"--frames must be between 1 and {MAX_FRAMES:,} (frame ids have six digits), got {frames}")
    if seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {seed}")
    root = Path(out)
    settings = domain_settings(site, seed)
    _check_settings(root, settings)
    layout = KittiLayout(root)
    complete, remade = _complete_frames(layout, frames, shard, settings["fingerprint"])
    indices = range(shard[0], frames, shard[1])
    jobs = ((site, seed, index, str(root), settings["fingerprint"], 1 if workers > 1 else 0)
            for index in indices if index not in complete)
    count = len(indices) - len(complete)
    keep_freed_memory()  # reuse the memory of each frame's numpy temporaries (see sim/memory.py)
    points = 0
    if workers > 1 and count > 1:
        pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_start_worker)
    else:  # frames in threads: their compiled loops, large numpy operations and file writes run outside
        # Python's interpreter lock (Open3D's cast_rays and the Python parts do not: docs/benchmarks.md#simulator-speed)
        pool = ThreadPoolExecutor(FRAME_THREADS)
    with pool, progress_bar(total=count, desc=f"simulate {site.name}", unit="frame", enabled=progress) as bar:
        for points_of_frame in bounded_map(pool, _write_one, jobs, ahead=4 * max(workers, FRAME_THREADS)):
            points += points_of_frame
            bar.update()
    existing = set(layout.frame_ids())
    complete = all(frame_id(i) in existing for i in range(frames))
    if complete:
        write_split(layout)
    return dict(written=count, skipped=len(indices) - count, remade=remade, points=int(points), complete=complete,
                fingerprint=settings["fingerprint"])


def simulate_sequence_dataset(site: Site, length: int, out: str | Path, seed: int = 0,
                              progress: bool = True) -> dict:
    """One sequence of `length` frames of `site` (sim.frame.simulate_sequence, sequence seed `seed`) as a
    KITTI-layout dataset at `out`, written whole into a temporary folder that replaces `out` at the end (a
    sequence is made in order, so it is not resumed). Returns dict(written, points, people, fingerprint)."""
    if not 2 <= length <= MAX_FRAMES:
        raise ConfigError(f"--sequence must be between 2 and {MAX_FRAMES:,} frames, got {length}")
    if site.background is not None:
        raise ConfigError(f"site '{site.name}' composites people into a background recording, frame by frame: "
                          f"--sequence needs a site with a scene")
    if seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {seed}")
    settings = domain_settings(site, seed, sequence_length=length)
    points, people = 0, 0
    keep_freed_memory()
    bar = progress_bar(total=length, desc=f"simulate a {site.name} sequence", unit="frame", enabled=progress)
    with atomic_dir(out, SEQUENCE_COMMAND) as tmp, bar:
        write_text(tmp / SETTINGS_FILE, json.dumps(settings, sort_keys=True, indent=1) + "\n")
        layout = KittiLayout(tmp)
        for index, frame in enumerate(simulate_sequence(site, seed, length)):
            write_simulated_frame(layout, index, frame, settings["fingerprint"])
            points, people = points + len(frame.points), len(frame.metadata["people"])
            bar.update()
        write_split(layout)
    return dict(written=length, points=int(points), people=people, fingerprint=settings["fingerprint"])


def simulate_empty_recording(site: Site, frames: int, out: str | Path, seed: int = 0) -> Site:
    """What a scene site's sensor records with nobody there: `frames` frames of `site` without people, written as a
    folder of .bin frames in the sensor frame (out/<index>.bin, as a recording's point clouds), whole into a
    temporary folder that replaces `out`, or read back when `out` holds them already. Returns the site with that
    folder as its background (a background site: `site train` composites people into it)."""
    if site.background is not None:
        return site
    if len(site.viewpoints) != 1:
        raise ConfigError(f"site '{site.name}' has {len(site.viewpoints)} viewpoints: a site's empty recording is "
                          f"made from one mount; give it `scene` and `mount`")
    out, mount = Path(out), site.viewpoints[0].mount
    names = [f"{index:06d}.bin" for index in range(frames)]
    if not (out.is_dir() and sorted(path.name for path in out.glob("*.bin")) == names):
        empty = dataclasses.replace(site, people=(0, 0))
        with atomic_dir(out, EMPTY_RECORDING_COMMAND) as tmp:
            for index, name in enumerate(names):
                points = simulate_frame(empty, seed, index).points
                write_points(tmp / name, np.c_[mount.ground_to_sensor(points[:, :3]), points[:, 3]])
    return dataclasses.replace(site, viewpoints=(Viewpoint(None, mount),), background=Background(str(out)))
