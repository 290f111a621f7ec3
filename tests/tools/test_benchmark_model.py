"""tools/benchmark_model.py: both heads timed side by side, a training step split into its phases, epochs of the
training loop."""
import importlib.util
import json
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TOOL = REPO / "tools" / "benchmark_model.py"


@pytest.mark.slow
def test_both_heads_with_the_phases_of_a_training_step(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no data folder here: synthetic frames over each config's range
    spec = importlib.util.spec_from_file_location("benchmark_model", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    out = tmp_path / "bench.json"
    assert tool.main(["--cfg", str(REPO / "cfgs/m3.yaml"), str(REPO / "cfgs/centerpoint/m3.yaml"), "--profiles",
                      "smoke", "--frames", "2", "--warmup", "1", "--threads", "1", "--op_kinds", "--output", str(out),
                      "--set", "DATA_CONFIG.DATA_PATH", str(tmp_path / "none")]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(row["config"], row["head"], row["head_stride"]) for row in rows] == [
        ("m3/smoke", "AnchorHeadSingle", 4), ("centerpoint/m3/smoke", "CenterHead", 4)]
    for row in rows:
        phases = row["train_ms_per_phase"]
        assert list(phases) == ["data", "to device", "forward", "backward", "optimizer"]
        assert all(ms > 0 for ms in phases.values()) and row["infer_ms"] > 0
        # the step is the four phases after the data: their sum, to the medians' spread
        assert 0.5 * row["train_step_ms"] < sum(phases.values()) - phases["data"] < 2 * row["train_step_ms"]
        kinds = row["train_ms_per_op_kind"]
        assert list(kinds) == [*tool.OP_KINDS, "other ops"]
        assert all(kinds[kind] > 0 for kind in ("sparse convs: gather and scatter", "matrix products (BLAS)",
                                                "dense convs (oneDNN, ATen)", "batch norm"))
    printed = capsys.readouterr().out
    assert "training step ms per phase" in printed and "training step ms per kind of work" in printed


@pytest.mark.slow
def test_epochs_of_the_training_loop_in_fp32_and_mixed_precision_leave_no_checkpoint(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # the tool's checkpoint folder goes here
    spec = importlib.util.spec_from_file_location("benchmark_model", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    out = tmp_path / "bench.json"
    assert tool.main(["--cfg", str(REPO / "cfgs/m3.yaml"), "--profiles", "smoke", "--frames", "2", "--warmup", "1",
                      "--threads", "1", "--epochs", "2", "--epoch_frames", "5", "--output", str(out),
                      "--set", "DATA_CONFIG.DATA_PATH", str(tmp_path / "none")]) == 0
    epochs = json.loads(out.read_text())["epochs"]
    assert [(row["config"], row["mode"], row["frames"]) for row in epochs] == [
        ("m3/smoke", "fp32", "synthetic"), ("m3/smoke", "amp", "synthetic")]
    for row in epochs:
        assert row["steps_per_epoch"] == 2  # 5 frames in batches of the smoke profile's 2, the last one dropped
        assert len(row["epoch_s"]) == 2 and all(s > 0 for s in row["epoch_s"])
    assert list(scratch.iterdir()) == []  # the checkpoints' temporary folder is gone
    assert "training epochs" in capsys.readouterr().out
