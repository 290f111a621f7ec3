"""Simulated people ray-cast into a real recording of the empty site (rendering-based compositing).

For a static sensor a recording of the empty site says, per pulse, where the beam ends (or that it returns
nothing). Per output frame:
1. take a background frame (the recording's frames in turn) and its pulses: direction and time from the recording
   where its format carries every pulse, with or without a return (io.formats: .bfpc), or, for formats of returns
   only (point-cloud files), each return along its own direction at the time of the site's scan-pattern pulse
   nearest to it, and the pattern's other pulses as pulses without a return;
2. place the site's distractors (objects that are not people, sim/distractors.py), then people, on the walkable
   floor, clear of what the background shows standing on it (`obstacle_cells`); people also walk around the
   distractors;
3. cast each pulse at its own time against the people (sim/caster.py, with the real ranges as the static world)
   and against the distractors: a pulse whose nearest hit is a person or a distractor nearer than its real return
   (or that had none) returns that hit through the site's sensor physics (range noise, mixed pixels, dropout,
   intensity); the real return behind it is gone (the shadow), and so is a person's hit behind a distractor;
4. every other pulse keeps its real return bit for bit (normalised to the ground frame as `memslidar import` does);
5. boxes (people only) and metadata as for simulated frames; the metadata names the background frame and lists the
   distractors.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import pcdet_memslidar
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.formats import InputFormat, format_files, list_frames
from pcdet_memslidar.io.frames import SourceFrame
from pcdet_memslidar.sim.bodies import BodyBank, load_body_bank
from pcdet_memslidar.sim.caster import Caster, FrameHits
from pcdet_memslidar.sim.distractors import Distractor, cast_distractors, footprints, frame_distractors
from pcdet_memslidar.sim.frame import Frame, frame_rng, points_of_returns
from pcdet_memslidar.sim.labels import label_people
from pcdet_memslidar.sim.pattern import PATTERNS, ScanPattern, get_pattern
from pcdet_memslidar.sim.people import Person, sample_people
from pcdet_memslidar.sim.scenes import Scene
from pcdet_memslidar.sim.sensor import SensorModel, get_sensor
from pcdet_memslidar.sim.site import Background, Site, background_format

OBSTACLE_CELL_M = 0.25  # cells of the floor grid in which the background shows something people cannot walk through
OBSTACLE_HEIGHT_M = (0.2, 1.8)  # returns between these heights above the floor make a cell an obstacle
OBSTACLE_MIN_RETURNS = 2  # over all background frames: a lone noisy return does not block a cell
WALK_HEADINGS = tuple(k * np.pi / 4 for k in range(8))  # people cross a background site in any direction
MAX_MATCH_SPACINGS = 0.5  # median angle from a return to its matched pulse, in pulse spacings, of a pattern's own data
REAL_RETURN = -1  # Composite.person of a real return (and FrameHits.person of a pulse whose nearest hit is real)
DISTRACTOR_RETURN = -2  # Composite.person of a return from a distractor (and FrameHits.person of its pulses)


@dataclass(frozen=True)
class BackgroundFrame:
    """One frame of a background recording, per pulse (P pulses, sensor frame): directions (P, 3) unit vectors,
    time_offset (P,) [s] from the frame start, range (P,) [m] of its real return (inf: none), points (P, 4) float32
    x, y, z, intensity of that return (nan: none); source: '<file>#<frame>'; time_s: start since the first frame
    [s]; unmatched: returns left out (a weaker return of a pulse that has several)."""

    source: str
    directions: np.ndarray
    time_offset: np.ndarray
    range: np.ndarray
    points: np.ndarray
    time_s: float
    unmatched: int = 0

    @property
    def returned(self) -> np.ndarray:
        """(P,) bool: pulses with a real return."""
        return np.isfinite(self.range)


def _pattern_check(path: Path, recorded: dict[str, float] | None, pattern: ScanPattern) -> None:
    """DataFormatError naming the fix when the scan pattern a recording stores (io.frames.PulseRecording.pattern)
    is not the site's."""
    if recorded is None:
        return
    differs = [key for key, value in recorded.items() if abs(value - getattr(pattern, key)) > 1e-3]
    if differs:
        match = next((name for name, preset in PATTERNS.items()
                      if all(abs(value - getattr(preset, key)) <= 1e-3 for key, value in recorded.items())), None)
        fix = f"set sensor.pattern to {match}" if match else "set sensor.pattern to " + str(
            {key: round(float(value), 4) for key, value in recorded.items()})
        raise DataFormatError(path, f"recorded with another scan pattern than the site's '{pattern.name}' ("
                                    f"{', '.join(differs)} differ): {fix} in the site file")


