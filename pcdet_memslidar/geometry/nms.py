"""Rotated non-maximum suppression of LiDAR boxes in bird's eye view, on CPU or GPU (torch)."""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.geometry.iou import aligned_iou_torch, near_pairs


def nms_rotated(boxes: torch.Tensor, scores: torch.Tensor, iou_threshold: float,
                pre_max: int | None = None, post_max: int | None = None) -> torch.Tensor:
    """Greedy class-agnostic NMS: keep the best-scored box, drop every box whose BEV IoU with it is > threshold.

    boxes (N, 7) [x, y, z, dx, dy, dz, heading], scores (N,), both on one device. Only the `pre_max` best-scored
    boxes are considered and at most `post_max` are kept. Returns the kept indices into `boxes` (torch.long, on
    the boxes' device), best score first. The exact rotated IoU (geometry.iou) is computed on the device for the
    pairs whose circumscribed circles overlap; the greedy pass over that sparse overlap graph runs on the CPU.
    """
    if boxes.ndim != 2 or boxes.shape[1] < 7 or scores.shape != boxes.shape[:1]:
        raise ValueError(f"nms_rotated: expected boxes (N, 7) and scores (N,), got {tuple(boxes.shape)} and "
                         f"{tuple(scores.shape)}")
    order = torch.argsort(scores, descending=True, stable=True)
    if pre_max is not None:
        order = order[:pre_max]
    candidates = boxes[order, :7].detach()
    count = len(order)
    first, second = near_pairs(candidates, candidates)
    later = second > first
    first, second = first[later], second[later]
    iou_bev, _ = aligned_iou_torch(candidates[first], candidates[second])
    overlapping = (iou_bev > iou_threshold).cpu().numpy()
    first, second = first.cpu().numpy()[overlapping], second.cpu().numpy()[overlapping]
    # Sparse overlap graph: neighbours of candidate i are second[start[i]:start[i + 1]] (first is sorted).
    start = np.searchsorted(first, np.arange(count + 1))
    suppressed = np.zeros(count, dtype=bool)
    kept = []
    for i in range(count):
        if suppressed[i]:
            continue
        kept.append(i)
        if post_max is not None and len(kept) == post_max:
            break
        suppressed[second[start[i]:start[i + 1]]] = True
    return order[torch.as_tensor(kept, dtype=torch.long, device=boxes.device)]
