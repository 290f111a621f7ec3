"""Benchmark the simulator: speed per domain and the speed-vs-error trade-off of mesh detail and time handling.

    python tools/benchmark_sim.py [--frames 60] [--error-frames 6] [--workers 2] [--where /dev/shm]

Part 1, per domain (and the paper target: cube1_paper pattern, 10 people, motion within the frame), after
building every viewpoint's caster, one warm-up frame and a warm-up run. The whole frame is people, casting,
sensor, labels and writing the KITTI files; the pure cast is all rays of the frame cast once against one prebuilt
Open3D scene holding the static world and every person posed at mid-frame. Three like-for-like ratios of
whole-frame time to pure-cast time:
- one core: the frames made one at a time in this thread, Open3D on one thread, against the pure cast on one
  thread (the CPU cost of a frame against that of its cast);
- one process: frames/s of `simulate_dataset` in one process (two frames at a time in threads, Open3D on all
  cores; Python's interpreter lock serialises their Python parts) against the pure cast on all cores;
- workers: `simulate_dataset` with --workers processes once they have built their casters (each process on one
  core) against the pure cast on all cores; their frames/s once started, and the seconds their start-up adds
  (imports, casters and compiled kernels loaded in each process).
Then the ms per frame of each stage on one core. Runs with glibc keeping freed memory, as simulate_dataset does;
writes into memory (/dev/shm) unless --where names another folder.
Part 2: for the frames of the paper target, every body detail level x time handling against the finest setting
('full' mesh, each pulse at its own time): displacement of the pulses that hit a person in both, share of
person pulses that hit a person in only one, and time per frame.
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.policy import apply_process_policy
from pcdet_memslidar.sim.bodies import LODS, load_body_bank
from pcdet_memslidar.sim.frame import frame_rng, get_caster, simulate_frame
from pcdet_memslidar.sim.memory import keep_freed_memory
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.people import sample_people
from pcdet_memslidar.sim.scenes import get_scene
from pcdet_memslidar.sim.site import BUNDLED_SITES, get_domain
from pcdet_memslidar.sim.writer import domain_settings, simulate_dataset, write_simulated_frame
from pcdet_memslidar.utils.open3d import import_open3d

TIME_HANDLING = {"per pulse": 0.0, "10 ms slices": 0.01, "50 ms slices": 0.05, "one instant": None}


def pure_cast_seconds(caster, scene_name, people, bank, lod, threads: int, repeats=3) -> float:
    """Seconds to cast all rays of a frame once, on `threads` threads (0: all cores), against a prebuilt scene of
    the static world + posed people."""
    o3d = import_open3d()
    vertices, triangles, _ = get_scene(scene_name).triangles()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    for person in people:
        xy, heading, phase, walk = person.trajectory.state(np.array([caster.frame_period_s / 2]))
        world = bank.posed_triangles(lod, person.shape, xy[0], heading[0], phase[0], walk[0]).reshape(-1, 3)
        scene.add_triangles(o3d.core.Tensor(world.astype(np.float32)),
                            o3d.core.Tensor(np.arange(len(world), dtype=np.uint32).reshape(-1, 3)))
    rays = o3d.core.Tensor(np.concatenate([np.broadcast_to(caster.origin, caster.directions.shape),
                                           caster.directions], 1).astype(np.float32))
    scene.cast_rays(rays)  # builds the BVH
    start = time.perf_counter()
    for _ in range(repeats):
        scene.cast_rays(rays, nthreads=threads)
    return (time.perf_counter() - start) / repeats


def frame_people(preset, seed, index, bank):
    """The viewpoint and people of frame `index`, drawn exactly as simulate_frame draws them."""
    rng = frame_rng(seed, index)
    viewpoint = preset.viewpoints[int(rng.integers(len(preset.viewpoints)))]
    pattern = get_pattern(preset.pattern)
    people = sample_people(rng, preset, get_scene(viewpoint.scene), viewpoint.mount, pattern.hfov_deg,
                           pattern.vfov_deg, pattern.frame_period_s, bank)
    return viewpoint, people


STAGES = ("people", "casting", "cast_rays", "sensor", "labels", "writing")


def _warm_up(preset, threads: int = 1) -> None:
    """Build the casters of every viewpoint of `preset` in this process (Open3D `threads`) and make one frame."""
    keep_freed_memory()
    for viewpoint in preset.viewpoints:
        get_caster(viewpoint.scene, viewpoint.mount, preset.pattern, preset.sensor, preset.lod, threads)
    simulate_frame(preset, 0, 10_000, threads=threads)


def _make_frame(args) -> None:
    preset, seed, index, layout, fingerprint = args
    write_simulated_frame(layout, index, simulate_frame(preset, seed, index, threads=1), fingerprint)


def started_seconds(preset, frames: int, workers: int, layout: KittiLayout, fingerprint: str, seed: int) -> float:
    """Wall time [s] of `frames` frames made and written by `workers` processes (as simulate_dataset's) that
    have already built their casters."""
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_warm_up,
                             initargs=(preset,)) as pool:
        list(pool.map(time.sleep, [1.0] * workers))  # every process started and warmed up
        start = time.perf_counter()
        list(pool.map(_make_frame, [(preset, seed, index, layout, fingerprint) for index in range(frames)],
                      chunksize=4))  # as simulate_dataset
        return time.perf_counter() - start


def speed(preset, frames: int, workers: int, where: str | None = None, seed: int = 0) -> dict:
    """Frames/s, rays/s, whole/pure ratios and ms per frame of each stage of `frames` frames of `preset`, written
    into a temporary folder in `where` (None: the system's temporary folder)."""
    bank = load_body_bank()
    for threads in (0, 1):  # static worlds built and cast once, for all cores and for one
        _warm_up(preset, threads)
    with tempfile.TemporaryDirectory(dir=where) as folder:
        # one process, as `memslidar simulate` makes frames (two at a time in threads), after a warm-up run in which
        # the threads' memory arenas grow to their working size
        simulate_dataset(preset, 8, Path(folder) / "warm-up", seed=seed + 1, progress=False)
        start = time.perf_counter()
        simulate_dataset(preset, frames, Path(folder) / "whole", seed=seed, workers=1, progress=False)
        whole = time.perf_counter() - start
        # one core: the same frames one at a time, stage by stage, and the pure cast of their rays
        fingerprint = domain_settings(preset, seed)["fingerprint"]
        layout = KittiLayout(Path(folder) / "stages")
        core, pure, pure_core, rays, people_count = 0.0, 0.0, 0.0, 0, 0
        stages = dict.fromkeys(STAGES, 0.0)
        for index in range(frames):
            start = time.perf_counter()
            frame = simulate_frame(preset, seed, index, threads=1)
            written = time.perf_counter()
            write_simulated_frame(layout, index, frame, fingerprint)
            core += time.perf_counter() - start
            stages["writing"] += time.perf_counter() - written
            for stage, seconds in frame.seconds.items():
                stages[stage] += seconds
            viewpoint, people = frame_people(preset, seed, index, bank)
            caster = get_caster(viewpoint.scene, viewpoint.mount, preset.pattern, preset.sensor, preset.lod)
            pure += pure_cast_seconds(caster, viewpoint.scene, people, bank, preset.lod, threads=0)
            pure_core += pure_cast_seconds(caster, viewpoint.scene, people, bank, preset.lod, threads=1)
            rays += len(caster.directions)
            people_count += len(people)
        # in `workers` processes: start-up included, and per frame once every process has its casters
        start = time.perf_counter()
        simulate_dataset(preset, frames, Path(folder) / "parallel", seed=seed, workers=workers, progress=False)
        parallel = time.perf_counter() - start
        started = started_seconds(preset, frames, workers, KittiLayout(Path(folder) / "started"), fingerprint, seed)
    return dict(fps=frames / whole, rays_per_s=rays / whole, core_ratio=core / pure_core, ratio=whole / pure,
                people_per_frame=people_count / frames, rays=rays / frames, parallel_fps=frames / started,
                start_up_s=parallel - started, parallel_ratio=started / pure, core_ms=1000 * core / frames,
                pure_core_ms=1000 * pure_core / frames,
                whole_ms=1000 * whole / frames, pure_ms=1000 * pure / frames,
                **{stage: 1000 * seconds / frames for stage, seconds in stages.items()})


def errors(preset, frames: int, seed: int = 0) -> list[tuple]:
    bank = load_body_bank()
    pattern = get_pattern(preset.pattern)
    rows = []
    reference = {}
    settings = [("full", "per pulse")] + [(lod, handling) for lod in reversed(LODS) for handling in TIME_HANDLING
                                          if (lod, handling) != ("full", "per pulse")]
    for lod, handling in settings:
        step = TIME_HANDLING[handling]
        step = pattern.frame_period_s if step is None else step
        displacement, mismatch, person_pulses, seconds = [], 0, 0, 0.0
        # warm-up, not timed: builds the body scene of this detail level and its BVH (on the first cast)
        viewpoint, people = frame_people(preset, seed, 0, bank)
        get_caster(viewpoint.scene, viewpoint.mount, preset.pattern, preset.sensor, lod).cast_frame(people)
        for index in range(frames):
            viewpoint, people = frame_people(preset, seed, index, bank)
            caster = get_caster(viewpoint.scene, viewpoint.mount, preset.pattern, preset.sensor, lod)
            start = time.perf_counter()
            hits = caster.cast_frame(people, step, preset.phase_steps)
            seconds += time.perf_counter() - start
            if (lod, handling) == ("full", "per pulse"):
                reference[index] = hits
                continue
            ref = reference[index]
            both = (ref.person >= 0) & (hits.person >= 0)
            either = (ref.person >= 0) | (hits.person >= 0)
            displacement.append(np.abs(hits.range[both] - ref.range[both]))
            mismatch += int(either.sum() - both.sum())
            person_pulses += int(either.sum())
        if displacement:
            d = np.concatenate(displacement)
            rows.append((lod, handling, 100 * np.median(d), 100 * np.percentile(d, 90), 100 * mismatch / person_pulses,
                         1000 * seconds / frames))
        else:
            rows.append((lod, handling, 0.0, 0.0, 0.0, 1000 * seconds / frames))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="frames per domain for the speed table")
    parser.add_argument("--error-frames", type=int, default=6, help="frames for the speed-vs-error table")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--where", default="/dev/shm" if Path("/dev/shm").is_dir() else None,
                        help="folder to write the frames into (default: /dev/shm, memory, so that the state of "
                             "the disk does not enter the timings; give a disk folder to include it)")
    args = parser.parse_args()
    apply_process_policy()  # as `memslidar simulate` does
    print(f"writing into {args.where or tempfile.gettempdir()}")
    keep_freed_memory()  # as simulate_dataset does
    target = dataclasses.replace(get_domain("sim"), name="paper target (sim, 10 people)", people=(10, 10))
    workers = f"x{args.workers} workers"
    print(f"{'domain':34s} {'people':>6s} {'rays':>7s} {'frames/s':>9s} {'Mrays/s':>8s} {'frames/s ' + workers:>19s} "
          f"{'start-up s':>10s}   whole/pure: {'one core':>8s} {'one process':>11s} {workers:>11s}")
    results = {}
    for preset in [target] + [get_domain(name) for name in list(BUNDLED_SITES)]:
        r = results[preset.name] = speed(preset, args.frames, args.workers, args.where)
        print(f"{preset.name:34s} {r['people_per_frame']:6.1f} {r['rays']:7.0f} {r['fps']:9.1f} "
              f"{r['rays_per_s'] / 1e6:8.2f} {r['parallel_fps']:19.1f} {r['start_up_s']:10.1f}   {'':11s} "
              f"{r['core_ratio']:8.2f} {r['ratio']:11.2f} {r['parallel_ratio']:11.2f}")
    print(f"\nms per frame on one core ('casting' includes 'cast_rays', the time inside Open3D; 'pure cast': all rays "
          f"of the frame against one prebuilt scene)\n{'domain':34s} " + " ".join(f"{s:>9s}" for s in STAGES)
          + f" {'whole':>9s} {'pure cast':>9s}")
    for name, r in results.items():
        print(f"{name:34s} " + " ".join(f"{r[s]:9.1f}" for s in STAGES)
              + f" {r['core_ms']:9.1f} {r['pure_core_ms']:9.1f}")
    print(f"\nspeed vs error ({args.error_frames} frames of the paper target; reference: 'full' mesh, per pulse; "
          f"displacement of person hits in cm)")
    print(f"{'mesh':8s} {'time handling':14s} {'median':>7s} {'p90':>7s} {'person pulses changed %':>24s} "
          f"{'people cast ms/frame':>21s}")
    for lod, handling, median, p90, changed, ms in errors(target, args.error_frames):
        print(f"{lod:8s} {handling:14s} {median:7.2f} {p90:7.2f} {changed:24.1f} {ms:21.1f}")


if __name__ == "__main__":
    main()
