"""tools/compute_floor.py: exact FLOP counts of known layers, and a GEMM rate that is a rate."""
import pytest
import torch


@pytest.fixture(scope="module")
def compute(load_tool):
    return load_tool("compute_floor.py")


def test_forward_flops_counts_a_convolution_and_a_linear_layer_exactly(compute):
    model = torch.nn.Sequential(torch.nn.Conv2d(8, 16, 3, padding=1, bias=False), torch.nn.Flatten(),
                                torch.nn.Linear(16 * 10 * 12, 5))
    # conv: 2 x (10 x 12 outputs) x 16 channels x (8 x 3 x 3 inputs); linear: 2 x 1920 x 5
    assert compute.forward_flops(model, torch.zeros(1, 8, 10, 12)) == 2 * 120 * 16 * 72 + 2 * 1920 * 5 == 295_680


def test_the_floor_is_flops_over_the_rate(compute):
    assert compute.floor_ms(43_200_000_000, 120e9) == 360.0
    rate = compute.gemm_flops_per_s(size=128, repeats=3)
    assert 1e6 < rate < 1e15
