"""`memslidar sweep`: the paper's open questions as sweeps over the training set, on the reproduction's machinery.

- ratio: M3's SECOND trained on MIX.TOTAL frames with 0, 10, ..., 100 % synthetic (Table 2's rule: largest-remainder
  counts of sim and real, the same epochs), each tested on the industrial split: which sim/real ratio is best.
- real-budget: 10, 25, 50 and 100 % of the real pool (the profile's MIX.TOTAL real frames), each alone and with a
  fixed pool of synthetic frames (half of MIX.TOTAL, M3's share); every point trains for the optimizer steps of
  the profile's recipe (epochs = NUM_EPOCHS x MIX.TOTAL / its frames, rounded), so small sets are not starved:
  how many real annotations the synthetic frames replace at equal AP (annotations_replaced).
A point is one ordinary training run (runs.run_model: runtime.train, then runtime.predict on the test split)
in out/points/<point>/seed_<k>, so any job runner can train points on other machines with `memslidar train` and the
config that run folder's config.json holds. A finished run is read back from its run.json: an interrupted sweep
resumes where it stopped. Results: out/results.json, out/report.md and out/<sweep>.png.
"""
from __future__ import annotations

import copy
import datetime
import time
from dataclasses import dataclass, field
from pathlib import Path

from easydict import EasyDict

from pcdet_memslidar.config import profile_settings
from pcdet_memslidar.datasets.mixing import source_counts
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.evaluation.figures import plot_sweep
from pcdet_memslidar.experiments.report import ap_text, write_report
from pcdet_memslidar.experiments.reproduce import RUNS, frames_needed, model_config, prepare_data
from pcdet_memslidar.experiments.results import HEADLINE, environment, json_safe, summarise_runs
from pcdet_memslidar.experiments.runs import StageClock, check_run_options, run_jobs, runs_at_once, training_jobs
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.runtime.common import create_logger
from pcdet_memslidar.utils.atomic import refuse_overlap

BASE_MODEL = "M3"  # the sweeps change only the training set of cfgs/m3.yaml
SIM, REAL = "sim", "real"
SIM_SHARES = tuple(range(0, 101, 10))  # ratio sweep: % synthetic frames of MIX.TOTAL
REAL_SHARES = (10, 25, 50, 100)  # real-budget sweep: % of the real pool


@dataclass(frozen=True)
class Point:
    """One training set of a sweep: its run folder name, the figure line it belongs to, its x value, the frames of
    each source (before the 70/30 split) and its epochs."""

    name: str
    group: str
    x: float
    counts: dict[str, int] = field(hash=False)
    epochs: int


def ratio_points(base, shares=SIM_SHARES) -> list[Point]:
    """`shares` % (default 0, 10, ..., 100) synthetic frames of the profile's MIX.TOTAL, the profile's epochs."""
    total, epochs = int(base.DATA_CONFIG.MIX.TOTAL), int(base.OPTIMIZATION.NUM_EPOCHS)
    points = []
    for share in shares:
        mix = EasyDict({"TOTAL": total, "SOURCES": [{"NAME": SIM, "RATIO": share / 100},
                                                    {"NAME": REAL, "RATIO": 1 - share / 100}]})
        points.append(Point(f"sim_{share:03d}", "sim + real", share, source_counts(mix), epochs))
    return points


def real_budget_points(base, shares=REAL_SHARES) -> list[Point]:
    """`shares` % (default 10, 25, 50, 100) of the real pool (MIX.TOTAL frames), alone and with MIX.TOTAL / 2
    synthetic frames, each for the recipe's optimizer steps (NUM_EPOCHS x MIX.TOTAL frames)."""
    total, epochs = int(base.DATA_CONFIG.MIX.TOTAL), int(base.OPTIMIZATION.NUM_EPOCHS)
    sim = total // 2
    if 0 in shares:
        raise ConfigError("--grid: 0 % of the real pool trains on synthetic frames alone (the ratio sweep's 100 % "
                          "point); give shares from 1 to 100")
    points = []
    for synthetic in (0, sim):
        group = "real only" if synthetic == 0 else f"real + {synthetic} sim"
        for share in shares:
            real = max(1, round(total * share / 100))
            steps_epochs = max(1, round(epochs * total / (real + synthetic)))
            points.append(Point(f"real_{real:05d}_sim_{synthetic:05d}", group, real,
                                {SIM: synthetic, REAL: real}, steps_epochs))
    return points


