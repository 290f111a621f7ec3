"""`memslidar detect`: a trained detector on recordings, with tracks and zone events (OpenPCDet's demo.py, for
industrial safety).

    list the recording's frames (the readers of io.formats; --format auto: a folder layout or the files' suffix)
    -> the mount: given, estimated from the ground plane, or none (frames already in the ground frame)
    -> per frame, with a config that names the site's background model (DATA_CONFIG.BACKGROUND_MODEL): is the
       sensor still where it was? (monitor.background_watch: realigns a turned sensor, reports a changed site)
    -> per batch of frames: normalise to the ground frame, voxelise (the config's DATA_PROCESSOR), infer
    -> per frame, in time order: track (monitor.tracker), zones and events (monitor.zones)
    -> write labels/<frame>.txt (KITTI with scores), detections.jsonl and summary.json (and on request plots/ and
       points/) into a temporary folder that replaces --out only when every frame succeeded; on request (mcap) the
       same detections as an MCAP file of ROS 2 messages (monitor.mcap_out), finished just before

Raw points are written only with save_points: by default only detections leave (the paper's GDPR argument: boxes
and tracks, not the gait in the points).
"""
from __future__ import annotations

import contextlib
import json
import logging
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pcdet_memslidar.datasets.dataset import DatasetTemplate
from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import ground, kitti
from pcdet_memslidar.io.formats import FORMATS, format_of, list_frames
from pcdet_memslidar.io.frames import SourceFrame, frame_stamp_ns
from pcdet_memslidar.io.importer import choose_mount
from pcdet_memslidar.models import load_data_to_device
from pcdet_memslidar.models.detector import PRECISIONS
from pcdet_memslidar.monitor.background_watch import BackgroundWatch
from pcdet_memslidar.monitor.mcap_out import mcap_out
from pcdet_memslidar.monitor.plots import plot_tracks_frame
from pcdet_memslidar.monitor.tracker import Tracker, TrackerConfig
from pcdet_memslidar.monitor.zones import Zone, ZoneMonitor
from pcdet_memslidar.runtime.common import threads_giving_way
from pcdet_memslidar.runtime.experiment import Process
from pcdet_memslidar.runtime.predict import load_detector
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.utils.atomic import atomic_dir, check_output_folder, refuse_overlap, write_text
from pcdet_memslidar.utils.progress import progress_bar

COMMAND = "memslidar detect"  # the owner of the folders it writes (utils.atomic.atomic_dir)
FRAME_PERIOD_S = get_pattern("cube1_paper").frame_period_s  # time between frames of formats without time stamps
DETECTIONS_FILE, SUMMARY_FILE = "detections.jsonl", "summary.json"
STAGES = ("read", "voxelise", "infer", "track", "write")
# frames per forward pass by device type: on a CPU one frame at a time is fastest per frame (measured:
# docs/benchmarks.md#detect-speed); batches fill a GPU
BATCH_SIZE = {"cpu": 1, "cuda": 4}


@dataclass
class DetectOptions:
    """What `memslidar detect` was asked for (see commands/detect.py for the flags)."""

    src: Path
    out: Path
    fmt: str = "auto"
    mount: Mount | None = None
    estimate_ground: bool = False
    zones: list[Zone] | None = None
    batch_size: int | None = None  # None: BATCH_SIZE of the device
    frame_period_s: float = FRAME_PERIOD_S
    save_points: bool = False
    plot: bool = False
    precision: str = PRECISIONS[0]  # inference precision of the BEV backbone and head (models.detector.PRECISIONS)
    time_unit_s: float | None = None  # seconds per unit of time fields whose format does not record it (None: unused)
    topic: str | None = None  # the point-cloud topic of a ROS 2 bag (None: its only one)
    mcap: Path | None = None  # also write the detections as this MCAP file (monitor.mcap_out)


def detect_formats() -> list[str]:
    """The --format choices of `memslidar detect`: 'auto' (resolve_format) and the registered formats but annotation
    exports (detect reads recordings, not labels)."""
    return ["auto", *(name for name, fmt in FORMATS.items() if not fmt.labelled)]


