"""Report writer on hand-made results (no training): exact numbers, complete tables."""
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.config import load_config, profile_settings
from pcdet_memslidar.experiments.report import (
    gain_over_reference,
    order_statement,
    render_report,
    summarise_runs,
    table2,
    write_report,
)

CFGS = Path(__file__).resolve().parents[2] / "cfgs"


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
    assert "| M3 | SECOND | 0.540 | 0.54 | +44.0 | +44.0 | 0.550 | 0.560 | 0.570 | 120.0 |" in text
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
                    "= M2 (0.000) = M1 (0.000). The oracle (in-domain training) reaches 0.000, not above every mix.")
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
