"""`memslidar sweep`: the points of each sweep (exact frame counts and epochs), the real frames that synthetic frames
replace (exact values), and a smoke sweep that writes its table and figure and resumes after an interruption."""
import json

import pytest

from pcdet_memslidar.cli import main as memslidar
from pcdet_memslidar.datasets.mixing import resolve_sources
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.experiments import runs as runs_module
from pcdet_memslidar.experiments.reproduce import model_config
from pcdet_memslidar.experiments.sweeps import (
    annotations_replaced,
    point_config,
    ratio_points,
    real_budget_points,
    sweep,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_ratio_points_keep_the_total_and_round_as_table2(tmp_path):
    base = model_config("M3", "quick", tmp_path)  # MIX.TOTAL 1200, 2 epochs
    points = ratio_points(base)
    assert [point.name for point in points] == [f"sim_{share:03d}" for share in range(0, 101, 10)]
    assert [point.counts["sim"] for point in points] == list(range(0, 1201, 120))
    assert all(point.counts["sim"] + point.counts["real"] == 1200 and point.epochs == 2 for point in points)
    base.DATA_CONFIG.MIX.TOTAL = 25  # 2.5 / 22.5: largest remainder, ties to the first source
    assert [(point.counts["sim"], point.counts["real"]) for point in ratio_points(base, (10, 30, 50))] == \
        [(3, 22), (8, 17), (13, 12)]


def test_real_budget_points_train_the_recipes_steps(tmp_path):
    points = real_budget_points(model_config("M3", "quick", tmp_path))  # 1200 frames x 2 epochs
    assert [(point.counts["real"], point.counts["sim"], point.epochs) for point in points] == [
        (120, 0, 20), (300, 0, 8), (600, 0, 4), (1200, 0, 2),
        (120, 600, 3), (300, 600, 3), (600, 600, 2), (1200, 600, 1)]
    assert {point.group for point in points} == {"real only", "real + 600 sim"}
    with pytest.raises(ConfigError, match="0 % of the real pool"):
        real_budget_points(model_config("M3", "quick", tmp_path), (0, 50))


def test_a_point_config_reads_exactly_its_counts(tmp_path):
    base = model_config("M3", "quick", tmp_path)
    point = real_budget_points(base)[4]  # 120 real + 600 sim, 3 epochs
    cfg = point_config(base, point)
    sources = {source.name: source.count for source in resolve_sources(cfg.DATA_CONFIG.MIX, tmp_path)}
    assert sources == {"sim": 600, "real": 120} and cfg.OPTIMIZATION.NUM_EPOCHS == 3
    assert base.OPTIMIZATION.NUM_EPOCHS == 2 and base.DATA_CONFIG.MIX.SOURCES[0].RATIO == 0.5  # base untouched


def test_annotations_replaced_reads_the_real_only_curve():
    real_only = [(40, 0.20), (100, 0.40), (200, 0.50), (400, 0.60)]
    rows = annotations_replaced(real_only, [(40, 0.30), (100, 0.55), (200, 0.70), (400, 0.10)])
    assert [row["equivalent_real"] for row in rows] == [pytest.approx(70.0), pytest.approx(300.0), None, 40]
    assert rows[0]["saved_fraction"] == pytest.approx(1 - 40 / 70)  # 43 % fewer real annotations
    assert rows[1]["saved_fraction"] == pytest.approx(1 - 100 / 300)
    assert rows[2]["saved_fraction"] is None  # above the whole pool's AP
    assert rows[3]["saved_fraction"] == pytest.approx(1 - 400 / 40)  # -9: synthetic frames cost AP
    # a curve that falls and rises again: the first n that reaches the AP
    rows = annotations_replaced([(10, 0.2), (20, 0.5), (30, 0.4), (40, 0.6)], [(10, 0.45), (10, 0.55)])
    assert [row["equivalent_real"] for row in rows] == [pytest.approx(10 + 0.25 / 0.3 * 10), pytest.approx(37.5)]


def test_a_bad_grid_names_the_fix(tmp_path):
    with pytest.raises(ConfigError, match=r"--grid \[0, 120\]: give distinct percentages from 0 to 100"):
        sweep("ratio", "smoke", 1, tmp_path / "out", tmp_path / "data", grid=[0, 120])
    with pytest.raises(ConfigError, match="unknown sweep 'ratios'; known sweeps: ratio, real-budget"):
        sweep("ratios", "smoke", 1, tmp_path / "out", tmp_path / "data")


def test_smoke_sweep_writes_its_table_and_figure_and_resumes(tmp_path, monkeypatch):
    out, data = tmp_path / "sweep", tmp_path / "data"
    real_predict, calls = runs_module.predict, []

    def interrupted_predict(*args, **kwargs):  # the second point is killed after its training
        calls.append(args[1])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_predict(*args, **kwargs)

    monkeypatch.setattr(runs_module, "predict", interrupted_predict)
    with pytest.raises(KeyboardInterrupt):
        sweep("ratio", "smoke", 1, out, data, jobs=1, grid=[0, 100])
    first = out / "points" / "sim_000" / "seed_0"
    second = out / "points" / "sim_100" / "seed_0"
    assert (first / "run.json").is_file() and not (second / "run.json").is_file()
    stamps = {path: path.stat().st_mtime_ns for path in (first / "run.json", *second.glob("ckpt/*.pth"))}
    assert len(stamps) == 2  # the first point's result and the second point's checkpoint

    monkeypatch.setattr(runs_module, "predict", real_predict)
    assert memslidar(["sweep", "ratio", "--grid", "0", "100", "--profile", "smoke", "--out", str(out),
                      "--data-root", str(data), "--jobs", "1"]) == 0
    assert all(path.stat().st_mtime_ns == stamp for path, stamp in stamps.items())  # nothing trained again
    results = json.loads((out / "results.json").read_text())
    assert [(row["point"], row["counts"]) for row in results["rows"]] == [
        ("sim_000", {"sim": 0, "real": 20}), ("sim_100", {"sim": 20, "real": 0})]
    for row in results["rows"]:
        run = json.loads((out / "points" / row["point"] / "seed_0" / "run.json").read_text())
        assert row["per_seed"] == [run["metrics"]["AP3D_R40"]] and row["mean"] == run["metrics"]["AP3D_R40"]
    text = (out / "report.md").read_text()
    assert "| sim_000 | sim + real | 0 | 20 | 1 |" in text and "| sim_100 | sim + real | 20 | 0 | 1 |" in text
    assert "](ratio.png)" in text and (out / "ratio.png").read_bytes()[:8] == PNG_MAGIC
    assert "memslidar sweep ratio --grid 0 100 --profile smoke --seeds 1" in text


@pytest.mark.slow
def test_a_sweep_point_is_validated_after_its_last_epoch_only(tmp_path):
    out = tmp_path / "sweep"
    sweep("ratio", "smoke", 1, out, tmp_path / "data", jobs=1, grid=[0], set_cfgs=["OPTIMIZATION.NUM_EPOCHS", "2"])
    curve = json.loads((out / "points" / "sim_000" / "seed_0" / "curve.json").read_text())
    assert [entry["epoch"] for entry in curve] == [1, 2]
    assert curve[0]["val_AP3D_R40"] is None and isinstance(curve[1]["val_AP3D_R40"], float)
