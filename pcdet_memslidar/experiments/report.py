"""report.md of a results dict (experiments.results): Tables 2 and 3 beside the paper's, the paper's order, AP and
orientation error per distance bin, figures, data, environment and wall time; write_report writes results.json and
report.md.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from pcdet_memslidar.experiments.results import (
    HEADLINE,
    INTERVAL_METRICS,
    ORACLE,
    ORIENTATION,
    PAPER_AP,
    PAPER_COUNTS,
    PAPER_ORDER,
    REFERENCE_MODEL,
    TABLE3_COLUMNS,
    counterpart,
    gain_over_reference,
    json_safe,
)
from pcdet_memslidar.models import DETECTORS
from pcdet_memslidar.utils.atomic import write_text


def ap_text(mean: float | None, std: float | None, seeds: int, interval: list | None = None) -> str:
    """'0.291 ± 0.060' over several seeds, '0.291' for one, 'n/a' where undefined; with its bootstrap interval
    (add_intervals) '0.291 [0.240, 0.342]'."""
    if mean is None:
        return "n/a"
    return (f"{mean:.3f} ± {std:.3f}" if seeds > 1 else f"{mean:.3f}") + _interval_text(interval, "{:.3f}")


def _interval_text(interval: list | None, number: str, scale: float = 1.0) -> str:
    """' [low, high]' with both bounds formatted by `number` after multiplying by `scale`; '' without an interval."""
    if interval is None or None in interval:
        return ""
    return " [" + ", ".join(number.format(scale * bound) for bound in interval) + "]"


def _pp(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.1f}"


def difference_text(models: dict, name: str, other: str, metric: str = HEADLINE) -> str:
    """Mean `metric` of model `name` minus model `other`'s in percentage points, with the paired bootstrap interval
    where there is one: '+4.1 [-1.2, +9.0]'."""
    gain = gain_over_reference(models, metric, other)[name]
    interval = models[name].get("difference_interval", {}).get(other, {}).get(metric)
    return _pp(gain) + ("" if gain is None else _interval_text(interval, "{:+.1f}", 100.0))


def order_sign(models: dict, a: str, b: str, metric: str = HEADLINE) -> str:
    """How model a's mean `metric` stands to b's. With bootstrap intervals (add_intervals): '>' or '<' only where the
    paired interval of a - b excludes 0, else '≈' (the intervals cannot order them); without: '>', '<' or '=' of
    the means."""
    interval = models[a].get("difference_interval", {}).get(b, {}).get(metric)
    if interval is None:
        mean_a, mean_b = models[a]["mean"][metric], models[b]["mean"][metric]
        return ">" if mean_a > mean_b else "<" if mean_a < mean_b else "="
    low, high = (math.nan if bound is None else bound for bound in interval)
    return ">" if low > 0 else "<" if high < 0 else "≈"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _bin_labels(models: dict) -> list[str]:
    """Distance-bin suffixes present in the metrics ('0-10m', ...), in evaluation order."""
    first = next(iter(models.values()))["mean"]
    return [key[len(HEADLINE) + 1:] for key in first if key.startswith(HEADLINE + "_")]


def table2(results: dict) -> list[str]:
    """Markdown lines of Table 2 as built: frames per source of each training set and its train/val split."""
    rows = []
    for name, model in results["models"].items():
        if name not in PAPER_COUNTS:
            continue
        counts = model["counts"]
        sim, real = counts.get("sim", {}), counts.get("real", {})
        total = sum(source["frames"] for source in counts.values()) or 1
        paper = PAPER_COUNTS.get(name)
        rows.append([
            name,
            f"{100 * sim.get('frames', 0) / total:.0f} / {100 * real.get('frames', 0) / total:.0f}",
            f"{sim.get('frames', 0)} / {real.get('frames', 0)}",
            f"{sim.get('train', 0)} / {real.get('train', 0)}",
            f"{sim.get('val', 0)} / {real.get('val', 0)}",
            f"{paper['sim']} / {paper['real']}" if paper else "-",
        ])
    return _table(["Model", "Synthetic / Real (%)", "Synthetic / Real (frames)", "train", "val",
                   "paper (frames)"], rows)


def other_training_sets(results: dict) -> list[str]:
    """Markdown lines for the models beyond Table 2 (the oracle): their sources with frames, train and val."""
    lines = []
    for name, model in results["models"].items():
        if name in PAPER_COUNTS:
            continue
        sources = ", ".join(f"`{source}` {entry['frames']} frames ({entry['train']} train / {entry['val']} val)"
                            for source, entry in model["counts"].items())
        lines.append(f"- {name}: {sources}")
    return lines


def order_statement(results: dict, metric: str = HEADLINE) -> str:
    """Whether this run's M1-M4 rank as in the paper (M3 > M4 > M2 > M1), pair by pair, and where the oracle stands.

    With bootstrap intervals (add_intervals) two models are ordered only where the paired interval of their
    difference excludes 0 (order_sign); without, by their means.
    """
    models, seeds = results["models"], len(results["seeds"])
    means = {name: models[name]["mean"].get(metric) for name in PAPER_ORDER if name in models}
    if len(means) < len(PAPER_ORDER) or any(value is None for value in means.values()):
        return "The paper's order cannot be checked: some of M1-M4 have no AP."
    order = sorted(means, key=means.get, reverse=True)
    pairs = list(zip(PAPER_ORDER, PAPER_ORDER[1:]))
    signs = [order_sign(models, a, b, metric) for a, b in pairs]
    verdict = ("holds" if all(sign == ">" for sign in signs) else
               "does not hold" if any(sign in "<=" for sign in signs) else "cannot be confirmed")
    ranked = f"{order[0]} ({means[order[0]]:.3f})" + "".join(
        f" {order_sign(models, a, b, metric)} {b} ({means[b]:.3f})" for a, b in zip(order, order[1:]))
    text = f"The paper's order M3 > M4 > M2 > M1 {verdict} here: this run gives {ranked}."
    intervals = results.get("intervals")
    if intervals and metric in INTERVAL_METRICS:
        verdicts = {">": "{a} > {b} as in the paper", "<": "{a} < {b}, against the paper",
                    "≈": "the intervals cannot order {a} and {b}"}
        steps = []
        for (a, b), sign in zip(pairs, signs):
            interval = _interval_text(models[a]["difference_interval"][b][metric], "{:+.3f}")
            steps.append(f"{a} - {b} {means[a] - means[b]:+.3f}{interval}, " + verdicts[sign].format(a=a, b=b))
        text += (f" Pair by pair, the difference with its paired {100 * intervals['level']:g} % bootstrap interval "
                 f"over the {intervals['frames']} test frames (≈: the interval includes 0): {'; '.join(steps)}.")
    if seeds > 1:
        close = [f"{a} - {b}" for a, b in zip(order, order[1:])
                 if means[a] - means[b] <= max(models[a]["std"][metric], models[b]["std"][metric])]
        text += (f" Gaps within one standard deviation of the {seeds} seeds: {', '.join(close)}." if close
                 else f" Every gap is larger than the standard deviation over {seeds} seeds.")
    oracle = models.get(ORACLE, {}).get("mean", {}).get(metric)
    if oracle is not None:
        best = order[0]
        signs = {name: order_sign(models, ORACLE, name, metric) for name in means}
        words = {">": "above", "<": "below", "=": "level with", "≈": "not ordered by the intervals against"}
        where = "above every mix" if all(sign == ">" for sign in signs.values()) else "; ".join(
            f"{word} {', '.join(name for name in means if signs[name] == sign)}" for sign, word in words.items()
            if sign in signs.values())
        text += f" The oracle (in-domain training) reaches {oracle:.3f}, {where}"
        text += f"; the best mix, {best}, reaches {100 * means[best] / oracle:.0f} % of it." if oracle > 0 else "."
    return text


def detector_names() -> dict[str, str]:
    """MODEL.NAME -> Table 3's name (its display_name) of every registered detector (models.DETECTORS)."""
    return {name: detector.display_name for name, detector in DETECTORS.items()}