def _pulse_frames(fmt: InputFormat, files: list[Path], pattern: ScanPattern) -> list[BackgroundFrame]:
    """Frames of a format that carries every pulse: each pulse's direction, time and strongest return as recorded,
    timed from the first frame's start."""
    frames = []
    for path in files:
        recording = fmt.read_pulses(path)
        _pattern_check(path, recording.pattern, pattern)
        frames += recording.frames
    background = []
    for frame in frames:
        ranges = np.where(frame.returned, np.linalg.norm(frame.points[:, :3].astype(np.float64), axis=1), np.inf)
        background.append(BackgroundFrame(frame.name, frame.directions, frame.time_offset, ranges, frame.points,
                                          (frame.start_time_ns - frames[0].start_time_ns) * 1e-9, frame.unmatched))
    return background


def _cloud_frames(path: Path, source: list[SourceFrame], pattern: ScanPattern) -> list[BackgroundFrame]:
    """Frames of the returns-only recording `path` (point-cloud files, a ROS 2 bag). Each return is a pulse along
    its own direction, at the time of the pattern's pulse nearest to it; the pattern's pulses that no return is
    nearest to are the pulses without a return. Frames without a recorded start are a frame period apart."""
    directions, time_offset, _ = pattern.pulses()
    tree, spacing = cKDTree(directions), np.radians(pattern.angle_spacing_deg)
    frames = []
    for index, frame in enumerate(source):
        cloud = frame.load()
        distance = np.linalg.norm(cloud.points[:, :3].astype(np.float64), axis=1)
        own = cloud.points[:, :3] / distance[:, None]
        angle, pulse = tree.query(own)  # chord ~ angle [rad] at these scales
        if len(angle) and np.median(angle) > MAX_MATCH_SPACINGS * spacing:
            raise DataFormatError(path, f"frame {frame.name}: its returns lie {np.degrees(np.median(angle)):.2f} "
                                        f"deg (median) from the nearest pulse of the site's scan pattern "
                                        f"'{pattern.name}' (spacing {pattern.angle_spacing_deg:g} deg): recorded with "
                                        "another pattern; set sensor.pattern in the site file to the recording's")
        silent = np.setdiff1d(np.arange(len(directions)), pulse)
        times = np.concatenate([time_offset[pulse], time_offset[silent]])
        order = np.argsort(times, kind="stable")
        points = np.concatenate([cloud.points, np.full((len(silent), 4), np.nan, dtype=np.float32)])
        frames.append(BackgroundFrame(frame.name, np.concatenate([own, directions[silent]])[order], times[order],
                                      np.concatenate([distance, np.full(len(silent), np.inf)])[order], points[order],
                                      index * pattern.frame_period_s if frame.time_s is None else frame.time_s))
    return frames


@functools.lru_cache(maxsize=4)
def read_background(background: Background, pattern: str | ScanPattern) -> tuple[BackgroundFrame, ...]:
    """The frames background.frames (first, stop) of a background recording (sim.site.background_format), per
    pulse; DataFormatError naming the file and fix when it does not fit the site's `pattern`."""
    path, pattern = Path(background.recording), get_pattern(pattern)
    fmt = background_format(path)
    frames = _pulse_frames(fmt, format_files(path, fmt), pattern) if fmt.pulses else \
        _cloud_frames(path, list_frames(fmt.name, path, topic=background.topic), pattern)
    first, stop = background.frames or (0, len(frames))
    if stop > len(frames) or not frames:
        raise DataFormatError(path, f"background.frames [{first}, {stop}) asks for more than its {len(frames)} "
                                    f"frames; fix background.frames in the site file")
    return tuple(frames[first:stop])


def recording_sha256(background: Background) -> str:
    """sha256 of the recording's bytes (its files in name order for a folder, a ROS 2 bag's folder included): part
    of a site's fingerprint."""
    path = Path(background.recording)
    digest = hashlib.sha256()
    for recording in format_files(path, background_format(path)):
        for file in sorted(recording.iterdir()) if recording.is_dir() else [recording]:
            digest.update(file.name.encode() + file.read_bytes())
    return digest.hexdigest()


def recording_points(background: Background, frames: int = 5) -> np.ndarray:
    """(N, 4) float32 returns (sensor frame) of the first `frames` frames of background.frames: what a mount is
    estimated from."""
    path = Path(background.recording)
    first = background.frames[0] if background.frames else 0
    clouds = [frame.load().points for frame in list_frames(background_format(path).name, path,
                                                           topic=background.topic)[first:first + frames]]
    if not clouds:
        raise DataFormatError(path, "holds no frames to estimate the mount from")
    return np.concatenate(clouds)


