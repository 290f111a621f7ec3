"""tools/thread_census.py: an op whose bits depend on the thread count is counted as differing and an elementwise op
is not, each op's result is kept; a training step on one thread against one differs nowhere."""
import importlib.util
import re
import sys
from collections import Counter
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]


@torch.library.custom_op("thread_census_test::threads_in_use", mutates_args=())
def threads_in_use(x: torch.Tensor) -> torch.Tensor:
    """An op whose result is the thread count it runs on: different bits on one thread than on two."""
    return torch.full_like(x, float(torch.get_num_threads()))


def load_tool(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "tools"))  # the tool imports benchmark_model
    monkeypatch.delitem(sys.modules, "benchmark_model", raising=False)
    spec = importlib.util.spec_from_file_location("thread_census", REPO / "tools" / "thread_census.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_an_op_that_depends_on_the_threads_differs_an_elementwise_op_does_not_and_each_result_is_kept(monkeypatch):
    tool = load_tool(monkeypatch)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        census = tool.ThreadCensus()
        values = torch.arange(100_000, dtype=torch.float32)  # above torch's grain: split between threads
        counted = torch.zeros(4)
        with census:
            product = values.mul(3.0)
            values.add_(1.0)  # in place: applied once, not once per thread count
            used = threads_in_use(counted)
    finally:
        torch.set_num_threads(threads)
    assert census.differ == Counter({("thread_census_test.threads_in_use.default", ((4,),)): 1})
    assert census.same == Counter({("aten.mul.Tensor", ((100_000,),)): 1, ("aten.add_.Tensor", ((100_000,),)): 1})
    assert product[7].item() == 21.0 and values[7].item() == 8.0
    assert used.tolist() == [2.0] * 4  # the result of the caller's two threads, not of the one-thread repeat


@pytest.mark.slow
def test_a_training_step_on_one_thread_against_one_differs_nowhere(monkeypatch, capsys):
    """The same thread count gives the same bits (random ops are skipped): 0 differ and no table rows."""
    tool = load_tool(monkeypatch)
    threads = torch.get_num_threads()
    try:
        assert tool.main(["--cfg", str(REPO / "cfgs/m3.yaml"), "--profile", "smoke", "--threads", "1"]) == 0
    finally:
        torch.set_num_threads(threads)
    lines = capsys.readouterr().out.splitlines()
    header = re.search(r"1 threads against 1: (\d+) of (\d+) op calls differ", lines[0])
    differ, total = int(header.group(1)), int(header.group(2))
    assert differ == 0 and total > 1000
    assert lines[1:] == ["", "| calls | op | input shapes |", "|---|---|---|"]