def finetune_statement(results: dict, metric: str = HEADLINE) -> str:
    """M5 (pre-trained on sim, fine-tuned on real) against M3 (sim and real mixed) at the same compute; '' without
    both."""
    models, seeds = results["models"], len(results["seeds"])
    if "M5" not in models or "M3" not in models:
        return ""
    m5, m3 = models["M5"]["mean"].get(metric), models["M3"]["mean"].get(metric)
    if m5 is None or m3 is None:
        return "M5 against M3 cannot be compared: one of them has no AP."
    spread = max(models["M5"]["std"][metric], models["M3"]["std"][metric])
    verdict = "above" if m5 > m3 else "below" if m5 < m3 else "level with"
    within = f"; the gap is within one standard deviation of the {seeds} seeds" if seeds > 1 and abs(m5 - m3) <= \
        spread else ""
    return (f"Pre-training on sim and fine-tuning on real (M5, {m5:.3f}) is {verdict} mixing them (M3, {m3:.3f}) at "
            f"the same number of optimizer steps{within}.")


def table3(results: dict) -> list[str]:
    """Markdown lines of Table 3: AP at IoU 0.5 (3D and BEV, R40 and R11), gain over M1, the difference to the oracle
    (where it ran), ms/frame, the paper's AP; with bootstrap intervals where add_intervals filled them."""
    models, seeds = results["models"], len(results["seeds"])
    paper_gain = {name: 100.0 * (value - PAPER_AP[REFERENCE_MODEL]) for name, value in PAPER_AP.items()}
    with_oracle = any((entry.get("model") or name) == ORACLE for name, entry in models.items())
    names = detector_names()
    rows = []
    for name, model in models.items():
        mean, std, interval = model["mean"], model["std"], model.get("interval", {})
        ms, orientation = mean.get("ms_per_frame"), mean.get(ORIENTATION)
        references = [counterpart(models, name, base) for base in (REFERENCE_MODEL, *[ORACLE] * with_oracle)]
        rows.append([name if name in PAPER_AP else f"{name} (not in the paper)",
                     names.get(model.get("detector", "SECONDNet"), model.get("detector")),
                     ap_text(mean.get(HEADLINE), std.get(HEADLINE), seeds, interval.get(HEADLINE)),
                     f"{PAPER_AP[name]:.2f}" if name in PAPER_AP else "-",
                     *(("-" if other is None else difference_text(models, name, other)) for other in references[:1]),
                     _pp(paper_gain.get(name)),
                     *(("-" if other is None else difference_text(models, name, other)) for other in references[1:]),
                     *(ap_text(mean.get(key), std.get(key), seeds, interval.get(key)) for key in TABLE3_COLUMNS[1:]),
                     "n/a" if orientation is None else f"{orientation:.1f}", "n/a" if ms is None else f"{ms:.1f}"])
    return _table(["Model", "Architecture", "AP 3D R40", "paper AP", "gain over M1 (pp)", "paper gain (pp)",
                   *(["vs oracle (pp)"] * with_oracle), "AP 3D R11", "AP BEV R40", "AP BEV R11",
                   "orientation error (deg)", "ms/frame"], rows)


