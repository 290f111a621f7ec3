"""Heatmap targets and decoding of a center head (OpenPCDet's centernet_utils, CenterPoint's conventions).

Feature-map cells: a point (x, y) [m] lies at cell coordinates ((x - x0) / (vx * stride), (y - y0) / (vy * stride));
cell (i, j) covers [i, i + 1) x [j, j + 1), and the heatmap is indexed [class, j, i] (rows are y).
- Target: each box puts a Gaussian peak of exactly 1 on the cell holding its centre; the Gaussian's radius comes
  from the box's BEV size in cells (`gaussian_radius`, CornerNet's bound: a box shifted by the radius still
  overlaps the true one by `min_overlap`), at least a minimum radius; where two peaks meet, the cell keeps the
  larger value. The regression target at the centre cell: the offset of the centre within its cell (in [0, 1)),
  z [m], log of (dx, dy, dz) [m], cos and sin of the heading.
- Decoding: the K highest heatmap cells over all classes (no local-maximum pooling: NMS follows), each turned back
  into a box from the regressions at that cell.
"""
from __future__ import annotations

import numpy as np
import torch


def gaussian_radius(length: torch.Tensor, width: torch.Tensor, min_overlap: float = 0.5) -> torch.Tensor:
    """(N,) radius [cells] of the Gaussian of boxes length x width [cells]: the smallest of CornerNet's three
    corner-shift bounds (both corners inside, both outside, one of each) that keep IoU >= min_overlap."""
    size_sum, area = length + width, length * width
    r1 = (size_sum + torch.sqrt(size_sum ** 2 - 4 * area * (1 - min_overlap) / (1 + min_overlap))) / 2
    r2 = (2 * size_sum + torch.sqrt((2 * size_sum) ** 2 - 16 * (1 - min_overlap) * area)) / 2
    b3 = -2 * min_overlap * size_sum
    r3 = (b3 + torch.sqrt(b3 ** 2 + 16 * min_overlap * (1 - min_overlap) * area)) / 2
    return torch.minimum(torch.minimum(r1, r2), r3)


def gaussian_kernel(radius: int) -> np.ndarray:
    """(2r + 1, 2r + 1) float64 exp(-d^2 / (2 sigma^2)) with sigma = (2r + 1) / 6, 1 at the centre; values below
    float64 eps x 1 set to 0."""
    diameter = 2 * radius + 1
    sigma = diameter / 6
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-(offsets[None, :] ** 2 + offsets[:, None] ** 2) / (2 * sigma * sigma))
    kernel[kernel < np.finfo(np.float64).eps * kernel.max()] = 0
    return kernel


def draw_gaussian(heatmap: torch.Tensor, center_cell: tuple[int, int], radius: int) -> torch.Tensor:
    """Raise heatmap (H, W) in place to the Gaussian of `radius` [cells] around the cell (i, j) = (column, row),
    clipped at the map's edges; returns heatmap."""
    i, j = center_cell
    height, width = heatmap.shape
    left, right = min(i, radius), min(width - i, radius + 1)
    top, bottom = min(j, radius), min(height - j, radius + 1)
    if min(left + right, top + bottom) <= 0:
        return heatmap
    kernel = torch.from_numpy(gaussian_kernel(radius)[radius - top:radius + bottom, radius - left:radius + right])
    window = heatmap[j - top:j + bottom, i - left:i + right]
    torch.maximum(window, kernel.to(heatmap), out=window)
    return heatmap


