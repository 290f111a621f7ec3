"""Scores and boxes per anchor -> final detections: score threshold, top-k, class-agnostic rotated NMS."""
from __future__ import annotations

import numpy as np
import torch

from pcdet_memslidar.geometry.iou import boxes_iou3d
from pcdet_memslidar.geometry.nms import nms_rotated


def class_agnostic_nms(box_scores: torch.Tensor, box_preds: torch.Tensor, nms_config, score_thresh=None):
    """box_scores (A,), box_preds (A, 7) -> (selected indices into the inputs, their scores), best first.

    nms_config: NMS_THRESH (BEV IoU), NMS_PRE_MAXSIZE, NMS_POST_MAXSIZE as in OpenPCDet's NMS_CONFIG.
    """
    candidates = torch.arange(len(box_scores), device=box_scores.device)
    if score_thresh is not None:
        candidates = candidates[box_scores >= score_thresh]
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


def post_processing(batch_dict: dict, post_process_cfg) -> tuple[list[dict], dict]:
    """batch_cls_preds (B, A, C), batch_box_preds (B, A, 7) -> per frame {pred_boxes (K, 7), pred_scores (K,),
    pred_labels (K,) 1-based}, and the recall record when gt_boxes are in the batch."""
    if post_process_cfg.NMS_CONFIG.get("MULTI_CLASSES_NMS", False):
        raise ValueError("POST_PROCESSING.NMS_CONFIG.MULTI_CLASSES_NMS is not supported: set it False")
    pred_dicts, recall_dict = [], {}
    for index in range(batch_dict["batch_size"]):
        box_preds = batch_dict["batch_box_preds"][index]
        cls_preds = batch_dict["batch_cls_preds"][index]
        if not batch_dict["cls_preds_normalized"]:
            cls_preds = torch.sigmoid(cls_preds)
        scores, labels = cls_preds.max(dim=-1)
        selected, selected_scores = class_agnostic_nms(scores, box_preds, post_process_cfg.NMS_CONFIG,
                                                       post_process_cfg.get("SCORE_THRESH"))
        final_boxes = box_preds[selected]
        if "gt_boxes" in batch_dict:
            recall_record(final_boxes, batch_dict["gt_boxes"][index], post_process_cfg.RECALL_THRESH_LIST,
                          recall_dict)
        pred_dicts.append({"pred_boxes": final_boxes, "pred_scores": selected_scores,
                           "pred_labels": labels[selected] + 1})
    return pred_dicts, recall_dict