def resolve_format(src: Path, fmt: str) -> str:
    """The format of `src` ('auto': a folder layout, or the suffix of the file or of the folder's files)."""
    if fmt != "auto":
        return fmt
    if not src.exists():
        raise DataFormatError(src, "not found: give a recording file or a folder of frames (--src)")
    names = detect_formats()[1:]
    return format_of(src, [FORMATS[name] for name in names], f"pass --format, one of {', '.join(names)}").name


class FrameVoxeliser(DatasetTemplate):
    """The config's point encoding and voxelisation (DATA_PROCESSOR, test mode) for frames that are no dataset."""

    def __init__(self, cfg, logger: logging.Logger):
        super().__init__(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False, root_path=Path("."), logger=logger)

    def __call__(self, points: np.ndarray, frame_id: str, point_times: np.ndarray | None = None) -> dict:
        """points (N, 4), and their time offsets (N,) [s] where the recording has them (the box step's drift)."""
        frame = {"points": self.point_features(points), "frame_id": frame_id}
        return self.prepare_data(frame if point_times is None else {**frame, "point_times": point_times})


class Monitor:
    """Tracks and zone events over a stream of frames' detections (the part of detect after the detector)."""

    def __init__(self, tracker: TrackerConfig, zones: list[Zone]):
        self.tracker, self.zones = Tracker(tracker), ZoneMonitor(zones)
        self.track_ids: set[int] = set()  # every id given so far

    def step(self, frame_id: str, source: str, time_s: float, boxes: np.ndarray, scores: np.ndarray
             ) -> tuple[dict, np.ndarray, np.ndarray, list]:
        """One frame's boxes (M, 7) and scores (M,) -> its detections.jsonl record, the kept boxes (K, 7) and scores
        (K,) (score >= the tracker's min_score) and their track ids (K,) (None: tentative)."""
        result = self.tracker.update(boxes, scores, time_s)
        boxes, scores, ids = boxes[result.kept], scores[result.kept], result.detection_ids
        zones_of, events = self.zones.update(time_s, ids, boxes, [track.track_id for track in result.lost])
        self.track_ids.update(i for i in ids if i is not None)
        record = {"frame": frame_id, "source": source, "time_s": round(time_s, 6),
                  "detections": [{"box": [round(float(v), 4) for v in box], "score": round(float(score), 4),
                                  "track_id": track_id, "zones": names}
                                 for box, score, track_id, names in zip(boxes, scores, ids, zones_of)],
                  "events": events}
        return record, boxes, scores, ids