def estimate_background_mount(background: Background) -> Mount:
    """The mount estimated from the floor of the background's first frames (io.ground.estimate_ground);
    ConfigError naming the fix when no floor is found."""
    try:
        return ground.estimate_ground(recording_points(background)).mount
    except ValueError as error:
        raise ConfigError(f"{background.recording}: {error} (mount: in the site file)") from None


def obstacle_cells(frames: tuple[BackgroundFrame, ...], mount: Mount) -> np.ndarray:
    """(O, 4) [x0, y0, x1, y1] footprints [m] of the floor cells (OBSTACLE_CELL_M) in which the background frames
    show at least OBSTACLE_MIN_RETURNS returns between OBSTACLE_HEIGHT_M above the floor: furniture, machines,
    walls that people do not walk through."""
    points = np.concatenate([mount.sensor_to_ground(frame.points[frame.returned, :3]) for frame in frames])
    standing = points[(points[:, 2] > OBSTACLE_HEIGHT_M[0]) & (points[:, 2] < OBSTACLE_HEIGHT_M[1])]
    cells, counts = np.unique(np.floor(standing[:, :2] / OBSTACLE_CELL_M).astype(np.int64), axis=0,
                              return_counts=True)
    low = cells[counts >= OBSTACLE_MIN_RETURNS] * OBSTACLE_CELL_M
    return np.concatenate([low, low + OBSTACLE_CELL_M], axis=1).reshape(-1, 4)


class BackgroundWorld:
    """A background site's frames, its walkable scene (no surfaces: the recording is the world; obstacles from
    `obstacle_cells`) and one caster per background frame (built on first use, once per process)."""

    def __init__(self, site: Site):
        if site.background is None or site.walkable is None:
            raise ConfigError(f"site '{site.name}': compositing needs a background and a walkable polygon")
        self.site, self.mount = site, site.viewpoints[0].mount
        self.pattern, self.sensor = get_pattern(site.pattern), get_sensor(site.sensor)
        self.frames = read_background(site.background, site.pattern)
        corners = np.asarray(site.walkable)
        self.scene = Scene("background", (), WALK_HEADINGS, float(corners[:, 0].max()),
                           obstacles=obstacle_cells(self.frames, self.mount))
        self._casters: dict[tuple[int, int], Caster] = {}
        self._lock = threading.Lock()

    def caster(self, index: int, threads: int) -> Caster:
        """The caster of background frame `index` (its pulses, its real ranges as the static world)."""
        with self._lock:
            if (index, threads) not in self._casters:
                frame = self.frames[index]
                self._casters[index, threads] = Caster(
                    frame.range, self.mount, frame.directions, frame.time_offset, self.pattern.frame_period_s,
                    load_body_bank(), lod=self.site.lod, beam_divergence_rad=self.sensor.beam_divergence_rad,
                    threads=threads)
            return self._casters[index, threads]


@functools.lru_cache(maxsize=4)
def background_world(site: Site) -> BackgroundWorld:
    return BackgroundWorld(site)


@dataclass
class Composite:
    """A background frame with people and distractors cast into it: points (N, 4) float32 [x, y, z, intensity] in
    the ground frame and time_offset (N,) float32 [s], in pulse order; pulse (N,) the pulse of each point; person (N,)
    the person a point is on (REAL_RETURN -1: a real return, DISTRACTOR_RETURN -2: a distractor's); hits: the nearest
    hits of every pulse (the caster's, with person DISTRACTOR_RETURN where a distractor is nearest)."""

    points: np.ndarray
    time_offset: np.ndarray
    pulse: np.ndarray
    person: np.ndarray
    hits: FrameHits

    @property
    def hidden(self) -> np.ndarray:
        """Pulses whose nearest hit is a person or a distractor (their real return, if any, is gone)."""
        return np.flatnonzero(self.hits.person != REAL_RETURN)

    def counts(self, people: int) -> tuple[np.ndarray, np.ndarray]:
        """(people,) returned points of each person and (people,) pulses whose nearest hit is that person (before
        dropout): what label_people takes."""
        return (np.bincount(self.person[self.person >= 0], minlength=people),
                np.bincount(self.hits.person[self.hits.person >= 0], minlength=people))