SWEEPS = {"ratio": (ratio_points, SIM_SHARES, "synthetic share of the training set [%]", False),
          "real-budget": (real_budget_points, REAL_SHARES, "real training frames (before the 70/30 split)", True)}


def point_config(base, point: Point):
    """base (cfgs/m3.yaml with the profile) with MIX.SOURCES set to the point's frame COUNTs and its epochs."""
    cfg = copy.deepcopy(base)
    entries = {entry.NAME: entry for entry in base.DATA_CONFIG.MIX.SOURCES}
    missing = set(point.counts) - set(entries)
    if missing:
        raise ConfigError(f"{base.CFG_FILE}: DATA_CONFIG.MIX.SOURCES has no source {sorted(missing)}; a sweep mixes "
                          f"the sources '{SIM}' and '{REAL}' of {BASE_MODEL}'s config")
    sources = []
    for name, count in point.counts.items():
        entry = {key: value for key, value in entries[name].items() if key not in ("RATIO", "COUNT")}
        sources.append({**entry, "COUNT": count})
    cfg.DATA_CONFIG.MIX.SOURCES = [EasyDict(entry) for entry in sources]
    cfg.OPTIMIZATION.NUM_EPOCHS = point.epochs
    return cfg


def annotations_replaced(real_only: list[tuple[float, float]], with_sim: list[tuple[float, float]]) -> list[dict]:
    """For each (real frames n, AP) trained with synthetic frames: the real frames that real alone needs for the
    same AP, read off the real-only points [(n, AP)] joined by straight lines (the first n where that line reaches
    the AP). Returns [{real, ap, equivalent_real, saved_fraction}]: equivalent_real None and saved_fraction None
    when the AP is above every real-only point (more than the pool), equivalent_real the smallest n when the AP is
    at or below the first real-only point; saved_fraction = 1 - n / equivalent_real (negative: synthetic frames
    cost AP)."""
    points = sorted(real_only)
    rows = []
    for real, ap in with_sim:
        equivalent = None
        if ap <= points[0][1]:
            equivalent = points[0][0]
        for (n0, ap0), (n1, ap1) in zip(points, points[1:]):
            if equivalent is None and ap0 < ap <= ap1:
                equivalent = n0 + (ap - ap0) / (ap1 - ap0) * (n1 - n0)
        saved = None if equivalent is None else 1 - real / equivalent
        rows.append({"real": real, "ap": ap, "equivalent_real": equivalent, "saved_fraction": saved})
    return rows


