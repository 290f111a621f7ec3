"""Exact rotated IoU of LiDAR boxes (N, 7) [x, y, z_center, dx, dy, dz, heading], in bird's eye view and in 3D.

The intersection of two rotated rectangles is a convex polygon bounded by the parts of each rectangle's edges that
lie inside the other. Its area follows from Green's theorem as the sum of cross(start, end) / 2 over those edge
parts, so no vertex sorting is needed: every edge of A is clipped to B and every edge of B to A (Cyrus-Beck), for
all pairs at once (no Python loop per pair); a boundary shared by both boxes is counted once.

Robustness: float64; each pair is moved to its common centre and scaled by its largest side first (huge
coordinates and millimetre boxes behave like unit boxes); parallel / on-the-line decisions use a tolerance of
1e-9 of that scale; zero-size boxes give IoU 0, never NaN; results are clamped to [0, 1]. A box's footprint does
not change with heading +- pi, so neither does its IoU. 3D IoU = BEV intersection x z overlap / union volume.
A circumscribed-circle prefilter skips pairs that cannot overlap.

One implementation in torch serves numpy callers (evaluation) and torch callers on any device (NMS).
"""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.geometry.boxes import check_boxes

_TOLERANCE = 1e-9  # parallel / on-the-line tolerance, relative to the larger box side of the pair
# Corners of the unit footprint, counter-clockwise.
_FOOTPRINT_SIGNS = ((0.5, 0.5), (-0.5, 0.5), (-0.5, -0.5), (0.5, -0.5))


def _cross(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """z component of the cross product of (..., 2) vectors."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _footprints(boxes: torch.Tensor, centre: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """(K, 7) boxes -> (K, 4, 2) counter-clockwise BEV corners relative to `centre` (K, 2), divided by `scale` (K,)."""
    signs = torch.tensor(_FOOTPRINT_SIGNS, dtype=boxes.dtype, device=boxes.device)
    local = signs[None] * boxes[:, None, 3:5]
    cos, sin = torch.cos(boxes[:, 6:7]), torch.sin(boxes[:, 6:7])
    x = cos * local[..., 0] - sin * local[..., 1] + (boxes[:, 0:1] - centre[:, 0:1])
    y = sin * local[..., 0] + cos * local[..., 1] + (boxes[:, 1:2] - centre[:, 1:2])
    return torch.stack([x, y], dim=-1) / scale[:, None, None]


def _pick(point: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """point[k, e, index[k, e]] of (K, 4, 4, 2) points and (K, 4) indices -> (K, 4, 2)."""
    return torch.gather(point, 2, index[..., None, None].expand(-1, -1, 1, 2))[:, :, 0]


def _clipped_edges_area(start: torch.Tensor, end: torch.Tensor, rate: torch.Tensor, distance: torch.Tensor,
                        crossing: torch.Tensor, point: torch.Tensor, parallel: torch.Tensor,
                        dropped: torch.Tensor) -> torch.Tensor:
    """Green's theorem share of one polygon's edges inside the other: sum of cross(begin, finish) / 2 -> (K,).

    Edge e runs start[:, e] -> end[:, e] (K, 4, 2), as start + t * (end - start). Per (edge e, half-plane h of the
    other polygon), (K, 4, 4): rate > 0 if the edge enters the half-plane, distance of its start from the
    half-plane's line (> 0 inside), crossing parameter t, crossing point (K, 4, 4, 2), parallel, and dropped (a
    boundary shared with the other polygon, counted there). Each edge is clipped (Cyrus-Beck) to the half-planes;
    the clipped ends are the crossing points themselves, the very points the other polygon's edges use, so the
    boundary of the intersection closes exactly.
    """
    outside = (parallel & (distance < -_TOLERANCE)) | dropped
    inf = torch.full_like(crossing, float("inf"))
    t_low, enter = torch.where(~parallel & (rate > 0), crossing, -inf).max(dim=2)
    t_high, leave = torch.where(~parallel & (rate < 0), crossing, inf).min(dim=2)
    begin = torch.where((t_low > 0)[..., None], _pick(point, enter), start)
    finish = torch.where((t_high < 1)[..., None], _pick(point, leave), end)
    kept = ~outside.any(dim=2) & (t_high.clamp(max=1.0) > t_low.clamp(min=0.0))
    return torch.where(kept, 0.5 * _cross(begin, finish), torch.zeros_like(t_low)).sum(dim=1)


def _polygon_intersection_area(poly_a: torch.Tensor, poly_b: torch.Tensor) -> torch.Tensor:
    """Area of the intersection of (K, 4, 2) counter-clockwise unit-scale polygons A and B -> (K,).

    Every pair (edge i of A, edge j of B) is classified once: parallel or not, and for non-parallel edges the
    crossing of their lines, which both polygons' clipped edges share.
    """
    next_a, next_b = torch.roll(poly_a, -1, dims=1), torch.roll(poly_b, -1, dims=1)
    edge_a, edge_b = next_a - poly_a, next_b - poly_b
    unit_a = edge_a / torch.linalg.vector_norm(edge_a, dim=-1, keepdim=True)
    unit_b = edge_b / torch.linalg.vector_norm(edge_b, dim=-1, keepdim=True)
    sine = _cross(unit_a[:, :, None], unit_b[:, None])  # (K, 4, 4) [i, j]
    parallel = sine.abs() <= _TOLERANCE
    same_direction = (unit_a[:, :, None] * unit_b[:, None]).sum(dim=-1) > 0
    offset = poly_b[:, None] - poly_a[:, :, None]  # start of B's edge j relative to the start of A's edge i
    distance_b = _cross(unit_a[:, :, None], offset)  # start of B's edge j from A's line i, > 0 inside A
    # For parallel edges, one distance decides both sides (no contradicting decisions near the tolerance): A's
    # edge lies inside B's half-plane by -distance_b if both run the same way, by +distance_b if they face.
    distance_a = torch.where(same_direction, -distance_b, distance_b)
    denom = _cross(edge_a[:, :, None], edge_b[:, None])
    denom = torch.where(parallel, torch.ones_like(denom), denom)
    t = _cross(offset, edge_b[:, None]) / denom  # crossing on A's edge i
    u = _cross(offset, edge_a[:, :, None]) / denom  # crossing on B's edge j
    point = poly_a[:, :, None] + t[..., None] * edge_a[:, :, None]
    # A's edge enters B's half-plane j where sine < 0; B's edge enters A's half-plane i where sine > 0.
    shared = parallel & same_direction & (distance_b.abs() <= _TOLERANCE)
    area_a = _clipped_edges_area(poly_a, next_a, -sine, distance_a, t, point, parallel, torch.zeros_like(shared))
    area_b = _clipped_edges_area(poly_b, next_b, sine.transpose(1, 2), distance_b.transpose(1, 2), u.transpose(1, 2),
                                 point.transpose(1, 2), parallel.transpose(1, 2), shared.transpose(1, 2))
    return area_a + area_b


_CPU_CHUNK = 4096  # pairs per step on the CPU: the (chunk, 4, 4) temporaries stay in cache (tools/benchmark_eval.py)


def bev_intersection_area(boxes_a: torch.Tensor, boxes_b: torch.Tensor) -> torch.Tensor:
    """Row-aligned (K, 7), (K, 7) boxes -> (K,) float64 BEV intersection area [m^2], on the boxes' device."""
    a, b = boxes_a.to(torch.float64), boxes_b.to(torch.float64)
    if a.device.type == "cpu" and len(a) > _CPU_CHUNK:
        return torch.cat([_intersection_area(a[i:i + _CPU_CHUNK], b[i:i + _CPU_CHUNK])
                          for i in range(0, len(a), _CPU_CHUNK)])
    return _intersection_area(a, b)


