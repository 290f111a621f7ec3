"""One simulated frame: scene + people -> scan pattern ray casting -> sensor physics -> points and boxes.

Each frame of a dataset draws everything from its own generator, seeded by (dataset seed, frame index) through
numpy's SeedSequence, so a frame is the same whichever worker or shard makes it. A sequence (for tracking) draws one
viewpoint and one set of people whose walks span all its frames, from one generator seeded by the sequence seed.
"""
from __future__ import annotations

import dataclasses
import functools
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np

import pcdet_memslidar
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.sim.bodies import BodyBank, load_body_bank
from pcdet_memslidar.sim.caster import Caster
from pcdet_memslidar.sim.labels import label_people
from pcdet_memslidar.sim.motion import Trajectory
from pcdet_memslidar.sim.pattern import ScanPattern, get_pattern
from pcdet_memslidar.sim.people import Person, sample_people
from pcdet_memslidar.sim.scenes import SceneSpec, get_scene, scene_name
from pcdet_memslidar.sim.sensor import SensorModel, get_sensor
from pcdet_memslidar.sim.site import Site
from pcdet_memslidar.utils.compiled import kernel


@dataclass
class Frame:
    """points (N, 4) float32 [x, y, z, intensity] in the ground frame; time_offset (N,) float32 [s] from the
    frame start; boxes (M, 7) [x, y, z_center, dx, dy, dz, heading]; names (M,); metadata (JSON-ready dict);
    seconds: wall time per stage."""

    points: np.ndarray
    time_offset: np.ndarray
    boxes: np.ndarray
    names: np.ndarray
    metadata: dict
    seconds: dict = field(default_factory=dict)


