"""Sparse 3D backbone of SECOND (spconv 2.x), OpenPCDet's VoxelBackBone8x with its state-dict layout."""
from __future__ import annotations

import contextlib
from functools import partial

import numpy as np
import spconv.pytorch as spconv
import torch
from torch import nn

from pcdet_memslidar.grid import SPARSE_OUTPUT_CHANNELS, SPARSE_STRIDE, sparse_output_shape
from pcdet_memslidar.models import rulebook
from pcdet_memslidar.models.spconv_cpu import patch_spconv, single_thread
from pcdet_memslidar.policy import ExecutionPolicy, choose_policy

_batch_norm = partial(nn.BatchNorm1d, eps=1e-3, momentum=0.01)


def sparse_block(in_channels: int, out_channels: int, kernel_size, indice_key: str, stride=1, padding=0,
                 conv_type: str = "subm") -> spconv.SparseSequential:
    """Bias-free sparse conv + BatchNorm + ReLU (biased sparse convs break in eval mode on CPU, spconv #719)."""
    if conv_type == "subm":
        conv = spconv.SubMConv3d(in_channels, out_channels, kernel_size, bias=False, indice_key=indice_key)
    elif conv_type == "spconv":
        conv = spconv.SparseConv3d(in_channels, out_channels, kernel_size, stride=stride, padding=padding,
                                   bias=False, indice_key=indice_key)
    else:
        raise ValueError(f"unknown sparse conv type '{conv_type}': use 'subm' or 'spconv'")
    return spconv.SparseSequential(conv, _batch_norm(out_channels), nn.ReLU())


class VoxelBackBone8x(nn.Module):
    """Sparse convs 16-32-64-64 channels, 8x downsampling, then a (3,1,1) z-conv to 128 channels.

    `policy` (pcdet_memslidar.policy, set by the runtime through the detector's set_policy) says which back end runs
    the convs, models.rulebook or spconv, with grad and without, and on how many threads; spconv on a CPU runs on one
    (its CPU kernels race with more, see spconv_cpu). Without a policy (a model used outside the runtime) each forward
    follows choose_policy for its input's device and torch's threads at that moment. Building one makes spconv
    correct on a CPU (spconv_cpu.patch_spconv).
    """

    def __init__(self, model_cfg, input_channels: int, grid_size, **kwargs):
        super().__init__()
        patch_spconv()
        self.policy: ExecutionPolicy | None = None
        self.model_cfg = model_cfg
        self.sparse_shape = (np.asarray(grid_size)[::-1] + [1, 0, 0]).tolist()  # (z + 1, y, x)
        self.conv_input = spconv.SparseSequential(
            spconv.SubMConv3d(input_channels, 16, 3, padding=1, bias=False, indice_key="subm1"),
            _batch_norm(16), nn.ReLU())
        self.conv1 = spconv.SparseSequential(sparse_block(16, 16, 3, padding=1, indice_key="subm1"))
        self.conv2 = spconv.SparseSequential(
            sparse_block(16, 32, 3, stride=2, padding=1, indice_key="spconv2", conv_type="spconv"),
            sparse_block(32, 32, 3, padding=1, indice_key="subm2"),
            sparse_block(32, 32, 3, padding=1, indice_key="subm2"))
        self.conv3 = spconv.SparseSequential(
            sparse_block(32, 64, 3, stride=2, padding=1, indice_key="spconv3", conv_type="spconv"),
            sparse_block(64, 64, 3, padding=1, indice_key="subm3"),
            sparse_block(64, 64, 3, padding=1, indice_key="subm3"))
        self.conv4 = spconv.SparseSequential(
            sparse_block(64, 64, 3, stride=2, padding=(0, 1, 1), indice_key="spconv4", conv_type="spconv"),
            sparse_block(64, 64, 3, padding=1, indice_key="subm4"),
            sparse_block(64, 64, 3, padding=1, indice_key="subm4"))
        self.conv_out = spconv.SparseSequential(
            spconv.SparseConv3d(64, SPARSE_OUTPUT_CHANNELS, (3, 1, 1), stride=(2, 1, 1),
                                padding=model_cfg.get("last_pad", 0), bias=False, indice_key="spconv_down2"),
            _batch_norm(SPARSE_OUTPUT_CHANNELS), nn.ReLU())
        self.num_point_features = SPARSE_OUTPUT_CHANNELS
        self.backbone_channels = {"x_conv1": 16, "x_conv2": 32, "x_conv3": 64, "x_conv4": 64}

    def forward(self, batch_dict: dict) -> dict:
        """voxel_features (V, C), voxel_coords (V, 4) [b, z, y, x] -> encoded_spconv_tensor (stride 8).

        A batch without any voxel (spconv cannot take one) gives an empty output tensor, i.e. an all-zero map.
        """
        features = batch_dict["voxel_features"]
        batch_dict.update({"encoded_spconv_tensor_stride": SPARSE_STRIDE,
                           "multi_scale_3d_strides": {"x_conv1": 1, "x_conv2": 2, "x_conv3": 4, "x_conv4": 8}})
        if features.shape[0] == 0:
            batch_dict["encoded_spconv_tensor"] = spconv.SparseConvTensor(
                features.new_zeros(0, self.num_point_features), batch_dict["voxel_coords"].new_zeros(0, 4).int(),
                sparse_output_shape(self.sparse_shape), batch_dict["batch_size"])
            return batch_dict
        device, grad = features.device.type, torch.is_grad_enabled()
        policy = self.policy or choose_policy(device, torch.get_num_threads())
        if policy.device != device:
            raise ValueError(f"the sparse backbone's execution policy is for {policy.device}, its input is on "
                             f"{device}: give the detector the policy of its device (set_policy(policy.choose_policy("
                             f"'{device}', threads)))")
        use_rulebook = policy.sparse_backend(grad) == "rulebook"
        conv_threads = policy.rulebook_threads(grad) if use_rulebook else None
        rulebooks = {}  # indice_key -> Rulebook, shared as spconv shares its indices

        def step(module, tensor):
            return rulebook.run(module, tensor, rulebooks, conv_threads) if use_rulebook else module(tensor)

        with single_thread() if device == "cpu" and not use_rulebook else contextlib.nullcontext():
            x = spconv.SparseConvTensor(features=features, indices=batch_dict["voxel_coords"].int(),
                                        spatial_shape=self.sparse_shape, batch_size=batch_dict["batch_size"])
            x = step(self.conv_input, x)
            x_conv1 = step(self.conv1, x)
            x_conv2 = step(self.conv2, x_conv1)
            x_conv3 = step(self.conv3, x_conv2)
            x_conv4 = step(self.conv4, x_conv3)
            out = step(self.conv_out, x_conv4)
        batch_dict["encoded_spconv_tensor"] = out
        batch_dict["multi_scale_3d_features"] = {"x_conv1": x_conv1, "x_conv2": x_conv2, "x_conv3": x_conv3,
                                                 "x_conv4": x_conv4}
        return batch_dict
