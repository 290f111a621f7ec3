"""Reading speed of recordings: the time per frame to read the same frames from a rosbag2 folder (MCAP and sqlite3
storage) and from KITTI .bin files, and the bundled Cube 1 .bfpc recording against its own frames as KITTI files,
measured in one run; beside the bags, rosbags' floor: each message read once, without listing.

    python tools/benchmark_read.py                          # 50 frames of 30 000 points, median of 5 reads
    python tools/benchmark_read.py --frames 200 --points 100000

The frames are made here (seed 0: random points, each with a time offset) as a KITTI layout with
training/time_offset/ (io.layout.write_frame) and exported as bags (io.rosbag.export_bag: float32 x, y, z, intensity
and time); the .bfpc's frames (strongest returns and their times) are written as a second KITTI layout. A read is
what `memslidar detect` and `import` do: list the frames (io.formats.list_frames), then load every cloud with its
time offsets. The floor rows read a bag as a single pass would: frame counts from its metadata, every message
read and decoded once, in order (io.rosbag.BagMessages: no listing, so no header stamps or layout checks before the
first frame loads). Each source is read once before timing (a warm page cache), then the sources are read in turn
--repeats times (so that a change in the machine's load touches all of them); a source's time is the median of its
reads, in wall-clock time and in CPU time of this process (which other processes on a busy machine change less), the
latter split into listing the frames and loading them; ratio = that source / the KITTI layout of the same frames.
One more read per source, traced by Python's tracemalloc, gives the most memory a read holds at once. Prints a
Markdown table and the load average; JSON to output/benchmark/read_benchmark.json.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from pcdet_memslidar.io.formats import list_frames
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.io.rosbag import STORAGES, BagMessages, export_bag
from pcdet_memslidar.utils.atomic import write_text

FRAME_PERIOD_S = 0.1
TOPIC = "/points"  # export_bag's
ONCE = "rosbag2, read once"  # the floor rows' format
BUNDLED_BFPC = Path(__file__).resolve().parents[1] / "pcdet_memslidar/assets/blickfeld/cube1_sample_2020.bfpc"


def make_sources(root: Path, frames: int, points: int) -> dict[str, tuple[str, Path]]:
    """{source name: (format, path)}: the KITTI layout of `frames` random frames of `points` points, and its bags."""
    rng = np.random.default_rng(0)
    layout = KittiLayout(root / "kitti")
    for index in range(frames):
        cloud = np.column_stack([rng.uniform(1, 40, (points, 3)), rng.uniform(0, 255, points)]).astype(np.float32)
        write_frame(layout, f"{index:06d}", cloud, [], np.zeros((0, 7)), {},
                    time_offset=np.sort(rng.uniform(0, FRAME_PERIOD_S, points)).astype(np.float32))
    sources = {"KITTI .bin + time_offset/": ("kitti", layout.root)}
    for storage in STORAGES:
        export_bag(list_frames("kitti", layout.root), root / storage, FRAME_PERIOD_S, storage)
        sources[f"rosbag2, {storage}"] = ("rosbag2", root / storage)
    for storage in STORAGES:
        sources[f"rosbag2, {storage}: read once, not listed (floor)"] = (ONCE, root / storage)
    return sources


def bfpc_sources(root: Path) -> dict[str, tuple[str, Path]]:
    """{source name: (format, path)}: the bundled .bfpc recording, and its frames as read (strongest returns with
    their times) written as a KITTI layout."""
    layout = KittiLayout(root / "bfpc_kitti")
    for index, frame in enumerate(list_frames("bfpc", BUNDLED_BFPC)):
        cloud = frame.load()
        write_frame(layout, f"{index:06d}", cloud.points, [], np.zeros((0, 7)), {}, time_offset=cloud.time_offsets())
    return {"its frames as KITTI .bin + time_offset/": ("kitti", layout.root),
            ".bfpc (the bundled Cube 1 recording)": ("bfpc", BUNDLED_BFPC)}


def loaders(fmt: str, src: Path) -> list:
    """The loaders of the frames of `src`: listed by io.formats, or for ONCE (a bag) counted from its metadata."""
    if fmt != ONCE:
        return [frame.load for frame in list_frames(fmt, src)]
    messages = BagMessages(src, TOPIC)
    with Reader(src) as reader:
        count = sum(connection.msgcount for connection in reader.connections if connection.topic == TOPIC)
    return [functools.partial(messages.cloud, index, None) for index in range(count)]


def read_ms(fmt: str, src: Path) -> tuple[tuple[float, float, float], int]:
    """((wall-clock ms, CPU ms listing the frames, CPU ms loading them) per frame of one read of `src`, points
    read)."""
    start, cpu = time.perf_counter(), time.process_time()
    frames = loaders(fmt, src)
    listed = time.process_time()
    count = sum(len(load().points) for load in frames)
    ms = [(time.perf_counter() - start), listed - cpu, time.process_time() - listed]
    return tuple(value * 1000 / len(frames) for value in ms), count


def peak_mb(fmt: str, src: Path) -> float:
    """The most memory [MB] Python traces at once while reading `src` as read_ms does (listing, then loading)."""
    tracemalloc.start()
    try:
        for load in loaders(fmt, src):
            load()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def read_all(sources: dict[str, tuple[str, Path]], repeats: int) -> dict[str, tuple[tuple[float, ...], int]]:
    """{source: ((wall-clock ms, CPU ms listing, CPU ms loading) per frame, each the median over `repeats` reads,
    points read)}: one warm-up read each, then the sources read in turn `repeats` times."""
    counts = {name: read_ms(fmt, src)[1] for name, (fmt, src) in sources.items()}
    times = {name: [] for name in sources}
    for _ in range(repeats):
        for name, (fmt, src) in sources.items():
            times[name].append(read_ms(fmt, src)[0])
    return {name: (tuple(statistics.median(column) for column in zip(*times[name])), counts[name])
            for name in sources}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--points", type=int, default=30_000, help="points per frame")
    parser.add_argument("--repeats", type=int, default=5, help="timed reads per source (median)")
    parser.add_argument("--output", default="output/benchmark/read_benchmark.json")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for group in (make_sources(Path(folder), args.frames, args.points), bfpc_sources(Path(folder))):
            first = len(rows)  # the group's KITTI layout: its reference
            for name, ((ms, list_ms, load_ms), count) in read_all(group, args.repeats).items():
                fmt, src = group[name]
                size = sum(path.stat().st_size for path in ([src] if src.is_file() else src.rglob("*"))
                           if path.is_file())
                rows.append({"source": name, "format": fmt, "ms_per_frame": ms, "cpu_ms_per_frame": list_ms + load_ms,
                             "cpu_ms_list": list_ms, "cpu_ms_load": load_ms, "points": count, "bytes": size,
                             "peak_mb": peak_mb(fmt, src), "reference": first})
            if len({row["points"] for row in rows[first:]}) != 1:
                raise RuntimeError(f"the sources gave different numbers of points: {rows[first:]}")
    print(f"\n{args.frames} frames of {args.points} points (float32 x, y, z, intensity, time), then the bundled "
          f".bfpc's 10 frames; median of {args.repeats} reads in turn, page cache warm; ratio = source / the KITTI "
          "layout of its frames\n")
    print("| source | ms per frame | ratio | CPU ms per frame (list + load) | CPU ratio | MB on disk | peak MB held |\n"
          "|---|---|---|---|---|---|---|")
    for row in rows:
        reference = rows[row["reference"]]
        print(f"| {row['source']} | {row['ms_per_frame']:.2f} | {row['ms_per_frame'] / reference['ms_per_frame']:.2f}x "
              f"| {row['cpu_ms_per_frame']:.2f} ({row['cpu_ms_list']:.2f} + {row['cpu_ms_load']:.2f}) "
              f"| {row['cpu_ms_per_frame'] / reference['cpu_ms_per_frame']:.2f}x | {row['bytes'] / 1e6:.1f} "
              f"| {row['peak_mb']:.1f} |")
    load = os.getloadavg()
    print(f"\nload average (1, 5, 15 min) at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    summary = {"frames": args.frames, "points": args.points, "repeats": args.repeats, "rows": rows,
               "loadavg": list(load)}
    write_text(Path(args.output), json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
