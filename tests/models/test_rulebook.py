"""models.rulebook on hand-made cells with exact expected values: a submanifold conv at a corner of the grid and
across frames, its gradients, a stride-2 conv reaching 8 output cells, conv_out's (3, 1, 1) kernel, BatchNorm
folding, and the layers it refuses; the backward against finite differences in float64; the same bits on one and two
threads for the convs and the training BatchNorm."""
import numpy as np
import pytest
import spconv.pytorch as spconv
import torch
from torch import nn

from pcdet_memslidar.models import rulebook


def _conv(conv: spconv.conv.SparseConvolution) -> spconv.conv.SparseConvolution:
    """One input and one output channel; the weight of kernel offset k (z-major) is k + 1."""
    with torch.no_grad():
        conv.weight.copy_(torch.arange(1.0, conv.weight.numel() + 1).view_as(conv.weight))
    return conv.eval()


def _run(module, coords, values, shape, batch_size=1) -> dict[tuple, float]:
    """{(b, z, y, x): output} of module on one-channel features."""
    tensor = spconv.SparseConvTensor(torch.tensor(values, dtype=torch.float32).view(-1, 1),
                                     torch.tensor(coords, dtype=torch.int32), shape, batch_size)
    with torch.no_grad():
        out = rulebook.run(module, tensor, {})
    return {tuple(cell): value for cell, value in zip(out.indices.tolist(), out.features[:, 0].tolist())}


def test_submanifold_conv_at_a_corner_keeps_frames_apart():
    """Cells (0, 0, 0) = 1 and (0, 0, 1) = 10 of frame 0, (0, 0, 1) = 100 of frame 1. Offset (dz, dy, dx) has
    k = 9 (dz + 1) + 3 (dy + 1) + dx + 1, weight k + 1: the centre 14, dx = +1 15, dx = -1 13. Neighbours outside the
    grid and in the other frame add nothing."""
    conv = _conv(spconv.SubMConv3d(1, 1, 3, bias=False, indice_key="subm"))
    out = _run(conv, [[0, 0, 0, 0], [0, 0, 0, 1], [1, 0, 0, 1]], [1.0, 10.0, 100.0], [2, 2, 2], batch_size=2)
    assert out == {(0, 0, 0, 0): 14 * 1 + 15 * 10, (0, 0, 0, 1): 14 * 10 + 13 * 1, (1, 0, 0, 1): 14 * 100}


def test_gradients_of_the_submanifold_conv_at_a_corner():
    """The cells of the test above, loss = sum of the outputs. Cell (0, 0, 0) of frame 0 reaches its own output by
    the centre (14) and output (0, 0, 1) by dx = -1 (13): gradient 27; cell (0, 0, 1) reaches its own by the centre
    and (0, 0, 0) by dx = +1 (15): 29; frame 1's cell only its own: 14. The weight of offset k gets the sum of the
    inputs it carried: centre 1 + 10 + 100, dx = -1 1, dx = +1 10, every other offset 0."""
    conv = _conv(spconv.SubMConv3d(1, 1, 3, bias=False, indice_key="subm")).train()
    features = torch.tensor([[1.0], [10.0], [100.0]], requires_grad=True)
    tensor = spconv.SparseConvTensor(features, torch.tensor([[0, 0, 0, 0], [0, 0, 0, 1], [1, 0, 0, 1]],
                                                            dtype=torch.int32), [2, 2, 2], 2)
    rulebook.run(conv, tensor, {}).features.sum().backward()
    assert features.grad[:, 0].tolist() == [27.0, 29.0, 14.0]
    expected = torch.zeros(27)
    expected[13], expected[12], expected[14] = 111.0, 1.0, 10.0
    assert torch.equal(conv.weight.grad.flatten(), expected)


@pytest.mark.parametrize("conv", [spconv.SubMConv3d(3, 4, 3, bias=False, indice_key="subm"),
                                  spconv.SparseConv3d(3, 4, 3, stride=2, padding=1, bias=False),
                                  spconv.SparseConv3d(3, 4, (3, 1, 1), stride=(2, 1, 1), bias=False)],
                         ids=["subm", "stride 2", "conv_out"])