def interval_note(results: dict) -> str:
    """What Table 3's brackets mean; '' without bootstrap intervals."""
    intervals = results.get("intervals")
    if not intervals:
        return ""
    seeds = len(results["seeds"])
    if seeds == 1:
        return (f"Brackets: {100 * intervals['level']:g} % bootstrap percentile interval over the "
                f"{intervals['frames']} test frames ({intervals['resamples']} resamples of the frames with "
                f"replacement, seed {intervals['seed']}); the differences to M1 and the oracle resample the same "
                "frames for both models (paired). They cover which test frames were drawn, not the training seed.")
    return (f"Values: the mean over {seeds} training seeds ± their standard deviation. Brackets: "
            f"{100 * intervals['level']:g} % bootstrap percentile interval of that mean over the "
            f"{intervals['frames']} test frames and the {seeds} seeds ({intervals['resamples']} resamples, each "
            f"drawing frames and each model's seeds with replacement, seed {intervals['seed']}); the differences to "
            "M1 and the oracle draw the same frames for both models (paired). They cover the test frames and the "
            "training seeds, not the CPU.")


def final_test_lines(results: dict) -> list[str]:
    """The section of Table 3 on the untouched seed (reproduce's stage 5); [] where it did not run."""
    final = results.get("final_test")
    if not final:
        return []
    note = interval_note(final)
    return [f"### Table 3 on an untouched seed: `{final['test_domain']}` simulated with seed {final['seed']}", "",
            "The same checkpoints on a split of the test domain that no selection rule, tool or analysis has read: "
            "where it disagrees with the table above, the difference is how much the usual test split has been "
            "looked at, or how much one split of frames decides.", "",
            *table3(final), "", *([note, ""] if note else []), order_statement(final), ""]


