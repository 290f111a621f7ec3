"""spconv on CPU: VoxelBackBone8x (models.rulebook) and spconv (backward patched) equal a dense conv3d reference at
2 threads, forward and backward, and in inference; training runs models.rulebook on 2 threads and spconv on 1, with
the same outputs and gradients; the CPU patch is idempotent, and the sparse output becomes the BEV map exactly on 2
threads."""
import subprocess
import sys

import pytest
import spconv.pytorch as spconv
import torch
from easydict import EasyDict
from torch.nn import functional as F

from pcdet_memslidar import policy
from pcdet_memslidar.models import rulebook
from pcdet_memslidar.models.backbone_3d import VoxelBackBone8x
from pcdet_memslidar.models.map_to_bev import HeightCompression
from pcdet_memslidar.models.spconv_cpu import patch_spconv, single_thread

GRID = [64, 48, 40]  # x, y, z cells
run = rulebook.run


def _dense_block(x, mask, sequential):
    """One spconv SparseSequential(conv, BatchNorm1d, ReLU) (eval mode) on dense (1, C, D, H, W) features."""
    conv, norm = sequential[0], sequential[1]
    weight = conv.weight.permute(0, 4, 1, 2, 3)  # spconv (Cout, kz, ky, kx, Cin) -> torch (Cout, Cin, kz, ky, kx)
    if conv.subm:
        out = F.conv3d(x, weight, padding=[k // 2 for k in conv.kernel_size])
    else:
        out = F.conv3d(x, weight, stride=conv.stride, padding=conv.padding)
        ones = torch.ones(1, 1, *conv.kernel_size)
        mask = F.conv3d(mask, ones, stride=conv.stride, padding=conv.padding) > 0
        mask = mask.to(x.dtype)
    scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
    out = (out - norm.running_mean.view(1, -1, 1, 1, 1)) * scale.view(1, -1, 1, 1, 1) + norm.bias.view(1, -1, 1, 1, 1)
    return torch.relu(out) * mask, mask


def _dense_backbone(backbone, features, coords, shape):
    x = torch.zeros(1, features.shape[1], *shape)
    x[0, :, coords[:, 1], coords[:, 2], coords[:, 3]] = features.t()
    mask = torch.zeros(1, 1, *shape)
    mask[0, 0, coords[:, 1], coords[:, 2], coords[:, 3]] = 1.0
    x, mask = _dense_block(x, mask, backbone.conv_input)
    for stage in (backbone.conv1, backbone.conv2, backbone.conv3, backbone.conv4):
        for block in stage:
            x, mask = _dense_block(x, mask, block)
    x, _ = _dense_block(x, mask, backbone.conv_out)
    return x


@pytest.fixture
def two_threads():
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)


def _eval_backbone(second_model_cfg, generator) -> VoxelBackBone8x:
    """An eval-mode backbone whose BatchNorms have running statistics and affine terms far from the identity."""
    backbone = VoxelBackBone8x(second_model_cfg().BACKBONE_3D, input_channels=4, grid_size=GRID)
    with torch.no_grad():
        for module in backbone.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.running_mean.uniform_(-0.2, 0.2, generator=generator)
                module.running_var.uniform_(0.5, 2.0, generator=generator)
                module.weight.uniform_(0.5, 1.5, generator=generator)
                module.bias.uniform_(-0.1, 0.1, generator=generator)
    return backbone.eval()


def _random_cells(shape, count: int, generator) -> torch.Tensor:
    """(N, 3) distinct random cells (z, y, x) of a grid of `shape`."""
    cells = torch.stack([torch.randint(0, s, (count,), generator=generator) for s in shape], dim=1)
    return torch.unique(cells, dim=0)


def test_sparse_backbone_equals_dense_conv3d_at_two_threads(two_threads, second_model_cfg):
    generator = torch.Generator().manual_seed(0)
    backbone = _eval_backbone(second_model_cfg, generator)
    shape = backbone.sparse_shape  # (z + 1, y, x)
    cells = _random_cells(shape, 3000, generator)
    coords = torch.cat([torch.zeros(len(cells), 1, dtype=torch.long), cells], dim=1)
    features = torch.randn(len(coords), 4, generator=generator, requires_grad=True)
    batch = {"voxel_features": features, "voxel_coords": coords.int(), "batch_size": 1}
    sparse_out = backbone(batch)["encoded_spconv_tensor"].dense()

    dense_features = features.detach().clone().requires_grad_()
    dense_out = _dense_backbone(backbone, dense_features, coords, shape)
    assert sparse_out.shape == dense_out.shape == (1, 128, 2, 6, 8)
    scale = dense_out.abs().max().item()
    assert scale > 0.1
    assert (sparse_out - dense_out).abs().max().item() <= 1e-4 * scale

    upstream = torch.randn(dense_out.shape, generator=generator)
    (sparse_out * upstream).sum().backward()  # the rulebook's backward, at 2 threads
    (dense_out * upstream).sum().backward()
    grad_scale = dense_features.grad.abs().max().item()
    assert (features.grad - dense_features.grad).abs().max().item() <= 1e-4 * grad_scale

    # spconv (OpenPCDet's path through the launcher): forward on one thread, backward at 2 threads (patched to one
    # inside spconv; unpatched, its scatter-add races there)
    spconv_features = features.detach().clone().requires_grad_()
    with single_thread():
        x = spconv.SparseConvTensor(spconv_features, coords.int(), shape, 1)
        for stage in (backbone.conv_input, backbone.conv1, backbone.conv2, backbone.conv3, backbone.conv4,
                      backbone.conv_out):
            x = stage(x)
    assert (x.dense() - dense_out).abs().max().item() <= 1e-4 * scale
    (x.dense() * upstream).sum().backward()
    assert (spconv_features.grad - dense_features.grad).abs().max().item() <= 1e-4 * grad_scale
    assert torch.get_num_threads() == 2


def test_inference_runs_the_rulebook_and_equals_spconv_and_dense_conv3d_at_two_threads(two_threads, second_model_cfg,
                                                                                       monkeypatch):
    """Eval mode without grad runs models.rulebook on all threads: two frames in one batch, cells on every face of
    the grid included, give spconv's map and the dense reference's per frame, and the same bits on every run."""
    generator = torch.Generator().manual_seed(2)
    backbone = _eval_backbone(second_model_cfg, generator)
    shape = backbone.sparse_shape
    faces = torch.tensor([[0, 0, 0], [shape[0] - 1, shape[1] - 1, shape[2] - 1], [0, shape[1] - 1, 5],
                          [shape[0] - 1, 0, shape[2] - 1], [3, 0, 0], [0, 7, shape[2] - 1]])
    frames = [torch.unique(torch.cat([faces, _random_cells(shape, 2500 + 500 * b, generator)]), dim=0)
              for b in range(2)]
    coords = torch.cat([torch.cat([torch.full((len(cells), 1), b), cells], dim=1) for b, cells in enumerate(frames)])
    features = torch.randn(len(coords), 4, generator=generator)
    batch = {"voxel_features": features, "voxel_coords": coords.int(), "batch_size": 2}
    calls = []
    monkeypatch.setattr(rulebook, "run", lambda *args: calls.append(1) or run(*args))
    with torch.no_grad():
        ours = [backbone(dict(batch))["encoded_spconv_tensor"] for _ in range(2)]
    assert len(calls) == 12  # two forwards of six sparse stages
    assert torch.equal(ours[0].features, ours[1].features) and torch.equal(ours[0].indices, ours[1].indices)
    with torch.no_grad(), single_thread():
        x = spconv.SparseConvTensor(features, coords.int(), shape, 2)
        for stage in (backbone.conv_input, backbone.conv1, backbone.conv2, backbone.conv3, backbone.conv4,
                      backbone.conv_out):
            x = stage(x)
    assert ours[0].spatial_shape == x.spatial_shape and len(ours[0].features) == len(x.features)
    reference = x.dense()
    scale = reference.abs().max().item()
    assert scale > 0.1
    assert (ours[0].dense() - reference).abs().max().item() <= 1e-5 * scale
    for b, cells in enumerate(frames):
        keep = coords[:, 0] == b
        dense = _dense_backbone(backbone, features[keep], coords[keep], shape)
        assert (ours[0].dense()[b] - dense[0]).abs().max().item() <= 1e-4 * scale
    assert torch.get_num_threads() == 2


@pytest.mark.slow
def test_training_runs_the_rulebook_on_two_threads_and_spconv_on_one_with_the_same_gradients(second_model_cfg,
                                                                                            monkeypatch):
    """Training mode (batch statistics in the BatchNorms), two frames, float64: the rulebook on 2 threads gives
    spconv's output (on 1 thread) and the gradients of every parameter and of the features, the same bits on every
    run, on 3 threads, and when other processes leave its convs one core. (In float32 the batch statistics of the
    deep layers, few cells each, amplify rounding to about 1 % of a gradient, for spconv as for the rulebook against
    a float64 reference.)"""
    torch.manual_seed(4)
    backbone = VoxelBackBone8x(second_model_cfg().BACKBONE_3D, input_channels=4, grid_size=GRID).train().double()
    generator = torch.Generator().manual_seed(4)
    shape = backbone.sparse_shape
    coords = torch.cat([torch.cat([torch.full((len(cells), 1), b), cells], dim=1)
                        for b, cells in enumerate(_random_cells(shape, 3000, generator) for _ in range(2))])
    features = torch.randn(len(coords), 4, generator=generator, dtype=torch.float64)
    upstream = torch.randn(2, 128, 2, 6, 8, generator=generator, dtype=torch.float64)
    calls = []
    monkeypatch.setattr(rulebook, "run", lambda *args: calls.append(args[3]) or run(*args))

    def gradients(threads: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        backbone.zero_grad()
        inputs = features.clone().requires_grad_()
        previous = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            out = backbone({"voxel_features": inputs, "voxel_coords": coords.int(), "batch_size": 2})
            dense = out["encoded_spconv_tensor"].dense()
            (dense * upstream).sum().backward()
        finally:
            torch.set_num_threads(previous)
        return dense.detach(), {"features": inputs.grad} | {n: p.grad.clone() for n, p in
                                                            backbone.named_parameters()}

    monkeypatch.setattr(policy, "free_threads", lambda limit: limit)  # an idle machine
    ours, again, reference, three = gradients(2), gradients(2), gradients(1), gradients(3)
    monkeypatch.setattr(policy, "free_threads", lambda limit: 1)  # three busy processes on two cores
    loaded = gradients(2)
    assert calls == [2] * 12 + [3] * 6 + [1] * 6  # four training steps of six sparse stages, none on spconv's 1
    for other in (again, three, loaded):
        assert torch.equal(ours[0], other[0]) and all(torch.equal(ours[1][n], other[1][n]) for n in ours[1])
    scale = reference[0].abs().max().item()
    assert scale > 0.1 and (ours[0] - reference[0]).abs().max().item() <= 1e-12 * scale
    assert len(ours[1]) == 1 + len(list(backbone.parameters()))
    for name, grad in reference[1].items():
        assert grad.abs().max() > 0, name
        assert (ours[1][name] - grad).abs().max().item() <= 1e-12 * grad.abs().max().item(), name


def test_patch_is_idempotent_and_single_thread_restores():
    import spconv.pytorch.functional as functional
    import spconv.pytorch.ops as ops

    patch_spconv()
    backward = functional.SubMConvFunction.backward
    patch_spconv()
    assert functional.SubMConvFunction.backward is backward  # wrapped once only
    if not torch.cuda.is_available():
        assert ops.get_current_stream() == 0
    threads = torch.get_num_threads()
    with single_thread():
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == threads


def test_height_compression_places_every_voxel_exactly_at_two_threads(two_threads):
    """HeightCompression runs on all threads (spconv's dense() is torch indexing): channel c of height d lands in
    BEV channel c * D + d at its (y, x), nothing else is written."""
    generator = torch.Generator().manual_seed(1)
    batch, channels, shape = 2, 3, (2, 40, 56)  # (D, H, W)
    cells = torch.randperm(batch * shape[0] * shape[1] * shape[2], generator=generator)[:900]
    b, rest = cells // (shape[0] * shape[1] * shape[2]), cells % (shape[0] * shape[1] * shape[2])
    z, y, x = rest // (shape[1] * shape[2]), rest // shape[2] % shape[1], rest % shape[2]
    features = torch.randn(len(cells), channels, generator=generator)
    tensor = spconv.SparseConvTensor(features, torch.stack([b, z, y, x], 1).int(), list(shape), batch)
    bev = HeightCompression(EasyDict(NUM_BEV_FEATURES=channels * shape[0]))(
        {"encoded_spconv_tensor": tensor, "encoded_spconv_tensor_stride": 8})["spatial_features"]
    expected = torch.zeros(batch, channels, *shape)
    expected[b, :, z, y, x] = features
    assert bev.shape == (batch, channels * shape[0], shape[1], shape[2])
    assert torch.equal(bev, expected.view(batch, channels * shape[0], shape[1], shape[2]))
    assert torch.equal(bev[b[0], 1 * shape[0] + z[0], y[0], x[0]], features[0, 1])


@pytest.mark.slow
@pytest.mark.parametrize("patched", [False, True])
def test_torch_fx_notice_stays_out_of_the_log_once_spconv_is_patched(patched):
    """Every SparseConvTensor asks torch.fx whether it traces; torch logs a notice the first time in a process."""
    code = ("import torch, spconv.pytorch as spconv\n"
            + ("from pcdet_memslidar.models.spconv_cpu import patch_spconv\npatch_spconv()\n" if patched else "")
            + "spconv.SparseConvTensor(torch.ones(1, 1), torch.zeros(1, 4, dtype=torch.int32), [2, 2, 2], 1)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert ("is_fx_tracing" in done.stderr) is not patched