@pytest.mark.slow
def test_backward_equals_finite_differences_in_float64(conv):
    generator = torch.Generator().manual_seed(0)
    shape = [7, 9, 8]
    cells = torch.unique(torch.stack([torch.randint(0, s, (80,), generator=generator) for s in shape], 1), dim=0)
    coords = torch.cat([torch.randint(0, 2, (len(cells), 1), generator=generator), cells], 1)
    coords = torch.unique(coords, dim=0).numpy()
    rules = rulebook.Rulebook(coords, shape, conv)
    features = torch.randn(len(coords), 3, dtype=torch.float64, generator=generator, requires_grad=True)
    weight = torch.randn(rulebook.kernel_weight(conv).shape, dtype=torch.float64, generator=generator,
                         requires_grad=True)
    assert len(rules.pairs) > 1
    assert torch.autograd.gradcheck(lambda f, w: rulebook.SparseConvFunction.apply(f, w, rules, 2),
                                    (features, weight))


def test_forward_and_backward_give_the_same_bits_on_one_and_two_threads():
    """What lets a training's rulebooks and convs give way to other processes without changing its results."""
    generator = torch.Generator().manual_seed(1)
    shape = [20, 60, 60]
    cells = torch.unique(torch.stack([torch.randint(0, s, (6000,), generator=generator) for s in shape], 1), dim=0)
    coords = torch.cat([torch.zeros(len(cells), 1, dtype=torch.long), cells], 1).numpy()
    features = torch.randn(len(coords), 64, generator=generator)
    results = []
    threads = torch.get_num_threads()
    for conv in (spconv.SubMConv3d(64, 64, 3, bias=False), spconv.SparseConv3d(64, 64, 3, stride=2, padding=1,
                                                                              bias=False)):
        built = []
        for count in (1, 2):
            with rulebook.on_threads(count):
                built.append(rulebook.Rulebook(coords, shape, conv))
        assert np.array_equal(built[0].coords, built[1].coords)
        assert [k for k, _, _ in built[0].pairs] == [k for k, _, _ in built[1].pairs]
        assert all(torch.equal(a, b) for (_, *one), (_, *two) in zip(*(rules.pairs for rules in built))
                   for a, b in zip(one, two))
        rules = built[1]
        weight = torch.randn(rulebook.kernel_weight(conv).shape, generator=generator)
        upstream = torch.randn(len(rules.coords), 64, generator=generator)
        for count in (1, 2):
            inputs, kernel = features.clone().requires_grad_(), weight.clone().requires_grad_()
            out = rulebook.SparseConvFunction.apply(inputs, kernel, rules, count)
            (out * upstream).sum().backward()
            results.append((out.detach(), inputs.grad, kernel.grad))
            assert torch.get_num_threads() == threads
    for one, two in (results[0:2], results[2:4]):
        assert all(torch.equal(a, b) for a, b in zip(one, two))


def test_stride_2_conv_reaches_eight_output_cells_as_spconv():
    """Input cell (1, 1, 1) = 1, kernel 3, stride 2, padding 1: output cell o per axis takes offset k = 1 + 1 - 2 o,
    so o = 0 takes k = 2 and o = 1 takes k = 0, and output (oz, oy, ox) is 1 + 9 kz + 3 ky + kx."""
    conv = _conv(spconv.SparseConv3d(1, 1, 3, stride=2, padding=1, bias=False))
    out = _run(conv, [[0, 1, 1, 1]], [1.0], [4, 4, 4])
    expected = {(0, oz, oy, ox): 1.0 + 9 * (2 - 2 * oz) + 3 * (2 - 2 * oy) + (2 - 2 * ox)
                for oz in (0, 1) for oy in (0, 1) for ox in (0, 1)}
    assert out == expected
    assert out[(0, 0, 0, 0)] == 27.0 and out[(0, 1, 1, 1)] == 1.0
    with torch.no_grad():
        reference = conv(spconv.SparseConvTensor(torch.ones(1, 1), torch.tensor([[0, 1, 1, 1]], dtype=torch.int32),
                                                 [4, 4, 4], 1))
    assert {tuple(c): v for c, v in zip(reference.indices.tolist(), reference.features[:, 0].tolist())} == expected


def test_z_conv_of_conv_out_and_its_output_grid():
    """Kernel (3, 1, 1), stride (2, 1, 1), no padding, depth 5 -> 2: z = 2 reaches o = 1 by k = 0 (weight 1) and
    o = 0 by k = 2 (weight 3); z = 4 reaches o = 1 by k = 2 only."""
    conv = _conv(spconv.SparseConv3d(1, 1, (3, 1, 1), stride=(2, 1, 1), bias=False))
    tensor = spconv.SparseConvTensor(torch.tensor([[1.0], [10.0]]), torch.tensor([[0, 2, 3, 4], [0, 4, 3, 4]],
                                                                                   dtype=torch.int32), [5, 6, 7], 1)
    with torch.no_grad():
        out = rulebook.run(conv, tensor, {})
    assert out.spatial_shape == [2, 6, 7]
    assert dict(zip(map(tuple, out.indices.tolist()), out.features[:, 0].tolist())) == {
        (0, 1, 3, 4): 1 * 1 + 3 * 10, (0, 0, 3, 4): 3 * 1}