_CASTER_LOCK = threading.Lock()  # frames may be made in several threads (see writer.simulate_dataset)


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of frame `index` of a dataset with seed `seed`."""
    return np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(index,)))


def get_caster(scene: str | SceneSpec, mount: Mount, pattern: str | ScanPattern, sensor_name: str, lod: str,
               threads: int = 0) -> Caster:
    """The caster of one viewpoint, built once per process (the static world is cast here), by one thread."""
    with _CASTER_LOCK:
        return _cached_caster(scene, mount, pattern, sensor_name, lod, threads)


@functools.lru_cache(maxsize=16)  # called with all arguments positional: one cache entry per viewpoint
def _cached_caster(scene: str | SceneSpec, mount: Mount, pattern: str | ScanPattern, sensor_name: str, lod: str,
                   threads: int) -> Caster:
    pattern = get_pattern(pattern)
    directions, time_offset, _ = pattern.pulses()
    return Caster(get_scene(scene), mount, directions, time_offset, pattern.frame_period_s, load_body_bank(),
                  lod=lod, beam_divergence_rad=get_sensor(sensor_name).beam_divergence_rad, threads=threads)


def render(caster: Caster, people: list[Person], sensor: SensorModel, rng: np.random.Generator, bank: BodyBank,
           lod: str, label_time_s: float, time_step_s: float = 0.0, phase_steps: int | None = None,
           seconds: dict | None = None):
    """Cast, measure and label one frame of `people`.

    Returns points (N, 4) float32, time_offset (N,) float32, boxes (M, 7), names (M,), per-person records;
    adds the wall time of each stage to `seconds`."""
    seconds = {} if seconds is None else seconds
    # cast every pulse, each seeing the people where they are at its time
    start = time.perf_counter()
    hits = caster.cast_frame(people, time_step_s, phase_steps)
    seconds["casting"] = time.perf_counter() - start
    seconds["cast_rays"] = hits.cast_seconds
    # sensor physics: noise, dropout, intensity
    start = time.perf_counter()
    pulse, measured, intensity = sensor.returns(hits.range, hits.cos_incidence, hits.reflectivity, rng,
                                                hits.edge_range)
    points, time_offset = points_of_returns(caster.origin, caster.directions, caster.time_offset, pulse, measured,
                                            intensity)
    seconds["sensor"] = time.perf_counter() - start
    # labels from the simulator state
    start = time.perf_counter()
    returned = hits.person.take(pulse)
    returned = np.bincount(returned[returned >= 0], minlength=len(people))
    hit = np.bincount(hits.person[hits.person >= 0], minlength=len(people))
    boxes, names, records = label_people(bank, lod, people, label_time_s, returned, hit, hits.unoccluded)
    seconds["labels"] = time.perf_counter() - start
    return points, time_offset, boxes, names, records


@kernel
def points_of_returns(origin, directions, pulse_time, pulse, range_m, intensity):
    """points (n, 4) float32 [origin + range_m x direction, intensity] and time offsets (n,) float32 [s] of the
    returns of pulses pulse (n,) (origin (3,), directions (P, 3), pulse_time (P,) [s], range_m (n,) [m],
    intensity (n,))."""
    points = np.empty((len(pulse), 4), dtype=np.float32)
    time_offset = np.empty(len(pulse), dtype=np.float32)
    for i in range(len(pulse)):
        for k in range(3):
            points[i, k] = origin[k] + directions[pulse[i], k] * range_m[i]
        points[i, 3] = intensity[i]
        time_offset[i] = pulse_time[pulse[i]]
    return points, time_offset


def simulate_frame(site: Site, seed: int, index: int, threads: int = 0,
                   bank: BodyBank | None = None) -> Frame:
    """Frame `index` of `site` with dataset seed `seed`."""
    return next(_frames(site, frame_rng(seed, index), 1, dict(frame_index=index, seed=seed), threads, bank))


def simulate_sequence(site: Site, seed: int, length: int, threads: int = 0,
                      bank: BodyBank | None = None) -> Iterator[Frame]:
    """`length` consecutive frames of one viewpoint of `site` and the same people (sequence seed `seed`): frame k
    scans from k frame periods after the first one's start. Each frame's metadata adds sequence_seed, time_s (its
    start [s]) and person_ids (M,): the person (an index into metadata['people'], the same people in every frame)
    of each box, for tracking metrics."""
    yield from _frames(site, frame_rng(seed, 0), length, dict(sequence_seed=seed), threads, bank)


def _frames(site: Site, rng: np.random.Generator, length: int, identity: dict, threads: int,
            bank: BodyBank | None) -> Iterator[Frame]:
    """Frames 0..length-1 of one viewpoint and one set of people whose walks span all of them (one frame: as in a
    dataset), everything drawn from `rng`; identity: metadata that names the frame's origin."""
    start = time.perf_counter()
    bank = bank or load_body_bank()
    pattern, sensor = get_pattern(site.pattern), get_sensor(site.sensor)
    period = pattern.frame_period_s
    # pick the viewpoint; its static world is built and cast once per process
    viewpoint = site.viewpoints[int(rng.integers(len(site.viewpoints)))]
    scene = get_scene(viewpoint.scene)
    caster = get_caster(viewpoint.scene, viewpoint.mount, site.pattern, site.sensor, site.lod, threads)
    # place the people and their trajectories over all the frames
    people = sample_people(rng, site, scene, viewpoint.mount, pattern.hfov_deg, pattern.vfov_deg,
                           length * period, bank)
    mount = viewpoint.mount
    setup_seconds = time.perf_counter() - start
    for k in range(length):
        seconds = {"people": setup_seconds if k == 0 else 0.0}
        # the trajectories' clock shifted so that this frame starts at 0
        times = people[0].trajectory.times - k * period if people else None
        now = [replace(p, trajectory=Trajectory(times, p.trajectory.samples)) for p in people]
        points, time_offset, boxes, names, records = render(caster, now, sensor, rng, bank, site.lod, period / 2,
                                                            site.time_step_s, site.phase_steps, seconds)
        metadata = dict(
            domain=site.name, scene=scene_name(viewpoint.scene), **identity,
            package_version=pcdet_memslidar.__version__, mount=dataclasses.asdict(mount), pattern=pattern.name,
            sensor=site.sensor, frame_period_s=period, label_time_s=period / 2,
            num_pulses=caster.pulses, num_points=len(points), people=records)
        if length > 1:
            metadata.update(frame_index=k, time_s=round(k * period, 9),
                            person_ids=[i for i, record in enumerate(records) if record["labelled"]])
        yield Frame(points, time_offset, boxes, names, metadata, seconds)