def _nearest_of_distractors(hits: FrameHits, caster: Caster, distractors: Sequence[Distractor]) -> FrameHits:
    """`hits` where a distractor is nearer than the real return and any person: its range, cosine, reflectivity,
    person DISTRACTOR_RETURN, and the edge range of its sub-rays against the distractors and the real returns."""
    ray_range, cos, reflectivity = cast_distractors(distractors, caster.origin, caster.directions, caster.threads)
    p = caster.pulses
    nearer = ray_range[:p] < hits.range
    edge_range = hits.edge_range
    if edge_range is not None:
        edge_range = edge_range.copy()
        edge_range[nearer] = caster.edge_range(np.minimum(caster.static_range, ray_range), np.flatnonzero(nearer))
    return dataclasses.replace(
        hits, range=np.where(nearer, ray_range[:p], hits.range),
        cos_incidence=np.where(nearer, cos[:p], hits.cos_incidence),
        reflectivity=np.where(nearer, reflectivity[:p], hits.reflectivity),
        person=np.where(nearer, DISTRACTOR_RETURN, hits.person), edge_range=edge_range)


def composite_pulses(background: BackgroundFrame, caster: Caster, people: list[Person], sensor: SensorModel,
                     rng: np.random.Generator, mount: Mount, time_step_s: float = 0.0,
                     phase_steps: int | None = None, distractors: Sequence[Distractor] = ()) -> Composite:
    """Cast `people` and `distractors` into one background frame (caster: built on its pulses and real ranges);
    steps 3 and 4 of the module docstring."""
    # cast every pulse at its own time; pulses whose person or distractor hit is nearer than the real return change
    hits = caster.cast_frame(people, time_step_s, phase_steps)
    if distractors:
        hits = _nearest_of_distractors(hits, caster, distractors)
    changed = np.flatnonzero(hits.person != REAL_RETURN)
    edge = None if hits.edge_range is None else hits.edge_range[changed]
    pulse, measured, intensity = sensor.returns(hits.range[changed], hits.cos_incidence[changed],
                                                hits.reflectivity[changed], rng, edge)
    cast_pulse = changed[pulse]
    cast_points, _ = points_of_returns(caster.origin, caster.directions, caster.time_offset, cast_pulse, measured,
                                       intensity)
    # every other pulse keeps its real return, normalised as an import would
    kept = np.flatnonzero(background.returned & (hits.person == REAL_RETURN))
    pulses = np.concatenate([kept, cast_pulse])
    order = np.argsort(pulses, kind="stable")
    points = np.concatenate([ground.normalise_points(background.points[kept], mount), cast_points])[order]
    return Composite(points, background.time_offset[pulses[order]].astype(np.float32), pulses[order],
                     np.concatenate([np.full(len(kept), REAL_RETURN), hits.person[cast_pulse]])[order], hits)


def composite_frame(site: Site, seed: int, index: int, threads: int = 0, bank: BodyBank | None = None) -> Frame:
    """Frame `index` of a background site with dataset seed `seed`: background frame index % (its frames), people
    drawn from the frame's own generator (sim.frame.frame_rng), distractors from theirs (frame_distractors)."""
    rng, bank = frame_rng(seed, index), bank or load_body_bank()
    world = background_world(site)
    k = index % len(world.frames)
    background, caster, period = world.frames[k], world.caster(k, threads), world.pattern.frame_period_s
    # distractors first, then people who walk around them
    distractors = frame_distractors(site, seed, index, world.scene.obstacles)
    scene = dataclasses.replace(world.scene, obstacles=np.concatenate([world.scene.obstacles, footprints(distractors)]))
    people = sample_people(rng, site, scene, world.mount, world.pattern.hfov_deg, world.pattern.vfov_deg, period, bank)
    result = composite_pulses(background, caster, people, world.sensor, rng, world.mount, site.time_step_s,
                              site.phase_steps, distractors)
    # labels from the simulator state (distractors get none)
    boxes, names, records = label_people(bank, site.lod, people, period / 2, *result.counts(len(people)),
                                         result.hits.unoccluded)
    metadata = dict(
        domain=site.name, scene="background", background=background.source, background_time_s=background.time_s,
        frame_index=index, seed=seed, package_version=pcdet_memslidar.__version__,
        mount=dataclasses.asdict(world.mount), pattern=world.pattern.name, sensor=site.sensor, frame_period_s=period,
        label_time_s=period / 2, num_pulses=caster.pulses, num_points=len(result.points),
        background_returns_hidden=int(background.returned[result.hidden].sum()), people=records)
    if site.distractors[1] > 0:  # frames of sites without distractors stay as they were
        metadata["distractors"] = [distractor.record() for distractor in distractors]
    return Frame(result.points, result.time_offset, boxes, names, metadata)
