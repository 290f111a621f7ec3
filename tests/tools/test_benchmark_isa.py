"""tools/benchmark_isa.py: its AVX2 setting really holds PyTorch to AVX2 code in the benchmark's process."""
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def load_tool():
    spec = importlib.util.spec_from_file_location("benchmark_isa", REPO / "tools" / "benchmark_isa.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


@pytest.mark.slow
def test_the_avx2_setting_holds_torch_to_avx2_whatever_the_cpu():
    env = {**os.environ, **load_tool().SETTINGS["avx2"]}
    capability = subprocess.run([sys.executable, "-c", "import torch; print(torch.backends.cpu.get_cpu_capability())"],
                                env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert capability == "AVX2"


def test_stage_times_put_inference_modules_and_training_phases_side_by_side():
    row = {"infer_ms": 10.0, "infer_ms_per_module": {"vfe": 1.0, "backbone_3d": 9.0}, "train_step_ms": 30.0,
           "train_ms_per_phase": {"forward": 12.0, "backward": 18.0}}
    assert load_tool().stage_times(row) == {"infer: vfe": 1.0, "infer: backbone_3d": 9.0, "infer: total": 10.0,
                                            "train: forward": 12.0, "train: backward": 18.0, "train: step": 30.0}


def test_stage_times_add_the_kinds_of_work_where_the_row_has_them():
    row = {"infer_ms": 10.0, "infer_ms_per_module": {}, "train_step_ms": 30.0, "train_ms_per_phase": {},
           "train_ms_per_op_kind": {"batch norm": 2.5, "other ops": 7.0}}
    assert load_tool().stage_times(row) == {"infer: total": 10.0, "train: step": 30.0, "train ops: batch norm": 2.5,
                                            "train ops: other ops": 7.0}
