"""Which torch ops of a training step give other bits on one thread than on torch's threads.

    python tools/thread_census.py --cfg cfgs/m3.yaml --profile quick

Runs one training step (forward and backward, batch of 2 frames, random weights, seed 0) and repeats every torch op
of it on one thread, on copies of the same inputs, comparing the two results bit for bit. An op listed here is why a
training step cannot take fewer threads when other processes need the cores without changing its results
(docs/benchmarks.md#speed-under-load). The sparse convolutions are numba and torch matrix products on their own thread
count (models.rulebook) and are not listed. Which ops differ depends on their shapes and data, so two steps may
list different ones.
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten, tree_map

# ops whose results are not numbers to compare, or that allocate or draw random numbers
SKIP = ("empty", "detach", "view", "alias", "as_strided", "resize", "set_", "_local_scalar", "random", "normal",
        "uniform", "bernoulli")


def _copy(value):
    return value.clone() if isinstance(value, torch.Tensor) else value


def _same(a, b) -> bool:
    """Equal to the bit, NaN equal to NaN."""
    if not isinstance(a, torch.Tensor):
        return True
    return torch.equal(a, b) or (a.is_floating_point() and torch.equal(a.nan_to_num(), b.nan_to_num()))


class ThreadCensus(TorchDispatchMode):
    """Runs each op as asked, and again on one thread: `differ` and `same` count (op, input shapes)."""

    def __init__(self):
        super().__init__()
        self.differ, self.same = Counter(), Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if any(part in str(func) for part in SKIP):
            return func(*args, **kwargs)
        threads = torch.get_num_threads()
        results = []
        for count in (threads, 1):
            copies = tree_map(_copy, (args, kwargs))  # in-place ops change their inputs: compare those too
            torch.set_num_threads(count)
            try:
                results.append(tree_flatten((func(*copies[0], **copies[1]), copies))[0])
            finally:
                torch.set_num_threads(threads)
        shapes = tuple(tuple(value.shape) for value in tree_flatten(args)[0] if isinstance(value, torch.Tensor))
        counter = self.same if all(_same(a, b) for a, b in zip(*results)) else self.differ
        counter[(str(func), shapes[:3])] += 1
        return func(*args, **kwargs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cfg", default="cfgs/m3.yaml")
    parser.add_argument("--profile", default="quick")
    parser.add_argument("--threads", type=int, default=2, help="torch threads to compare with one (default 2)")
    args = parser.parse_args(argv)
    from benchmark_model import frames_for
    from pcdet_memslidar.config import load_config
    from pcdet_memslidar.models import build_network, load_data_to_device
    from pcdet_memslidar.runtime.common import set_random_seed

    torch.set_num_threads(args.threads)
    cfg = load_config(args.cfg, profile=args.profile)
    dataset, source = frames_for(cfg, training=True, count=2)
    set_random_seed(0)
    model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), dataset).train()
    batch = load_data_to_device(dataset.collate_batch([dataset[0], dataset[1]]), torch.device("cpu"))
    census = ThreadCensus()
    with census:
        ret_dict, _, _ = model(batch)
        ret_dict["loss"].mean().backward()
    print(f"{args.cfg} profile {args.profile} ({source} frames), {args.threads} threads against 1: "
          f"{sum(census.differ.values())} of {sum(census.differ.values()) + sum(census.same.values())} op calls differ")
    print("\n| calls | op | input shapes |\n|---|---|---|")
    for (op, shapes), calls in census.differ.most_common():
        print(f"| {calls} | `{op}` | {', '.join(str(list(shape)) for shape in shapes)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
