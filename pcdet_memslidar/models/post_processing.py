"""Scores and boxes per anchor -> final detections: implausible sizes dropped, score threshold, top-k,
class-agnostic rotated NMS; optionally each box's centre and heading from its points (BOX_FROM_POINTS, our key)."""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.box_from_points import fit_boxes_to_points
from pcdet_memslidar.geometry.iou import boxes_iou3d
from pcdet_memslidar.geometry.nms import nms_rotated


def size_limits(anchor_configs, class_names, ratio_range) -> torch.Tensor:
    """(C, 2, 3) smallest and largest [dx, dy, dz] [m] a box of each class may have: its anchor sizes times
    ratio_range [low, high] (POST_PROCESSING.SIZE_RATIO_RANGE); an object that is a person is never 20 x its
    anchor, and a 50 m or 2 cm box is a saturated regression, not a detection."""
    low, high = (float(v) for v in ratio_range)
    if not 0 < low <= 1 <= high:
        raise ConfigError(f"POST_PROCESSING.SIZE_RATIO_RANGE must be [low, high] with 0 < low <= 1 <= high, "
                          f"got {list(ratio_range)}")
    limits = []
    for name in class_names:
        sizes = [size for config in anchor_configs if config["class_name"] == name for size in config["anchor_sizes"]]
        sizes = torch.tensor(sizes, dtype=torch.float32).view(-1, 3)
        limits.append(torch.stack([sizes.min(dim=0).values * low, sizes.max(dim=0).values * high]))
    return torch.stack(limits)


def plausible(box_preds: torch.Tensor, labels: torch.Tensor, limits: torch.Tensor) -> torch.Tensor:
    """(A,) bool: boxes (A, 7+) whose sizes lie within their class's limits (C, 2, 3) (labels 0-based);
    NaN sizes are never plausible."""
    bounds = limits.to(box_preds.device)[labels]  # (A, 2, 3)
    sizes = box_preds[:, 3:6]
    return ((sizes >= bounds[:, 0]) & (sizes <= bounds[:, 1])).all(dim=1)


def class_agnostic_nms(box_scores: torch.Tensor, box_preds: torch.Tensor, nms_config, score_thresh=None,
                       allowed: torch.Tensor | None = None):
    """box_scores (A,), box_preds (A, 7) -> (selected indices into the inputs, their scores), best first.

    nms_config: NMS_THRESH (BEV IoU), NMS_PRE_MAXSIZE, NMS_POST_MAXSIZE as in OpenPCDet's NMS_CONFIG; allowed
    (A,) bool: the only candidates (e.g. plausible sizes).
    """
    candidates = torch.arange(len(box_scores), device=box_scores.device)
    mask = torch.ones_like(box_scores, dtype=torch.bool) if allowed is None else allowed.clone()
    if score_thresh is not None:
        mask &= box_scores >= score_thresh
    candidates = candidates[mask]
    if len(candidates) == 0:
        return candidates, box_scores[candidates]
    keep = nms_rotated(box_preds[candidates, :7], box_scores[candidates], nms_config.NMS_THRESH,
                       pre_max=nms_config.NMS_PRE_MAXSIZE, post_max=nms_config.NMS_POST_MAXSIZE)
    selected = candidates[keep]
    return selected, box_scores[selected]


def recall_record(pred_boxes: torch.Tensor, gt_boxes: torch.Tensor, thresh_list, recall_dict: dict) -> dict:
    """Add to recall_dict['gt'] the number of ground-truth boxes (M, 7+) and to recall_dict['rcnn_<t>'] those
    matched by a prediction (N, 7+) with 3D IoU > t (OpenPCDet's generate_recall_record)."""
    for threshold in thresh_list:
        recall_dict.setdefault(f"rcnn_{threshold}", 0)
    recall_dict.setdefault("gt", 0)
    valid = gt_boxes[:, :7].abs().sum(dim=1) > 0
    gt = gt_boxes[valid, :7].detach().cpu().double().numpy()
    recall_dict["gt"] += len(gt)
    if len(gt) and len(pred_boxes):
        best = boxes_iou3d(pred_boxes[:, :7].detach().cpu().double().numpy(), gt).max(axis=0)
        for threshold in thresh_list:
            recall_dict[f"rcnn_{threshold}"] += int(np.sum(best > threshold))
    return recall_dict