def assign_center_targets(gt_boxes: torch.Tensor, num_classes: int, map_size: tuple[int, int], point_cloud_range,
                          voxel_size, stride: int, num_max_objs: int, gaussian_overlap: float, min_radius: int):
    """Targets of one frame: gt_boxes (M, 8) [x, y, z, dx, dy, dz, heading, class 1..num_classes], rows of size
    0 skipped (padding); map_size (W, H) cells.

    Returns heatmap (num_classes, H, W), target boxes (num_max_objs, 8) [offset x, offset y, z, log dx, log dy,
    log dz, cos, sin], inds (num_max_objs,) int64 flat cell index j * W + i, mask (num_max_objs,) int64 1 where a
    box is. Boxes beyond num_max_objs are left out, as OpenPCDet does.
    """
    width, height = map_size
    gt_boxes = gt_boxes.float()
    heatmap = gt_boxes.new_zeros(num_classes, height, width)
    target_boxes = gt_boxes.new_zeros(num_max_objs, 8)
    inds = torch.zeros(num_max_objs, dtype=torch.int64)
    mask = torch.zeros(num_max_objs, dtype=torch.int64)
    cell_x = ((gt_boxes[:, 0] - point_cloud_range[0]) / voxel_size[0] / stride).clamp(0, width - 0.5)
    cell_y = ((gt_boxes[:, 1] - point_cloud_range[1]) / voxel_size[1] / stride).clamp(0, height - 0.5)
    length = gt_boxes[:, 3] / voxel_size[0] / stride
    width_cells = gt_boxes[:, 4] / voxel_size[1] / stride
    radius = gaussian_radius(length, width_cells, gaussian_overlap).int().clamp_min(min_radius)
    for k in range(min(num_max_objs, len(gt_boxes))):
        if length[k] <= 0 or width_cells[k] <= 0:
            continue
        i, j = int(cell_x[k]), int(cell_y[k])
        draw_gaussian(heatmap[int(gt_boxes[k, 7]) - 1], (i, j), int(radius[k]))
        inds[k], mask[k] = j * width + i, 1
        target_boxes[k, 0], target_boxes[k, 1] = cell_x[k] - i, cell_y[k] - j
        target_boxes[k, 2] = gt_boxes[k, 2]
        target_boxes[k, 3:6] = gt_boxes[k, 3:6].log()
        target_boxes[k, 6], target_boxes[k, 7] = torch.cos(gt_boxes[k, 6]), torch.sin(gt_boxes[k, 6])
    return heatmap, target_boxes, inds, mask


def gather_cells(features: torch.Tensor, inds: torch.Tensor) -> torch.Tensor:
    """features (B, C, H, W), inds (B, K) flat cell indices -> (B, K, C)."""
    batch, channels = features.shape[:2]
    flat = features.reshape(batch, channels, -1).permute(0, 2, 1)
    return flat.gather(1, inds.unsqueeze(-1).expand(-1, -1, channels))


def decode_heatmap(heatmap: torch.Tensor, center: torch.Tensor, center_z: torch.Tensor, dim: torch.Tensor,
                   rot: torch.Tensor, point_cloud_range, voxel_size, stride: int, max_objects: int,
                   score_thresh: float | None, center_limit_range) -> list[dict]:
    """Head outputs (B, C, H, W) (heatmap as probabilities, dim as sizes [m], rot as (cos, sin)) -> per frame
    {'pred_boxes' (K', 7), 'pred_scores' (K',), 'pred_labels' (K',) 0-based}: the max_objects best cells over all
    classes, boxes whose centre lies in center_limit_range [x0, y0, z0, x1, y1, z1] [m], scores > score_thresh."""
    batch, num_classes, height, width = heatmap.shape
    k = min(max_objects, num_classes * height * width)
    scores, flat = heatmap.reshape(batch, -1).topk(k)
    labels, inds = flat // (height * width), flat % (height * width)
    offsets = gather_cells(center, inds)
    xs = ((inds % width).to(offsets.dtype) + offsets[..., 0]) * stride * voxel_size[0] + point_cloud_range[0]
    ys = ((inds // width).to(offsets.dtype) + offsets[..., 1]) * stride * voxel_size[1] + point_cloud_range[1]
    rotation = gather_cells(rot, inds)
    heading = torch.atan2(rotation[..., 1], rotation[..., 0])
    boxes = torch.cat([xs.unsqueeze(-1), ys.unsqueeze(-1), gather_cells(center_z, inds), gather_cells(dim, inds),
                       heading.unsqueeze(-1)], dim=-1)
    limits = torch.as_tensor(center_limit_range, dtype=boxes.dtype, device=boxes.device)
    keep = ((boxes[..., :3] >= limits[:3]) & (boxes[..., :3] <= limits[3:])).all(dim=-1)
    if score_thresh is not None:
        keep &= scores > score_thresh
    return [{"pred_boxes": boxes[index, keep[index]], "pred_scores": scores[index, keep[index]],
             "pred_labels": labels[index, keep[index]]} for index in range(batch)]