def _intersection_area(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """bev_intersection_area of float64 (K, 7) pairs in one vectorised step."""
    centre = (a[:, :2] + b[:, :2]) / 2.0
    scale = torch.cat([a[:, 3:5], b[:, 3:5]], dim=1).amax(dim=1)
    degenerate = (a[:, 3:5].amin(dim=1) <= 0) | (b[:, 3:5].amin(dim=1) <= 0)
    # Degenerate pairs are replaced by unit boxes to keep every step finite; their area is set to 0 below.
    unit = torch.tensor([0, 0, 0, 1, 1, 1, 0], dtype=a.dtype, device=a.device)
    a = torch.where(degenerate[:, None], unit, a)
    b = torch.where(degenerate[:, None], unit, b)
    scale = torch.where(degenerate, torch.ones_like(scale), scale)
    poly_a, poly_b = _footprints(a, centre, scale), _footprints(b, centre, scale)
    area = _polygon_intersection_area(poly_a, poly_b)
    area = torch.minimum(area.clamp(min=0.0) * scale**2, torch.minimum(a[:, 3] * a[:, 4], b[:, 3] * b[:, 4]))
    return torch.where(degenerate, torch.zeros_like(area), area)


def _ratio(intersection: torch.Tensor, size_a: torch.Tensor, size_b: torch.Tensor) -> torch.Tensor:
    """intersection / union clamped to [0, 1]; 0 where the union is empty."""
    union = size_a + size_b - intersection
    positive = union > 0
    iou = intersection / torch.where(positive, union, torch.ones_like(union))
    return torch.where(positive, iou.clamp(0.0, 1.0), torch.zeros_like(iou))


def aligned_iou_torch(boxes_a: torch.Tensor, boxes_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Row-aligned (K, 7), (K, 7) torch boxes -> (BEV IoU (K,), 3D IoU (K,)) float64 on the boxes' device."""
    a, b = boxes_a.to(torch.float64), boxes_b.to(torch.float64)
    area = bev_intersection_area(a, b)
    iou_bev = _ratio(area, a[:, 3] * a[:, 4], b[:, 3] * b[:, 4])
    top = torch.minimum(a[:, 2] + a[:, 5] / 2, b[:, 2] + b[:, 5] / 2)
    bottom = torch.maximum(a[:, 2] - a[:, 5] / 2, b[:, 2] - b[:, 5] / 2)
    volume = area * (top - bottom).clamp(min=0.0)
    iou_3d = _ratio(volume, a[:, 3] * a[:, 4] * a[:, 5], b[:, 3] * b[:, 4] * b[:, 5])
    return iou_bev, iou_3d


def aligned_iou(boxes_a, boxes_b) -> tuple[np.ndarray, np.ndarray]:
    """Row-aligned numpy (K, 7), (K, 7) boxes -> (BEV IoU (K,), 3D IoU (K,)) float64."""
    a, b = check_boxes(boxes_a, "boxes_a"), check_boxes(boxes_b, "boxes_b")
    if len(a) != len(b):
        raise ValueError(f"aligned_iou: {len(a)} boxes_a rows but {len(b)} boxes_b rows")
    iou_bev, iou_3d = aligned_iou_torch(torch.from_numpy(a), torch.from_numpy(b))
    return iou_bev.numpy(), iou_3d.numpy()


def circles_overlap(boxes_a, boxes_b):
    """Row-aligned prefilter: (K,) bool, False where the BEV circumscribed circles are apart (IoU surely 0).

    numpy arrays or torch tensors (K, 7).
    """
    lib = torch if isinstance(boxes_a, torch.Tensor) else np
    radius_a = lib.hypot(boxes_a[:, 3], boxes_a[:, 4]) / 2
    radius_b = lib.hypot(boxes_b[:, 3], boxes_b[:, 4]) / 2
    distance = lib.hypot(boxes_a[:, 0] - boxes_b[:, 0], boxes_a[:, 1] - boxes_b[:, 1])
    return distance <= radius_a + radius_b


def near_pairs(boxes_a: torch.Tensor, boxes_b: torch.Tensor, chunk: int = 1024) -> tuple[torch.Tensor, torch.Tensor]:
    """Index pairs (rows into a, cols into b), row-major, whose BEV circumscribed circles overlap.

    (N, 7), (M, 7) torch boxes; memory stays O(chunk x M) instead of O(N x M).
    """
    a, b = boxes_a.to(torch.float64), boxes_b.to(torch.float64)
    radius_b = torch.hypot(b[:, 3], b[:, 4]) / 2
    rows, cols = [], []
    for begin in range(0, len(a), chunk):
        part = a[begin:begin + chunk]
        distance = torch.cdist(part[:, :2], b[:, :2], compute_mode="donot_use_mm_for_euclid_dist")
        near = distance <= (torch.hypot(part[:, 3], part[:, 4]) / 2)[:, None] + radius_b[None]
        row, col = near.nonzero(as_tuple=True)
        rows.append(row + begin)
        cols.append(col)
    if not rows:
        empty = torch.zeros(0, dtype=torch.long, device=a.device)
        return empty, empty
    return torch.cat(rows), torch.cat(cols)


def _iou_matrix(boxes_a, boxes_b, kind: int) -> np.ndarray:
    """(N, M) IoU, computed exactly only for pairs that pass the circle prefilter; kind 0 = BEV, 1 = 3D."""
    a = torch.from_numpy(check_boxes(boxes_a, "boxes_a"))
    b = torch.from_numpy(check_boxes(boxes_b, "boxes_b"))
    rows, cols = near_pairs(a, b)
    iou = torch.zeros((len(a), len(b)), dtype=torch.float64)
    iou[rows, cols] = aligned_iou_torch(a[rows], b[cols])[kind]
    return iou.numpy()


def boxes_iou_bev(boxes_a, boxes_b) -> np.ndarray:
    """(N, 7), (M, 7) LiDAR boxes -> (N, M) float64 rotated bird's-eye-view IoU in [0, 1]."""
    return _iou_matrix(boxes_a, boxes_b, 0)


def boxes_iou3d(boxes_a, boxes_b) -> np.ndarray:
    """(N, 7), (M, 7) LiDAR boxes -> (N, M) float64 rotated 3D IoU in [0, 1]."""
    return _iou_matrix(boxes_a, boxes_b, 1)