def post_processing(batch_dict: dict, post_process_cfg, limits: torch.Tensor | None = None) -> list[dict]:
    """batch_cls_preds (B, A, C), batch_box_preds (B, A, 7) -> per frame {pred_boxes (K, 7), pred_scores (K,),
    pred_labels (K,) 1-based}. With `limits` (C, 2, 3) (size_limits), boxes of implausible size never reach NMS."""
    if post_process_cfg.NMS_CONFIG.get("MULTI_CLASSES_NMS", False):
        raise ConfigError("POST_PROCESSING.NMS_CONFIG.MULTI_CLASSES_NMS is not supported: set it False")
    pred_dicts = []
    for index in range(batch_dict["batch_size"]):
        box_preds = batch_dict["batch_box_preds"][index]
        cls_preds = batch_dict["batch_cls_preds"][index]
        if not batch_dict["cls_preds_normalized"]:
            cls_preds = torch.sigmoid(cls_preds)
        scores, labels = cls_preds.max(dim=-1)
        allowed = None if limits is None else plausible(box_preds, labels, limits)
        selected, selected_scores = class_agnostic_nms(scores, box_preds, post_process_cfg.NMS_CONFIG,
                                                       post_process_cfg.get("SCORE_THRESH"), allowed)
        pred_dicts.append({"pred_boxes": box_preds[selected], "pred_scores": selected_scores,
                           "pred_labels": labels[selected] + 1})
    return pred_dicts


BOX_KEYS = ("ENABLED", "MIN_POINTS", "MARGIN", "MIN_HEIGHT", "CENTER_DEPTH",  # POST_PROCESSING.BOX_FROM_POINTS
            "MIN_DRIFT_SPEED")
BOX_EXAMPLE = ("{ENABLED: True, MIN_POINTS: 5, MARGIN: 0.1, MIN_HEIGHT: 0.4, CENTER_DEPTH: 0.08, "
               "MIN_DRIFT_SPEED: 0.5}")


def box_from_points(post_process_cfg) -> tuple[int, float, float, float | None, float | None] | None:
    """POST_PROCESSING.BOX_FROM_POINTS {ENABLED, MIN_POINTS, MARGIN [m], MIN_HEIGHT [m], CENTER_DEPTH [m] or None,
    MIN_DRIFT_SPEED [m/s] or None} -> (min_points, margin, min_height, center_depth, min_drift_speed)
    (geometry.box_from_points.fit_boxes_to_points), None when absent or not ENABLED; ConfigError for a missing,
    unknown or out-of-range key."""
    block = post_process_cfg.get("BOX_FROM_POINTS")
    if block is None:
        return None
    where = "POST_PROCESSING.BOX_FROM_POINTS"
    if not isinstance(block, dict) or set(block) != set(BOX_KEYS):
        raise ConfigError(f"{where} is {block!r}: write {BOX_EXAMPLE} (points inside a box grown by MARGIN m, "
                          f"MIN_HEIGHT m above its bottom or higher; the centre CENTER_DEPTH m behind their mean, or "
                          f"null to keep it; the long side along the points' drift where it is MIN_DRIFT_SPEED m/s "
                          f"or faster, or null for their main axis only; with fewer than MIN_POINTS the network's "
                          f"box stays)")
    enabled, min_points, margin, min_height, center_depth, min_drift_speed = (block[key] for key in BOX_KEYS)
    if not isinstance(enabled, bool):
        raise ConfigError(f"{where}.ENABLED is {enabled!r}: use True or False")
    if isinstance(min_points, bool) or not isinstance(min_points, int) or min_points < 2:
        raise ConfigError(f"{where}.MIN_POINTS is {min_points!r}: use an integer >= 2")
    for key, value, unit, nullable in (("MARGIN", margin, "metres", False), ("MIN_HEIGHT", min_height, "metres", False),
                                       ("CENTER_DEPTH", center_depth, "metres", True),
                                       ("MIN_DRIFT_SPEED", min_drift_speed, "metres per second", True)):
        if value is None and nullable:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 10:
            raise ConfigError(f"{where}.{key} is {value!r}: use {unit} in [0, 10){' or null' if nullable else ''}")
    if not enabled:
        return None
    return (min_points, float(margin), float(min_height), None if center_depth is None else float(center_depth),
            None if min_drift_speed is None else float(min_drift_speed))


def fit_to_points(pred_dicts: list[dict], points: torch.Tensor, min_points: int, margin: float, min_height: float,
                  center_depth: float | None, min_drift_speed: float | None = None,
                  point_times: torch.Tensor | None = None) -> None:
    """Fit each predicted box's centre and long side to its points (geometry.box_from_points), in place.
    points: (N, 1+3+C) [frame index in the batch, x, y, z, ...] as the batch's; point_times (N,) [s] or None."""
    frame_of = points[:, 0].long()
    for index, pred_dict in enumerate(pred_dicts):
        boxes = pred_dict["pred_boxes"]
        if not len(boxes):
            continue
        in_frame = frame_of == index
        own = points[in_frame, 1:4].detach().cpu().double().numpy()
        times = None if point_times is None else point_times[in_frame].detach().cpu().double().numpy()
        fitted, _ = fit_boxes_to_points(boxes.detach().cpu().double().numpy(), own, min_points, margin, min_height,
                                        center_depth, times, min_drift_speed)
        pred_dict["pred_boxes"] = torch.as_tensor(fitted, dtype=boxes.dtype, device=boxes.device)
