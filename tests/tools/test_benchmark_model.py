"""tools/benchmark_model.py: both heads timed side by side, a training step split into its phases."""
import importlib.util
import json
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TOOL = REPO / "tools" / "benchmark_model.py"


def test_both_heads_with_the_phases_of_a_training_step(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no data folder here: synthetic frames over each config's range
    spec = importlib.util.spec_from_file_location("benchmark_model", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    out = tmp_path / "bench.json"
    assert tool.main(["--cfg", str(REPO / "cfgs/m3.yaml"), str(REPO / "cfgs/centerpoint/m3.yaml"), "--profiles",
                      "smoke", "--frames", "2", "--warmup", "1", "--threads", "1", "--output", str(out),
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
    assert "training step ms per phase" in capsys.readouterr().out