def detect(cfg, checkpoint: str | Path | None, options: DetectOptions, logger: logging.Logger | None = None,
           device: str | torch.device = "cpu") -> dict:
    """Run the detector of cfg / checkpoint over options.src and write options.out (module docstring); returns the
    summary (also in out/summary.json)."""
    logger = logger or logging.getLogger(__name__)
    src, out = Path(options.src), Path(options.out)
    refuse_overlap(out, [src], "--out")
    check_output_folder(out, COMMAND)
    if options.mcap is not None:
        _check_mcap(Path(options.mcap), src)
    fmt = resolve_format(src, options.fmt)
    listing = time.perf_counter()
    frames = list_frames(fmt, src, options.time_unit_s, topic=options.topic)
    listed_s = time.perf_counter() - listing  # reading too: a bag or a .bfpc is read through and checked to list it
    if not frames:
        raise DataFormatError(src, "holds no frames: give a recording with at least one frame")
    mount, mount_entry = choose_mount(frames, options.mount, options.estimate_ground)
    monitor = Monitor(TrackerConfig.from_block(cfg.get("TRACKER"), cfg.get("CFG_FILE", "the config")),
                      options.zones or [])
    voxeliser = FrameVoxeliser(cfg, logger)
    watch = BackgroundWatch(voxeliser.background, logger) if voxeliser.background is not None else None
    process = Process(torch.device(device), torch.get_num_threads())  # its execution policy: Process.policy
    model, _ = load_detector(cfg, checkpoint, voxeliser, process, logger, options.precision)
    batch_size = options.batch_size or BATCH_SIZE[torch.device(device).type]
    seconds, counts = Counter(read=listed_s), Counter()
    started = time.perf_counter() - listed_s
    with atomic_dir(out, COMMAND) as tmp, (tmp / DETECTIONS_FILE).open("w") as lines, \
            threads_giving_way() as give_way, \
            _mcap_out(options, out, tmp, mount) as to_mcap:  # give_way: an edge box shares its cores
        bar = progress_bar(total=len(frames), desc="detect", unit="frame")
        for first in range(0, len(frames), batch_size):
            batch = frames[first:first + batch_size]
            clouds, times = _read(batch, mount, seconds, counts, watch)  # 1. read, normalise, align
            if torch.device(device).type == "cpu":
                give_way()
            predictions = _infer(model, voxeliser, clouds, times, first, device, seconds, counts)  # 2. voxelise, infer
            for index, frame, points, (boxes, scores) in zip(range(first, first + len(batch)), batch, clouds,
                                                             predictions):
                tick = time.perf_counter()  # 3. track, zones and events, in time order
                time_s = frame.time_s if frame.time_s is not None else index * options.frame_period_s
                if monitor.tracker.time_s is not None and time_s < monitor.tracker.time_s:
                    raise DataFormatError(src, f"frame {frame.name} starts {monitor.tracker.time_s - time_s:.3f} s "
                                               "before the frame listed before it: give the recordings of one "
                                               "sensor, named in time order")
                record, boxes, scores, ids = monitor.step(f"{index:06d}", frame.name, time_s, boxes, scores)
                tick = _lap(seconds, "track", tick)
                lines.write(json.dumps(record) + "\n")  # 4. write
                _write_frame(tmp, record, boxes, scores, ids, points, monitor, options,
                             cfg.DATA_CONFIG.POINT_CLOUD_RANGE)
                if to_mcap is not None:
                    to_mcap(record, points, frame_stamp_ns(frame, time_s), frame.frame_id)
                _lap(seconds, "write", tick)
                counts["detections"] += len(boxes)
                counts["events"] += len(record["events"])
                bar.update()
        bar.close()
        wall = time.perf_counter() - started
        summary = {"source": str(src), "format": fmt, "checkpoint": checkpoint and str(checkpoint),
                   "config": cfg.get("CFG_FILE"), "profile": cfg.get("PROFILE"), "mount": mount_entry,
                   "frames": len(frames), "frames_without_points": counts["empty"],
                   "frames_with_point_times": counts["timed"],
                   "frames_without_voxels": counts["no_voxels"], "dropped_invalid_points": counts["dropped"],
                   "detections": counts["detections"], "tracks": len(monitor.track_ids), "events": counts["events"],
                   "background_events": watch.events if watch else None,
                   "zones": [zone.name for zone in options.zones or []], "points_written": options.save_points,
                   "mcap": options.mcap and str(options.mcap),
                   "device": str(device), "torch_threads": torch.get_num_threads(), "batch_size": batch_size,
                   "precision": options.precision,
                   "ms_per_frame": {stage: 1000 * seconds[stage] / max(1, len(frames)) for stage in STAGES},
                   "frames_per_s": len(frames) / wall if wall > 0 else float("inf")}
        write_text(tmp / SUMMARY_FILE, json.dumps(summary, indent=1) + "\n")
    return summary


