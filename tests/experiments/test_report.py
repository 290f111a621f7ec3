"""Report writer on hand-made results (no training): exact numbers, complete tables, bootstrap intervals."""
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.config import load_config, profile_settings
from pcdet_memslidar.experiments.report import (
    order_statement,
    orientation_bin_table,
    render_report,
    table2,
    table3,
    write_report,
)
from pcdet_memslidar.experiments.results import (
    add_intervals,
    counterpart,
    gain_over_reference,
    score_run,
    summarise_runs,
)
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io.kitti import label_from_boxes, write_label

CFGS = Path(__file__).resolve().parents[2] / "cfgs"
TOOL = Path(__file__).resolve().parents[2] / "tools" / "research" / "report_intervals.py"


def make_results(ap: dict, seeds=(0,), std=0.0):
    models = {}
    for name, value in ap.items():
        metrics = {"AP3D_R40": value, "AP3D_R11": value + 0.01, "APBEV_R40": value + 0.02, "APBEV_R11": value + 0.03,
                   "AP3D_R40_0-10m": value, "AP3D_R40_10-20m": None, "ms_per_frame": 120.0}
        sim = {"M1": 0, "M2": 20, "M3": 10, "M4": 14, "oracle": 0}[name]
        counts = {"sim": {"frames": sim, "train": sim - sim * 3 // 10, "val": sim * 3 // 10},
                  "real": {"frames": 20 - sim, "train": (20 - sim) - (20 - sim) * 3 // 10, "val": (20 - sim) * 3 // 10}}
        models[name] = {"cfg": f"cfgs/{name.lower()}.yaml", "counts": counts, "mean": metrics,
                        "std": {key: (None if v is None else std) for key, v in metrics.items()},
                        "runs": [{"seed": s, "metrics": metrics, "num_gt": {"all": 5, "0-10m": 3, "10-20m": 0},
                                  "num_dt": {"all": 7}, "predictions": f"models/{name}/seed_{s}/pred"} for s in seeds]}
    return {"profile": "smoke", "seeds": list(seeds), "command": "memslidar reproduce --profile smoke",
            "date": "2025-01-01T00:00:00+00:00", "wall_seconds": 90.0, "test_domain": "industrial",
            "environment": {"package": "0.1.0", "python": "3.11", "libraries": {"torch": "2.13.0"},
                            "machine": {"cpu": "test cpu", "cores": 2, "torch_threads": 2, "gpu": None,
                                        "load_average_1min": 1.5}},
            "stages": {"data": 10.0, "train M1": 20.0},
            "data": {"industrial": {"path": "/d", "frames": 8, "boxes": 20}},
            "models": models, "figures": {"examples": "fig3_examples.png"},
            "example_frames": [{"role": "easy", "frame_id": "000001", "why": "because"}]}


def test_summarise_runs_mean_and_sample_std():
    runs = [{"metrics": {"AP3D_R40": 0.2, "bin": 0.5}}, {"metrics": {"AP3D_R40": 0.4, "bin": None}}]
    mean, std = summarise_runs(runs)
    assert mean["AP3D_R40"] == pytest.approx(0.3)
    assert std["AP3D_R40"] == pytest.approx(np.sqrt(0.02))  # sample std of (0.2, 0.4)
    assert mean["bin"] is None and std["bin"] is None
    one_mean, one_std = summarise_runs(runs[:1])
    assert one_mean["AP3D_R40"] == 0.2 and one_std["AP3D_R40"] == 0.0


def test_gain_over_m1_in_percentage_points():
    results = make_results({"M1": 0.10, "M2": 0.27, "M3": 0.54, "M4": 0.45})
    gains = gain_over_reference(results["models"])
    assert gains["M1"] == pytest.approx(0.0)
    assert gains["M3"] == pytest.approx(44.0)
    assert gains["M4"] == pytest.approx(35.0)


def test_report_tables_complete_and_consistent(tmp_path):
    results = make_results({"M1": 0.10, "M2": 0.27, "M3": 0.54, "M4": 0.45})
    report_path, json_path = write_report(results, tmp_path)
    text = report_path.read_text()
    stored = json.loads(json_path.read_text())
    assert stored["models"]["M3"]["mean"]["AP3D_R40"] == 0.54
    assert stored["models"]["M3"]["mean"]["AP3D_R40_10-20m"] is None
    model_rows = [line for line in text.splitlines() if line.startswith(("| M1 ", "| M2 ", "| M3 ", "| M4 "))]
    assert len(model_rows) == 4 + 4 + 4  # Table 2, Table 3 and the distance-bin table each have M1-M4
    assert "| M3 | SECOND | 0.540 | 0.54 | +44.0 | +44.0 | 0.550 | 0.560 | 0.570 | n/a | 120.0 |" in text
    assert "| M4 | 70 / 30 | 14 / 6 | 10 / 5 | 4 / 1 | 1470 / 630 |" in text
    assert "0-10m (3 gt)" in text and "10-20m (0 gt)" in text and "n/a" in text
    assert "simulated stand-ins" in text and "![example frames](fig3_examples.png)" in text
    assert "**easy** (frame 000001): because" in text


def test_report_with_seeds_shows_mean_and_std(tmp_path):
    results = make_results({"M1": 0.1, "M2": 0.2, "M3": 0.3, "M4": 0.4}, seeds=(0, 1, 2), std=0.05)
    text = render_report(results)
    assert "mean ± standard deviation over 3 training seeds [0, 1, 2]" in text
    assert "| M2 | SECOND | 0.200 ± 0.050 | 0.27 | +10.0 | +17.0 |" in text


def test_order_statement_ties_seeds_and_oracle():
    held = order_statement(make_results({"M1": 0.1, "M2": 0.2, "M3": 0.4, "M4": 0.3, "oracle": 0.5}))
    assert held == ("The paper's order M3 > M4 > M2 > M1 holds here: this run gives M3 (0.400) > M4 (0.300) > "
                    "M2 (0.200) > M1 (0.100). The oracle (in-domain training) reaches 0.500, above every mix; the "
                    "best mix, M3, reaches 80 % of it.")
    tied = order_statement(make_results({"M1": 0.0, "M2": 0.0, "M3": 0.0, "M4": 0.0, "oracle": 0.0}))
    assert tied == ("The paper's order M3 > M4 > M2 > M1 does not hold here: this run gives M3 (0.000) = M4 (0.000) "
                    "= M2 (0.000) = M1 (0.000). The oracle (in-domain training) reaches 0.000, level with M3, M4, M2, "
                    "M1.")
    noisy = order_statement(make_results({"M1": 0.1, "M2": 0.2, "M3": 0.4, "M4": 0.35}, seeds=(0, 1, 2), std=0.06))
    assert noisy.endswith("M3 (0.400) > M4 (0.350) > M2 (0.200) > M1 (0.100). Gaps within one standard deviation of "
                          "the 3 seeds: M3 - M4.")


def test_table2_percentages():
    lines = table2(make_results({"M1": 0.1, "M2": 0.1, "M3": 0.1, "M4": 0.1}))
    assert lines[2].startswith("| M1 | 0 / 100 | 0 / 20 |")
    assert lines[4].startswith("| M3 | 50 / 50 | 10 / 10 |")


def test_report_states_what_its_profile_sets():
    settings = profile_settings(load_config(CFGS / "m3.yaml", profile="quick"))
    assert "DATA_CONFIG.MIX.TOTAL 1200" in settings and "OPTIMIZATION.NUM_EPOCHS 2" in settings
    assert 'DATA_CONFIG.DATA_PROCESSOR[0].NAME "fold_box_headings"' in settings
    assert "MODEL.DENSE_HEAD.ANCHOR_GENERATOR_CONFIG[0].anchor_rotations [0]" in settings
    assert profile_settings(load_config(CFGS / "m3.yaml", profile="paper")) == []  # the config as written
    text = render_report(make_results({"M1": 0.1, "M2": 0.2, "M3": 0.3, "M4": 0.4}) | {"profile_settings": settings})
    assert "- what the profile sets (its PROFILES entry; the rest is the config as written): `DATA_CONFIG.MIX.TOTAL " \
           "1200`; `DATA_CONFIG.POINT_CLOUD_RANGE [2.56, -23.2, 0.1, 40.96, 23.2, 2.5]`;" in text


# ------------------------------------------------------------------------------------------- bootstrap intervals
def with_intervals(results: dict, differences: dict, level=0.95) -> dict:
    """`results` with hand-set paired intervals {(a, b): [low, high]} of AP3D_R40 (b - a: the negated interval)."""
    for name, model in results["models"].items():
        model["difference_interval"] = {other: {} for other in results["models"] if other != name}
    for (a, b), (low, high) in differences.items():
        results["models"][a]["difference_interval"][b]["AP3D_R40"] = [low, high]
        results["models"][b]["difference_interval"][a]["AP3D_R40"] = [-high, -low]
    results["intervals"] = {"level": level, "resamples": 1000, "seed": 0, "frames": 230, "seconds": 1.0}
    return results


def test_order_statement_orders_only_where_the_paired_interval_excludes_zero():
    ap = {"M1": 0.1, "M2": 0.2, "M3": 0.4, "M4": 0.3, "oracle": 0.5}
    apart = {("M3", "M4"): [0.05, 0.15], ("M4", "M2"): [0.02, 0.2], ("M2", "M1"): [0.01, 0.2],
             ("oracle", "M3"): [0.01, 0.2], ("oracle", "M4"): [0.1, 0.3], ("oracle", "M2"): [0.2, 0.4],
             ("oracle", "M1"): [0.3, 0.5]}
    held = order_statement(with_intervals(make_results(ap), apart))
    assert held == ("The paper's order M3 > M4 > M2 > M1 holds here: this run gives M3 (0.400) > M4 (0.300) > M2 "
                    "(0.200) > M1 (0.100). Pair by pair, the difference with its paired 95 % bootstrap interval over "
                    "the 230 test frames (≈: the interval includes 0): M3 - M4 +0.100 [+0.050, +0.150], M3 > M4 as "
                    "in the paper; M4 - M2 +0.100 [+0.020, +0.200], M4 > M2 as in the paper; M2 - M1 +0.100 [+0.010, "
                    "+0.200], M2 > M1 as in the paper. The oracle (in-domain training) reaches 0.500, above every "
                    "mix; the best mix, M3, reaches 80 % of it.")
    close = apart | {("M3", "M4"): [-0.01, 0.2], ("oracle", "M3"): [-0.05, 0.2]}
    unsure = order_statement(with_intervals(make_results(ap), close))
    assert unsure.startswith("The paper's order M3 > M4 > M2 > M1 cannot be confirmed here: this run gives M3 (0.400) "
                             "≈ M4 (0.300) > M2 (0.200) > M1 (0.100).")
    assert "M3 - M4 +0.100 [-0.010, +0.200], the intervals cannot order M3 and M4;" in unsure
    assert unsure.endswith("reaches 0.500, above M4, M2, M1; not ordered by the intervals against M3; the best mix, "
                           "M3, reaches 80 % of it.")
    reversed_pair = apart | {("M2", "M1"): [-0.2, -0.01]}  # the means say M2 > M1, the paired interval says below
    against = order_statement(with_intervals(make_results(ap), reversed_pair))
    assert against.startswith("The paper's order M3 > M4 > M2 > M1 does not hold here: this run gives M3 (0.400) > "
                              "M4 (0.300) > M2 (0.200) < M1 (0.100).")
    assert "M2 - M1 +0.100 [-0.200, -0.010], M2 < M1, against the paper." in against


def write_labels(folder: Path, frames: list[list], scores: list[list] | None = None):
    """One KITTI label file per frame of person boxes at (x, y) centres (with scores: predictions)."""
    for index, centres in enumerate(frames):
        boxes = np.array([[x, y, 0.9, 0.6, 0.5, 1.8, 0.0] for x, y in centres]).reshape(-1, 7)
        write_label(folder / f"{index:06d}.txt", label_from_boxes(["Pedestrian"] * len(boxes), boxes,
                                                                   Calibration.virtual(),
                                                                   None if scores is None else np.array(scores[index])))


@pytest.mark.slow
def test_add_intervals_from_prediction_folders_and_table3(tmp_path):
    # two frames of one person each: 'half' finds frame 0 and has a false positive in frame 1 (AP 1, 1/2 or 0 as
    # frame 0 is drawn twice, once or never), 'mirror' the other way round, 'perfect' finds both
    gt = [[(5, 0)], [(8, 2)]]
    half, mirror = ([[(5, 0)], [(15, -5)]], [[0.9], [0.8]]), ([[(15, -5)], [(8, 2)]], [[0.8], [0.9]])
    perfect = (gt, [[0.9], [0.9]])
    predictions = {("M1", 0): half, ("M2", 0): mirror, ("M2", 1): half, ("M3", 0): perfect, ("M4", 0): half,
                   ("oracle", 0): perfect}
    results = make_results({"M1": 0.5, "M2": 0.5, "M3": 1.0, "M4": 0.5, "oracle": 1.0})
    results["models"]["M2"]["runs"] = [dict(results["models"]["M2"]["runs"][0], seed=seed,
                                            predictions=f"models/M2/seed_{seed}/pred") for seed in (0, 1)]
    write_labels(tmp_path / "gt", gt)
    for (name, seed), (centres, scores) in predictions.items():
        write_labels(tmp_path / "models" / name / f"seed_{seed}" / "pred", centres, scores)
    add_intervals(results, tmp_path / "gt", tmp_path, resamples=200)
    assert results["figures"]["ap_intervals"] == "ap_intervals.png"
    assert (tmp_path / "ap_intervals.png").stat().st_size > 10_000
    models = results["models"]
    assert {key: value for key, value in results["intervals"].items() if key != "seconds"} == {
        "level": 0.95, "resamples": 200, "seed": 0, "frames": 2}
    assert set(models["M3"]["interval"]) == {"AP3D_R40", "AP3D_R11", "APBEV_R40", "APBEV_R11"}
    assert models["M3"]["interval"]["AP3D_R40"] == [1.0, 1.0] == models["oracle"]["interval"]["APBEV_R11"]
    assert models["M1"]["interval"]["AP3D_R40"] == [0.0, 1.0]
    # the seed mean of the mirror images is 1/2 on any frames, but a resample may draw one seed twice: 0 to 1
    assert models["M2"]["interval"]["AP3D_R40"] == [0.0, 1.0]
    assert models["M4"]["difference_interval"]["M1"]["AP3D_R40"] == [0.0, 0.0]  # the same predictions
    assert models["M3"]["difference_interval"]["oracle"]["APBEV_R40"] == [0.0, 0.0]
    assert models["M1"]["difference_interval"]["M3"]["AP3D_R40"] == [-1.0, 0.0]
    assert set(models["M1"]["difference_interval"]) == {"M2", "M3", "M4", "oracle"}
    rows = table3(results)
    assert rows[0].startswith("| Model | Architecture | AP 3D R40 | paper AP | gain over M1 (pp) | paper gain (pp) | "
                              "vs oracle (pp) | AP 3D R11 |")
    assert rows[4] == ("| M3 | SECOND | 1.000 [1.000, 1.000] | 0.54 | +50.0 [+0.0, +100.0] | +44.0 | +0.0 [+0.0, +0.0] "
                       "| 1.010 [1.000, 1.000] | 1.020 [1.000, 1.000] | 1.030 [1.000, 1.000] | n/a | 120.0 |")
    assert rows[2].startswith("| M1 | SECOND | 0.500 [0.000, 1.000] | 0.10 | +0.0 | +0.0 | -50.0 [-100.0, +0.0] |")

    # tools/research/report_intervals.py does the same for a written report, into another folder
    write_report(make_results({"M1": 0.5, "M2": 0.5, "M3": 1.0, "M4": 0.5, "oracle": 1.0}) | {
        "models": {name: {key: value for key, value in model.items() if "interval" not in key}
                   for name, model in models.items()}}, tmp_path)
    spec = importlib.util.spec_from_file_location("report_intervals", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    out = tmp_path / "again"
    assert tool.main([str(tmp_path), "--out", str(out), "--gt", str(tmp_path / "gt"), "--resamples", "200"]) == 0
    again = json.loads((out / "results.json").read_text())
    assert {name: model["interval"] for name, model in again["models"].items()} == {
        name: model["interval"] for name, model in models.items()}
    text = (out / "report.md").read_text()
    assert "Brackets: 95 % bootstrap percentile interval over the 2 test frames (200 resamples" in text
    assert rows[4] in text


def test_orientation_error_per_distance_bin_from_labels_to_the_report(tmp_path):
    # one person per frame at 5, 15 and 25 m; the predictions turned by 0, 30 and 90 deg
    for folder, turns in (("gt", (0.0, 0.0, 0.0)), ("pred", (0.0, 30.0, 90.0))):
        for index, (x, turn) in enumerate(zip((5.0, 15.0, 25.0), turns)):
            box = np.array([[x, 0.0, 0.9, 0.8, 0.5, 1.8, np.radians(turn)]])
            write_label(tmp_path / folder / f"{index:06d}.txt", label_from_boxes(
                ["Pedestrian"], box, Calibration.virtual(), None if folder == "gt" else np.array([0.9])))
    metrics = score_run(tmp_path / "gt", tmp_path / "pred")["metrics"]
    by_distance = {key: metrics[key] for key in metrics if key.startswith("orientation_error_deg")}
    assert by_distance == pytest.approx({"orientation_error_deg": 30.0, "orientation_error_deg_0-10m": 0.0,
                                         "orientation_error_deg_10-20m": 30.0, "orientation_error_deg_20+m": 90.0},
                                        abs=0.5)  # KITTI labels keep rotation_y to 0.01 rad

    results = make_results({"M1": 0.1, "M3": 0.5}, seeds=(0, 1))
    for name, (near, middle) in {"M1": (12.0, 20.5), "M3": (8.25, None)}.items():
        model = results["models"][name]
        model["mean"] |= {"orientation_error_deg_0-10m": near, "orientation_error_deg_10-20m": middle}
        model["std"] |= {"orientation_error_deg_0-10m": 1.5, "orientation_error_deg_10-20m": None if middle is None
                         else 0.0}
    assert orientation_bin_table(results) == ["| Model | 0-10m | 10-20m |", "|---|---|---|",
                                              "| M1 | 12.0 ± 1.5 | 20.5 ± 0.0 |", "| M3 | 8.2 ± 1.5 | n/a |"]
    assert "### Orientation error per distance bin" in render_report(results)
    assert orientation_bin_table(make_results({"M1": 0.1})) == []  # results scored before the bins: no table
    assert "### Orientation error" not in render_report(make_results({"M1": 0.1}))


def test_a_second_head_is_compared_with_its_own_m1_and_oracle():
    models = {name: {"detector": detector, "model": name.split("-")[0],
                     "mean": {"AP3D_R40": ap, "orientation_error_deg": 12.5}, "std": {}}
              for name, detector, ap in (("M1", "SECONDNet", 0.4), ("oracle", "SECONDNet", 0.6),
                                         ("M1-center", "CenterPoint", 0.5), ("M3-center", "CenterPoint", 0.55),
                                         ("oracle-center", "CenterPoint", 0.7))}
    assert counterpart(models, "M3-center", "M1") == "M1-center"
    assert counterpart(models, "M3-center", "oracle") == "oracle-center"
    assert counterpart(models, "oracle", "M1") == "M1"
    rows = table3({"models": models, "seeds": [0]})
    assert rows[5].startswith("| M3-center (not in the paper) | CenterPoint | 0.550 | - | +5.0 | n/a | -15.0 | ")
    assert rows[5].endswith("| 12.5 | n/a |")
