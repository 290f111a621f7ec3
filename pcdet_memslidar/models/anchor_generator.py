"""Anchors on the BEV feature map (OpenPCDet's AnchorGenerator)."""
from __future__ import annotations

import numpy as np
import torch


def generate_anchors(anchor_configs, grid_size, point_cloud_range) -> tuple[list[torch.Tensor], list[int]]:
    """One anchor tensor per class config, shaped (num_heights, H, W, num_sizes, num_rotations, 7) with boxes
    [x, y, z_center, dx, dy, dz, heading]; the map is the voxel grid divided by `feature_map_stride`.

    Returns (anchors per class, anchors per location per class).
    """
    grid_size = np.asarray(grid_size)
    pc_range = [float(v) for v in point_cloud_range]
    all_anchors, per_location = [], []
    for config in anchor_configs:
        map_x, map_y = (grid_size[:2] // config["feature_map_stride"]).tolist()
        sizes = torch.tensor(config["anchor_sizes"], dtype=torch.float32)
        rotations = torch.tensor(config["anchor_rotations"], dtype=torch.float32)
        bottoms = torch.tensor(config["anchor_bottom_heights"], dtype=torch.float32)
        if config.get("align_center", False):
            x_stride, y_stride = (pc_range[3] - pc_range[0]) / map_x, (pc_range[4] - pc_range[1]) / map_y
            x_offset, y_offset = x_stride / 2, y_stride / 2
        else:
            x_stride, y_stride = (pc_range[3] - pc_range[0]) / (map_x - 1), (pc_range[4] - pc_range[1]) / (map_y - 1)
            x_offset = y_offset = 0.0
        xs = pc_range[0] + x_offset + x_stride * torch.arange(map_x, dtype=torch.float32)
        ys = pc_range[1] + y_offset + y_stride * torch.arange(map_y, dtype=torch.float32)
        grid_x, grid_y, grid_z = torch.meshgrid(xs, ys, bottoms, indexing="ij")  # (W, H, Z)
        shape = (*grid_x.shape, len(sizes), len(rotations))
        anchors = torch.stack([
            grid_x[..., None, None].expand(shape), grid_y[..., None, None].expand(shape),
            grid_z[..., None, None].expand(shape),
            sizes[:, 0, None].expand(shape), sizes[:, 1, None].expand(shape), sizes[:, 2, None].expand(shape),
            rotations.expand(shape)], dim=-1)
        anchors = anchors.permute(2, 1, 0, 3, 4, 5).contiguous()  # (Z, H, W, sizes, rotations, 7)
        anchors[..., 2] += anchors[..., 5] / 2  # bottom height -> box centre
        all_anchors.append(anchors)
        per_location.append(len(sizes) * len(rotations) * len(bottoms))
    return all_anchors, per_location