def bin_table(results: dict) -> list[str]:
    """Markdown lines of AP 3D R40 per distance bin, with the ground-truth count of each bin."""
    models, seeds = results["models"], len(results["seeds"])
    labels = _bin_labels(models)
    num_gt = next(iter(models.values()))["runs"][0]["num_gt"]
    rows = [[name, *(ap_text(model["mean"].get(f"{HEADLINE}_{label}"), model["std"].get(f"{HEADLINE}_{label}"), seeds)
                     for label in labels)] for name, model in models.items()]
    return _table(["Model", *(f"{label} ({num_gt.get(label, 0)} gt)" for label in labels)], rows)


def orientation_bin_table(results: dict) -> list[str]:
    """Markdown lines of the median orientation error [deg] of matched people per distance bin (the AP bins), with
    the seeds' standard deviation; [] for results scored before the bins."""
    models, seeds = results["models"], len(results["seeds"])
    labels = [label for label in _bin_labels(models) if f"{ORIENTATION}_{label}" in next(iter(models.values()))["mean"]]
    if not labels:
        return []

    def cell(model: dict, label: str) -> str:
        mean, std = model["mean"].get(f"{ORIENTATION}_{label}"), model["std"].get(f"{ORIENTATION}_{label}")
        return "n/a" if mean is None else f"{mean:.1f} ± {std:.1f}" if seeds > 1 else f"{mean:.1f}"
    rows = [[name, *(cell(model, label) for label in labels)] for name, model in models.items()]
    return _table(["Model", *labels], rows)


def cpu_table(runs: list[dict], metric: str = HEADLINE) -> list[str]:
    """Markdown lines: one row per reproduction in `runs` (one profile, on different CPUs or vector code) with each
    model's seed mean ± std of `metric`, then the spread between the rows (largest minus smallest mean)."""
    names = list(dict.fromkeys(name for results in runs for name in results["models"]))
    rows = []
    for results in runs:
        machine = results["environment"]["machine"]
        models, seeds = results["models"], len(results["seeds"])
        rows.append([machine["cpu"], machine.get("aten_cpu_capability") or "n/a",
                     results["environment"].get("commit") or "unknown", f"`{results['command']}`", str(seeds),
                     *(ap_text(models[name]["mean"].get(metric), models[name]["std"].get(metric), seeds)
                       if name in models else "-" for name in names)])
    if len(runs) > 1:
        spread = []
        for name in names:
            means = [results["models"][name]["mean"].get(metric) for results in runs if name in results["models"]]
            means = [value for value in means if value is not None]
            spread.append(f"{max(means) - min(means):.3f}" if len(means) > 1 else "-")
        rows.append(["**spread between the rows**", "", "", "", "", *spread])
    return _table(["CPU", "torch vector code", "commit", "command", "seeds", *names], rows)


def machine_line(environment: dict) -> str:
    """'CPU (vector extensions; torch's vector code, oneDNN's limit where set), N cores, GPU' of
    results['environment'] (results from before the extensions were recorded: the CPU alone)."""
    machine = environment["machine"]
    vectors = ", ".join(machine.get("vector_extensions", []))
    if machine.get("aten_cpu_capability"):
        vectors += f"; torch vector code {machine['aten_cpu_capability']}"
    if machine.get("onednn_max_cpu_isa"):
        vectors += f", oneDNN up to {machine['onednn_max_cpu_isa']}"
    return (f"{machine['cpu']}{f' ({vectors})' if vectors else ''}, {machine['cores']} cores, GPU: "
            f"{machine['gpu'] or 'none'}")


