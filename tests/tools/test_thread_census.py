"""tools/thread_census.py: an elementwise op is never counted as differing, and one training step is censused."""
import importlib.util
import re
import sys
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[2]


def load_tool(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "tools"))  # the tool imports benchmark_model
    monkeypatch.delitem(sys.modules, "benchmark_model", raising=False)
    spec = importlib.util.spec_from_file_location("thread_census", REPO / "tools" / "thread_census.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_an_elementwise_op_gives_the_same_bits_and_the_ops_result_is_kept(monkeypatch):
    tool = load_tool(monkeypatch)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        census = tool.ThreadCensus()
        values = torch.arange(100_000, dtype=torch.float32)  # above torch's grain: split between threads
        with census:
            product = values.mul(3.0)
            values.add_(1.0)  # in place: applied once, not once per thread count
    finally:
        torch.set_num_threads(threads)
    assert not census.differ and sum(census.same.values()) == 2
    assert product[7].item() == 21.0 and values[7].item() == 8.0


def test_a_training_step_is_censused(monkeypatch, capsys):
    tool = load_tool(monkeypatch)
    threads = torch.get_num_threads()
    try:
        assert tool.main(["--cfg", str(REPO / "cfgs/m3.yaml"), "--profile", "smoke", "--threads", "2"]) == 0
    finally:
        torch.set_num_threads(threads)
    first = capsys.readouterr().out.splitlines()[0]
    differ, total = (int(n) for n in re.search(r"(\d+) of (\d+) op calls differ", first).groups())
    assert total > 1000 and 0 <= differ < total
