"""The optimizers' update gives the same bits on one and two threads: what lets a training step's update take only
the free cores (runtime.train_loop.train_one_step) without changing its results."""
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar.runtime.optimization import build_optimizer


@pytest.mark.parametrize("name", ["adam_onecycle", "adam", "sgd"])
def test_the_update_gives_the_same_bits_on_one_and_two_threads(name):
    generator = torch.Generator().manual_seed(0)
    # a sparse conv's weight (27 offsets x 64 x 64: above torch's grain, so split between threads) and a BatchNorm's
    start = [torch.randn(27, 64, 64, generator=generator), torch.randn(64, generator=generator)]
    grads = [[torch.randn(p.shape, generator=generator) for p in start] for _ in range(3)]
    cfg = EasyDict(OPTIMIZER=name, LR=0.003, WEIGHT_DECAY=0.01, MOMENTUM=0.9)
    results = []
    threads = torch.get_num_threads()
    try:
        for count in (1, 2):
            torch.set_num_threads(count)
            model = torch.nn.Module()
            model.weight, model.norm = torch.nn.Parameter(start[0].clone()), torch.nn.BatchNorm1d(64)
            model.norm.weight = torch.nn.Parameter(start[1].clone())
            optimizer = build_optimizer(model, cfg)
            for step in grads:
                model.weight.grad, model.norm.weight.grad = (grad.clone() for grad in step)
                optimizer.step()
            results.append([model.weight.detach().clone(), model.norm.weight.detach().clone()])
    finally:
        torch.set_num_threads(threads)
    assert not torch.equal(results[0][0], start[0])
    assert all(torch.equal(one, two) for one, two in zip(*results))