def wall_time(results: dict) -> str:
    """'24.8 min, 1-min load average 1.1 at the end': a run's wall time and how busy the machine was, and how many
    of its trainings (a reproduction's runs, a site's learned detectors: results['read_back']) were read back from
    earlier calls (whose time it does not include)."""
    load = results["environment"]["machine"].get("load_average_1min")
    read_back = ([bool(run.get("read_back")) for entry in results.get("models", {}).values() for run in entry["runs"]]
                 or list(results.get("read_back", {}).values()))
    return (f"{results['wall_seconds'] / 60:.1f} min" + ("" if load is None else
                                                          f", 1-min load average {load:.1f} at the end")
            + (f" ({sum(read_back)} of {len(read_back)} trainings read back from earlier calls in its --out, their "
               "time not included)" if any(read_back) else ""))


def run_header(results: dict) -> str:
    """The one line that says where a table's numbers come from: date, machine, commit, command."""
    commit = results["environment"].get("commit") or "unknown"
    return f"{results['date']}; {machine_line(results['environment'])}; commit {commit}; `{results['command']}`"


def _environment_lines(results: dict) -> list[str]:
    environment = results["environment"]
    machine = environment["machine"]
    libraries = ", ".join(f"{name} {version}" for name, version in environment["libraries"].items())
    return [f"- package: pcdet-memslidar {environment['package']} (commit {environment.get('commit') or 'unknown'}), "
            f"Python {environment['python']}",
            f"- libraries: {libraries}",
            f"- machine: {machine_line(environment)}, torch threads {machine['torch_threads']}; 1-min load average at "
            f"the end {machine['load_average_1min']:.1f} (timings grow when other processes share the cores)"]


def _stage_lines(results: dict) -> list[str]:
    rows = [[name, f"{seconds:.1f}"] for name, seconds in results["stages"].items()]
    rows.append(["**total**", f"**{results['wall_seconds']:.1f}**"])
    lines = _table(["stage", "wall time (s)"], rows)
    timed = [(name, run) for name, model in results["models"].items() for run in model["runs"] if "seconds" in run]
    if timed:
        lines += ["", f"Per model ({results.get('jobs', 1)} trained at once; training time includes the validation "
                      "after each epoch):", ""]
        lines += _table(["model", "seed", "torch threads", "train (s)", "evaluate (s)"],
                        [[name, str(run["seed"]), str(run.get("threads", "")), f"{run['seconds']['train']:.1f}",
                          f"{run['seconds']['evaluate']:.1f}"] for name, run in timed])
    return lines


def _data_lines(results: dict) -> list[str]:
    rows = [[domain, str(entry["frames"]), str(entry["boxes"]), f"`{entry['path']}`"]
            for domain, entry in results["data"].items()]
    return _table(["domain", "frames", "boxes", "folder"], rows)


def _figure_lines(results: dict) -> list[str]:
    figures, lines = results.get("figures", {}), []
    if "examples" in figures:
        lines += ["### Example frames (Fig. 3 style)", "",
                  "Bird's-eye view (top) and side view (bottom) of three industrial frames; ground truth blue, "
                  "predictions green (score >= the threshold in the title), one column per model. Frames were "
                  "chosen automatically:", ""]
        lines += [f"- **{entry['role']}** (frame {entry['frame_id']}): {entry['why']}"
                  for entry in results.get("example_frames", [])]
        lines += ["", f"![example frames]({figures['examples']})", ""]
    if "ap_intervals" in figures:
        lines += ["### AP with its interval", "",
                  "AP 3D R40 of every model with its 95 % bootstrap interval over the test frames, the paper's AP "
                  "(crosses) and the oracle's (dashed).", "", f"![AP with intervals]({figures['ap_intervals']})", ""]
    if "pr_curves" in figures:
        lines += ["### Precision-recall curves", "", "Industrial split, IoU 0.5, all distances (first seed).", "",
                  f"![precision-recall curves]({figures['pr_curves']})", ""]
    if "training_curves" in figures:
        lines += ["### Convergence", "",
                  "Training loss per epoch (mean over the epoch), and AP 3D R40 on each model's own validation split "
                  "(the 30 % of its mix; the oracle's: industrial frames of its own seed) after every epoch against "
                  "the training minutes so far (first seed). A curve still rising at its end says more training "
                  "would pay.", "",
                  f"![training curves]({figures['training_curves']})", ""]
    if "ap_vs_time" in figures:
        lines += ["### AP against inference time", "",
                  "AP 3D (R40) on the industrial split against CPU inference time per frame: the models of this run "
                  "and the configurations of tools/benchmark_model.py where its results file exists.", "",
                  f"![AP against inference time]({figures['ap_vs_time']})", ""]
    return lines


