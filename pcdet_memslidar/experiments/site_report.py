"""report.md of a `memslidar site train` run (experiments.site_detector's results dict): the detectors side by side."""
from __future__ import annotations

from pathlib import Path

from pcdet_memslidar.experiments.report import run_header, wall_time

NAMES = {"background": "background subtraction (classical)", "second": "SECOND",
         "second_background": "SECOND + background_depth"}
SET_TITLES = {"test": "people", "pairs": "people in pairs", "test_distractors": "people beside distractors"}


def _ap(entry: dict, metric: str = "AP3D_R40") -> str:
    """'0.812 [0.776, 0.843]': an AP with its interval; 'n/a' for a set without people (AP undefined)."""
    low, high = entry["interval"][metric]
    if entry[metric] is None or low is None:
        return "n/a"
    return f"{entry[metric]:.3f} [{low:.3f}, {high:.3f}]"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def side_by_side(results: dict) -> list[str]:
    """The detectors' table: AP on each composited held-out set, false alarms on the sets without people, speed."""
    scores, alarms = results["scores"], results["false_alarms"]
    sets = list(next(iter(scores.values())))
    header = ["detector", *(f"AP 3D R40 [95 %], {SET_TITLES.get(name, name)}" for name in sets),
              "AP BEV R40, people", "empty frames: detections / frame", "distractor frames: detections / frame",
              "frames / s (detect)"]
    rows = [[NAMES.get(detector, detector), *(_ap(scores[detector][name]) for name in sets),
             _ap(scores[detector]["test"], "APBEV_R40"),
             _per_frame(alarms["empty"][detector]), _per_frame(alarms["distractors"][detector]),
             f"{alarms['distractors'][detector]['frames_per_s']:.1f}"]
            for detector in scores]
    return _table(header, rows)


def _per_frame(alarms: dict) -> str:
    """'0.00 (3 frames, 0.37 s)': detections per frame with the frames and seconds of recording they rest on."""
    return f"{alarms['detections_per_frame']:.2f} ({alarms['frames']} frames, {alarms['seconds']:.2f} s)"


def sites_table(runs: list[dict]) -> list[str]:
    """One table over several `site train` runs (their results dicts): per site and detector the AP 3D R40 on each
    held-out set with people, false alarms per frame without people, frames per second; a header line per run says
    when, where and how it ran."""
    header = ["site", "detector", "AP 3D R40, people", "people in pairs", "people beside distractors",
              "empty: detections / frame", "distractors: detections / frame", "frames / s"]
    rows, sources = [], []
    for results in runs:
        alarms = results["false_alarms"]
        sources.append(f"- {results['site']}: {run_header(results)}; {wall_time(results)}")
        for detector, scores in results["scores"].items():
            rows.append([results["site"], NAMES.get(detector, detector),
                         *(_ap(scores[name]) for name in ("test", "pairs", "test_distractors")),
                         _per_frame(alarms["empty"][detector]), _per_frame(alarms["distractors"][detector]),
                         f"{alarms['distractors'][detector]['frames_per_s']:.1f}"])
    return [*sources, "", *_table(header, rows)]


def compared_models(results: dict) -> list[str]:
    """False alarms of every model (the site's and the bundled --compare ones) on the sets without people."""
    alarms = results["false_alarms"]
    rows = [[NAMES.get(model, model), _per_frame(alarms["empty"][model]),
             str(alarms["empty"][model]["confirmed_tracks"]), _per_frame(alarms["distractors"][model]),
             str(alarms["distractors"][model]["confirmed_tracks"])]
            for model in alarms["empty"]]
    return _table(["model", "empty: detections / frame", "empty: confirmed tracks", "distractors: detections / frame",
                   "distractors: confirmed tracks"], rows)


def render_site_report(results: dict) -> str:
    """report.md of a `site train` run."""
    empty = results["false_alarms"]["empty"]
    first = next(iter(empty.values()))
    distractor_frames = next(iter(results["false_alarms"]["distractors"].values()))["frames"]
    background, classical = results["background_model"], results["classical"]
    lines = [
        f"# Site detectors: {results['site']}", "",
        f"{run_header(results)}; profile {results['profile']}; wall time {wall_time(results)}.", "",
        f"Background recording: `{results['background']}`; frames {results['held_out_frames'][0]} to "
        f"{results['held_out_frames'][1] - 1} held out (never trained on, nor in the background model). Mount "
        f"{results['mount']}. Grid (POINT_CLOUD_RANGE) {results['point_cloud_range']}. Background model: "
        f"{background['frames']} empty frames, margin {background['margin_m']} m + {background['margin_per_m']} x "
        f"range, {100 * background['no_background_share']:.1f} % of the pulses without a background.", "",
        "## The detectors side by side", "",
        f"AP at 3D IoU 0.5 on people composited into the held-out frames, with its 95 % bootstrap interval over the "
        f"frames of each set; false alarms (detections at score >= {results['min_score']}, the tracker's min_score) on "
        f"the {first['frames']} held-out empty frames ({first['seconds']:.2f} s of recording: per minute extrapolates "
        f"from that) and on {distractor_frames} held-out frames with 1-3 composited distractors (boxes, pallets, "
        "carts, a forklift, open doors, posts) and nobody; frames per second of `memslidar detect` on the distractor "
        "frames.",
        "", *side_by_side(results), "",
        "## False alarms of every model", "", *compared_models(results), ""]
    if classical["settings"]:
        trials = classical["trials"]
        varied = [key for key in classical["settings"] if len({str(t["settings"][key]) for t in trials}) > 1]
        lines += ["## The classical detector's settings", "",
                  f"Chosen on the validation part of the composited training frames (AP 3D R40), never on held-out "
                  f"frames: **{classical['settings']}**. All trials:", "",
                  *_table([*varied, "validation AP 3D R40"],
                          [[*(str(trial["settings"][key]) for key in varied), f"{trial['AP3D_R40']:.3f}"]
                           for trial in trials]), ""]
    lines += [f"![held-out frames]({Path(results['figure']).name})", "",
              "## Detect on new recordings of the site", ""]
    mount = results["mount"]
    for detector, config in results["configs"].items():
        checkpoint = results["checkpoints"][detector]
        lines.append(f"    memslidar detect --cfg {config} --profile {results['profile']}"
                     f"{f' --ckpt {checkpoint}' if checkpoint else ''} --src NEW_RECORDING --mount "
                     f"{mount['height']},{mount['tilt_deg']},{mount['roll_deg']} --zones ZONES.yaml --out OUT")
    return "\n".join(lines) + "\n"