def _write_frame(folder: Path, record: dict, boxes: np.ndarray, scores: np.ndarray, ids: list, points: np.ndarray,
                 monitor: Monitor, options: DetectOptions, point_cloud_range) -> None:
    """labels/<frame>.txt, and with the options points/<frame>.bin and plots/<frame>.png."""
    frame_id = record["frame"]
    label = kitti.label_from_boxes(["Pedestrian"] * len(boxes), boxes, Calibration.virtual(), scores)
    kitti.write_label(folder / "labels" / f"{frame_id}.txt", label)
    if options.save_points:
        kitti.write_points(folder / "points" / f"{frame_id}.bin", points)
    if options.plot:
        trails = {track.track_id: np.array([(x, y) for _, x, y in track.history]) for track in monitor.tracker.tracks
                  if track.confirmed}
        x0, y0, _, x1, y1, _ = point_cloud_range
        plot_tracks_frame(folder / "plots" / f"{frame_id}.png", boxes, ids, trails,
                          [(zone.name, zone.level, zone.polygon) for zone in options.zones or []], record["events"],
                          f"frame {frame_id} ({record['source']}), t = {record['time_s']:.2f} s",
                          (np.array([x0, x1]), np.array([y0, y1])))


def _check_mcap(path: Path, src: Path) -> None:
    """ConfigError unless the --mcap file `path` is named *.mcap; OutputError where it is or lies in the input."""
    if path.suffix.lower() != ".mcap":
        raise ConfigError(f"--mcap {path}: name the file with the suffix .mcap")
    path, src = path.resolve(), src.resolve()
    if path == src or src in path.parents:
        raise OutputError(f"--mcap {path} {'is' if path == src else 'lies in'} the input {src}; choose a file outside "
                          "the input")


def _mcap_out(options: DetectOptions, out: Path, tmp: Path, mount: Mount | None):
    """monitor.mcap_out's writer of options.mcap (a file inside `out` is written into its temporary folder `tmp`), or
    a context of None without it."""
    if options.mcap is None:
        return contextlib.nullcontext()
    path, out = Path(options.mcap).resolve(), out.resolve()
    return mcap_out(tmp / path.relative_to(out) if path.is_relative_to(out) else path, options.zones or [], mount,
                    options.save_points)


def _lap(seconds: Counter, stage: str, tick: float) -> float:
    now = time.perf_counter()
    seconds[stage] += now - tick
    return now


def _read(batch: list[SourceFrame], mount: Mount | None, seconds: Counter, counts: Counter,
          watch: BackgroundWatch | None = None) -> tuple[list[np.ndarray], list[np.ndarray | None]]:
    """The batch's clouds (N, 4) in the ground frame (aligned to the site's background by `watch`), and their
    points' time offsets (N,) [s] where the format gives their unit (else None); invalid points are counted (the
    readers drop them)."""
    tick, clouds, times = time.perf_counter(), [], []
    for frame in batch:
        cloud = frame.load()
        counts["dropped"] += cloud.dropped
        counts["empty"] += len(cloud.points) == 0
        points = cloud.points if mount is None else ground.normalise_points(cloud.points, mount)
        clouds.append(points if watch is None else watch(frame.name, points))
        times.append(cloud.time_offsets())
        counts["timed"] += times[-1] is not None
    _lap(seconds, "read", tick)
    return clouds, times


def _infer(model, voxeliser: FrameVoxeliser, clouds: list[np.ndarray], times: list[np.ndarray | None], first: int,
           device, seconds: Counter, counts: Counter) -> list[tuple[np.ndarray, np.ndarray]]:
    """(boxes (M, 7), scores (M,)) per cloud (with its points' time offsets or None); a frame with no voxel in range
    gets none (counted)."""
    tick = time.perf_counter()
    samples = [voxeliser(points, f"{first + k:06d}", point_times)
               for k, (points, point_times) in enumerate(zip(clouds, times))]
    filled = [k for k, sample in enumerate(samples) if len(sample["voxels"])]
    counts["no_voxels"] += len(samples) - len(filled)
    tick = _lap(seconds, "voxelise", tick)
    results = [(np.zeros((0, 7)), np.zeros(0))] * len(samples)
    if filled:
        batch = load_data_to_device(voxeliser.collate_batch([samples[k] for k in filled]), device)
        with torch.no_grad():
            pred_dicts, _ = model(batch)
        for k, pred in zip(filled, pred_dicts):
            results[k] = (pred["pred_boxes"].cpu().numpy().astype(np.float64).reshape(-1, 7),
                          pred["pred_scores"].cpu().numpy().astype(np.float64))
    _lap(seconds, "infer", tick)
    return results