def test_training_batch_norm_gives_the_same_bits_on_one_and_two_threads():
    """torch's BatchNorm of (V, C) rows splits them between threads, so its bits differ on one and two (asserted
    here: the trap); the sparse blocks' training BatchNorm gives torch's one-thread bits on two threads, forward,
    backward and running statistics, so it too may run beside busy processes without changing a training."""
    generator = torch.Generator().manual_seed(2)
    features = torch.randn(800, 32, generator=generator) * 3 + 1
    upstream = torch.randn(800, 32, generator=generator)
    threads = torch.get_num_threads()

    def results(count: int, forward) -> list[torch.Tensor]:
        norm = nn.BatchNorm1d(32, eps=1e-3, momentum=0.01)
        with torch.no_grad():
            norm.weight.copy_(torch.linspace(0.5, 2.0, 32))
            norm.bias.copy_(torch.linspace(-1.0, 1.0, 32))
        inputs = features.clone().requires_grad_()
        with rulebook.on_threads(count):
            out = forward(norm, inputs)
            (out * upstream).sum().backward()
        return [out.detach(), inputs.grad, norm.weight.grad, norm.bias.grad, norm.running_mean, norm.running_var,
                norm.num_batches_tracked]

    torch_one, torch_two = results(1, nn.BatchNorm1d.__call__), results(2, nn.BatchNorm1d.__call__)
    ours_two, ours_one = results(2, rulebook.batch_norm), results(1, rulebook.batch_norm)
    assert not all(torch.equal(a, b) for a, b in zip(torch_one, torch_two))
    for ours in (ours_one, ours_two):
        assert all(torch.equal(a, b) for a, b in zip(torch_one, ours))
    assert ours_two[-1].item() == 1 and torch.get_num_threads() == threads


def test_batch_norm_is_folded_and_relu_applied():
    """Conv -> BatchNorm (mean 2, var + eps 4, gamma 3, beta -1: (c - 2) / 2 * 3 - 1) -> ReLU."""
    conv = _conv(spconv.SubMConv3d(1, 1, 3, bias=False, indice_key="subm"))
    norm = nn.BatchNorm1d(1, eps=1e-3).eval()
    with torch.no_grad():
        norm.running_mean.fill_(2.0)
        norm.running_var.fill_(4.0 - 1e-3)
        norm.weight.fill_(3.0)
        norm.bias.fill_(-1.0)
    block = spconv.SparseSequential(conv, norm, nn.ReLU())
    out = _run(block, [[0, 0, 0, 0], [0, 1, 1, 1]], [1.0, 0.0], [3, 3, 3])
    # (0,0,0) sees itself (14) and (1,1,1) at offset (+1,+1,+1), k = 26; (1,1,1) sees (0,0,0) at k = 0, weight 1
    assert out[(0, 0, 0, 0)] == pytest.approx((14 * 1 - 2) / 2 * 3 - 1, rel=1e-6)  # 17
    assert out[(0, 1, 1, 1)] == 0.0  # 0.5 * (1 * 1 - 2) * 3 - 1 = -2.5 -> ReLU


def test_torch_keeps_its_thread_count():
    """numba's parallel kernels must not change torch's threads: starting numba's OpenMP pool set a 1-thread process
    to 2 threads (5 training processes on 2 cores then ran 6x slower after their first validation)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        _run(_conv(spconv.SubMConv3d(1, 1, 3, bias=False)), [[0, 0, 0, 0], [0, 0, 0, 1]], [1.0, 2.0], [2, 2, 2])
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(threads)


def test_unsupported_layers_are_refused_by_name():
    tensor = spconv.SparseConvTensor(torch.ones(1, 1), torch.zeros(1, 4, dtype=torch.int32), [3, 3, 3], 1)
    with torch.no_grad(), pytest.raises(ValueError, match="dilation"):
        rulebook.run(spconv.SubMConv3d(1, 1, 3, dilation=2, bias=False), tensor, {})
    with torch.no_grad(), pytest.raises(ValueError, match="centres odd kernels"):
        rulebook.run(spconv.SubMConv3d(1, 1, 2, bias=False), tensor, {})
    with torch.no_grad(), pytest.raises(ValueError, match="Sigmoid in a sparse block"):
        rulebook.run(spconv.SparseSequential(nn.Sigmoid()), tensor, {})
