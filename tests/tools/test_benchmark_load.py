"""tools/benchmark_load.py: one measurement (what each setting's fresh process runs) gives numbers."""
import argparse
import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_a_measurement_gives_inference_and_training_step_milliseconds(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "tools"))  # the tool imports benchmark_model as its child process does
    spec = importlib.util.spec_from_file_location("benchmark_load", REPO / "tools" / "benchmark_load.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    monkeypatch.delitem(sys.modules, "benchmark_model", raising=False)
    monkeypatch.setenv("MEMSLIDAR_SLICE_US", "0")  # this test process keeps the kernel's time slice
    args = argparse.Namespace(cfg=str(REPO / "cfgs/m3.yaml"), profile="smoke", threads=1, frames=2, warmup=1,
                              steps=1, give_way=True)
    result = tool.measure(args)
    assert set(result) == {"infer_ms", "train_step_ms", "threads"}
    assert all(isinstance(value, float) and value > 0 for value in result.values()), result
    assert result["threads"] == 1.0