def sweep(kind: str, profile: str, seeds: int, out: Path, data_root: Path | None = None, workers: int = 0,
          command: str = "", set_cfgs: list[str] | None = None, jobs: int | None = None,
          grid: list[int] | None = None) -> dict:
    """Run the sweep `kind` (SWEEPS) over `grid` (percentages; default: the sweep's) with training seeds
    0..seeds-1 into `out`; returns the results dict written to out/results.json."""
    if kind not in SWEEPS:
        raise ConfigError(f"unknown sweep '{kind}'; known sweeps: {', '.join(SWEEPS)}")
    jobs = check_run_options(seeds, jobs, workers, len(RUNS))
    started, wall_start = datetime.datetime.now().astimezone(), time.perf_counter()
    make_points, default_grid, xlabel, log_x = SWEEPS[kind]
    grid = list(default_grid if grid is None else grid)
    if not grid or any(not 0 <= share <= 100 for share in grid) or len(set(grid)) != len(grid):
        example = " ".join(map(str, default_grid))
        raise ConfigError(f"--grid {grid}: give distinct percentages from 0 to 100, e.g. --grid {example}")
    base = model_config(BASE_MODEL, profile, data_root, set_cfgs)
    points = make_points(base, sorted(grid))
    cfgs = {point.name: point_config(base, point) for point in points}
    needed = frames_needed(cfgs)
    refuse_overlap(out, [source.root for source in needed.values()], "--out")
    out.mkdir(parents=True, exist_ok=True)
    logger = create_logger(out / "sweep_log.txt")
    clock = StageClock(logger)
    prepare_data(needed, clock, logger)

    test = base.DATA_CONFIG.TEST_SOURCE.NAME
    gt_dir = KittiLayout(needed[test].root).training / "label_2"
    parallel = runs_at_once(seeds * len(points), jobs)
    # a point needs only its test AP: its validation AP after the last epoch, not after each (a tenth of the time)
    todo = training_jobs(cfgs, seeds, out / "points", gt_dir, out, workers, parallel, every_epoch=False)
    with clock(f"train and evaluate {len(todo)} models ({parallel} at once)"):
        finished = run_jobs(todo, parallel, logger)

    rows = []
    for point in points:
        runs = [run for job, run in zip(todo, finished) if job["model"] == point.name]
        mean, std = summarise_runs(runs)
        rows.append({"point": point.name, "group": point.group, "x": point.x, "counts": point.counts,
                     "epochs": point.epochs, "per_seed": [run["metrics"][HEADLINE] for run in runs],
                     "mean": mean[HEADLINE], "std": std[HEADLINE]})
    results = {"sweep": kind, "profile": profile, "profile_settings": profile_settings(base),
               "overrides": list(set_cfgs or []), "seeds": list(range(seeds)), "command": command,
               "date": started.isoformat(timespec="seconds"), "jobs": parallel, "environment": environment(),
               "test_domain": test, "xlabel": xlabel, "rows": rows}
    lines = {group: [row for row in rows if row["group"] == group] for group in dict.fromkeys(r["group"] for r in rows)}
    if kind == "real-budget":  # lines: real only, then real + synthetic
        real_only, with_sim = ([(row["x"], row["mean"]) for row in line] for line in lines.values())
        results["replaced"] = annotations_replaced(real_only, with_sim)
    with clock("figure"):
        plot_sweep(out / f"{kind}.png", {group: [(row["x"], row["per_seed"]) for row in line]
                                         for group, line in lines.items()},
                   xlabel, f"AP on the {test} split: {kind} sweep ({profile} profile, {seeds} seed(s))", log_x)
    results["figure"] = f"{kind}.png"
    results["stages"] = clock.seconds
    results["wall_seconds"] = time.perf_counter() - wall_start
    report_path, json_path = write_report(results, out, render_sweep)
    logger.info(f"report: {report_path}; results: {json_path}")
    return json_safe(results)


def render_sweep(results: dict) -> str:
    """report.md of a sweep: what ran, the table (AP 3D R40 per seed and mean ± std), the figure and, for the
    real-budget sweep, the real frames that the synthetic frames replace."""
    seeds = len(results["seeds"])
    spread = f"mean ± standard deviation (n - 1) over {seeds} training seeds" if seeds > 1 else "one seed"
    lines = [f"# Sweep: {results['sweep']}", "",
             f"- command: `{results['command']}`" if results["command"] else "- command: (called from Python)",
             f"- date: {results['date']}; wall time {results['wall_seconds'] / 60:.1f} min, {results['jobs']} runs "
             f"at once",
             f"- profile: {results['profile']}; what it sets: "
             + ("; ".join(f"`{item}`" for item in results["profile_settings"]) or "nothing (the config as written)"),
             f"- overrides (--set): {' '.join(results['overrides']) or 'none'}",
             f"- tested on every frame of `{results['test_domain']}`; {HEADLINE} at IoU 0.5 as fractions; "
             f"{spread}",
             f"- machine: {results['environment']['machine']['cpu']}, {results['environment']['machine']['cores']} "
             f"cores, GPU: {results['environment']['machine']['gpu'] or 'none'}", "",
             "| point | line | sim frames | real frames | epochs | AP per seed | AP |", "|---|---|---|---|---|---|---|"]
    for row in results["rows"]:
        per_seed = " / ".join("n/a" if ap is None else f"{ap:.3f}" for ap in row["per_seed"])
        lines.append(f"| {row['point']} | {row['group']} | {row['counts'].get(SIM, 0)} | {row['counts'].get(REAL, 0)} "
                     f"| {row['epochs']} | {per_seed} | {ap_text(row['mean'], row['std'], seeds)} |")
    if "replaced" in results:
        lines += ["", "Real frames that the synthetic frames replace at equal AP (the real-only means joined by "
                      "straight lines):", ""]
        for entry in results["replaced"]:
            if entry["equivalent_real"] is None:
                text = "above every real-only point: more than the whole real pool"
            else:
                text = (f"real alone needs {entry['equivalent_real']:.0f} for that AP "
                        f"({entry['saved_fraction']:+.0%} of the real annotations saved)")
            lines.append(f"- {entry['real']} real + synthetic: AP {entry['ap']:.3f}; {text}")
    lines += ["", f"![{results['sweep']} sweep]({results['figure']})", ""]
    return "\n".join(lines)