def render_report(results: dict) -> str:
    """report.md text of `results`."""
    seeds = results["seeds"]
    seed_note = (f"mean ± standard deviation over {len(seeds)} training seeds {seeds}" if len(seeds) > 1
                 else f"one training seed ({seeds[0]})")
    overrides = f" with overrides `{' '.join(results['overrides'])}`" if results.get("overrides") else ""
    finetune, note, orientation = finetune_statement(results), interval_note(results), orientation_bin_table(results)
    lines = [
        "# M1-M4 reproduction report", "",
        f"- profile: **{results['profile']}**{overrides}; {seed_note}",
        f"- command: `{results['command']}`",
        *([f"- what the profile sets (its PROFILES entry; the rest is the config as written): "
           f"{'; '.join(f'`{item}`' for item in results['profile_settings'])}"]
          if results.get("profile_settings") else []),
        f"- date: {results['date']}; total wall time {results['wall_seconds'] / 60:.1f} min", "",
        "The bundled `real` and `industrial` domains are **simulated stand-ins** for the paper's unpublished Cube 1 "
        "recordings (docs/design.md, Domains); the numbers below compare the method, not the paper's data.", "",
        "## Table 2: training sets as built", "",
        "Frames of each source before the stable 70/30 train/val split, and after it.", "",
        *table2(results), "",
        *other_training_sets(results), "",
        f"## Table 3: SECOND on the unseen `{results['test_domain']}` split", "",
        "AP at IoU 0.5 (fractions). The paper's AP is compared with AP 3D R40; gains are percentage points over M1 "
        "(the paper's '+44 %' is 0.54 - 0.10). ms/frame: model forward and post-processing per frame on this machine"
        + (f", timed while {results['jobs']} models shared its cores (tools/benchmark_model.py times one alone)."
           if results.get("jobs", 1) > 1 else "."),
        "",
        *table3(results), "",
        *([note, ""] if note else []),
        order_statement(results), "",
        *([finetune, ""] if finetune else []),
        *final_test_lines(results),
        "### AP 3D R40 per distance bin (BEV range from the sensor)", "",
        *bin_table(results), "",
        *(["### Orientation error per distance bin (median deg over matched people)", "",
           "A far person's few returns are about as wide every way, and their main axis tells little of the "
           "person's (a guess scores 45 deg on people facing every way): a model that finds more far people has a "
           "larger overall error.", "", *orientation, ""] if orientation else []),
        *_figure_lines(results),
        "## Data", "",
        *_data_lines(results), "",
        "## Environment", "",
        *_environment_lines(results), "",
        "## Wall time per stage", "",
        *_stage_lines(results), "",
    ]
    return "\n".join(lines)


def write_report(results: dict, out_dir: str | Path, render=None) -> tuple[Path, Path]:
    """Write `out_dir`/results.json and `out_dir`/report.md (render(results) -> markdown; default: the
    reproduction's render_report) atomically; returns their paths."""
    out_dir = Path(out_dir)
    results = json_safe(results)
    json_path, report_path = out_dir / "results.json", out_dir / "report.md"
    write_text(json_path, json.dumps(results, indent=2) + "\n")
    write_text(report_path, (render or render_report)(results))
    return report_path, json_path
