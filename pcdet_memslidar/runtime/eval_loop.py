"""The evaluation loop: inference over a split, per-frame predictions, the dataset's AP, ms/frame."""
from __future__ import annotations

import copy
import logging
import pickle
import time
from pathlib import Path

import torch

from pcdet_memslidar.datasets.dataset import iterate_batches
from pcdet_memslidar.models import load_data_to_device
from pcdet_memslidar.runtime.common import threads_giving_way
from pcdet_memslidar.runtime.distributed import get_dist_info, merge_results_dist
from pcdet_memslidar.utils.atomic import write_bytes
from pcdet_memslidar.utils.progress import progress_bar


def eval_one_epoch(cfg, model, dataloader, epoch_id, logger: logging.Logger | None, device, dist_test: bool = False,
                   result_dir: str | Path | None = None, save_to_file: bool = False) -> dict:
    """Run `model` over `dataloader`, write result.pkl (det_annos) to `result_dir` (and, with save_to_file, KITTI
    labels with scores under prediction_folder(result_dir)), and return on rank 0 the dataset's evaluation scalars
    plus recall_rcnn_<t> and infer_time_ms (mean per frame, first batch excluded as warm-up when there are more);
    other ranks return {}."""
    logger = logger or logging.getLogger(__name__)
    rank, world_size = get_dist_info()
    dataset = dataloader.dataset
    class_names = dataset.class_names
    final_output_dir = prediction_folder(result_dir) if save_to_file and result_dir else None
    thresholds = cfg.MODEL.POST_PROCESSING.RECALL_THRESH_LIST
    recall = {"gt": 0, **{f"rcnn_{t}": 0 for t in thresholds}}
    det_annos, batch_times = [], []
    model.eval()
    logger.info(f"*************** EPOCH {epoch_id} EVALUATION *****************")
    batches = progress_bar(iterate_batches(dataloader), enabled=rank == 0, total=len(dataloader), desc="eval",
                           leave=False)
    with threads_giving_way() as give_way:  # on a CPU shared with other processes, fewer threads are faster
        for batch in batches:
            load_data_to_device(batch, device)
            if torch.device(device).type == "cpu":
                give_way()
            start = time.perf_counter()
            with torch.no_grad():
                pred_dicts, recall_dict = model(batch)
            if torch.device(device).type == "cuda":
                torch.cuda.synchronize(device)
            batch_times.append(((time.perf_counter() - start) * 1000.0, batch["batch_size"]))
            for key in recall:
                recall[key] += recall_dict.get(key, 0)
            det_annos += dataset.generate_prediction_dicts(batch, pred_dicts, class_names,
                                                           output_path=final_output_dir)
    timed = batch_times[1:] if len(batch_times) > 1 else batch_times
    infer_time_ms = sum(t for t, _ in timed) / max(1, sum(n for _, n in timed))
    if dist_test:
        det_annos = merge_results_dist(det_annos, len(dataset))
        counts = torch.tensor([recall[key] for key in recall], dtype=torch.float64)
        torch.distributed.all_reduce(counts)
        recall = dict(zip(recall, counts.tolist()))
    logger.info(f"Inference time: {infer_time_ms:.1f} ms/frame ({torch.get_num_threads()} torch threads, "
                f"device {torch.device(device)}, {world_size} process(es))")
    if rank != 0:
        return {}
    ret_dict = {"infer_time_ms": infer_time_ms}
    for threshold in thresholds:
        value = recall[f"rcnn_{threshold}"] / max(recall["gt"], 1)
        ret_dict[f"recall/rcnn_{threshold}"] = value
        logger.info(f"recall_rcnn_{threshold}: {value:.4f}")
    if result_dir is not None:
        write_bytes(Path(result_dir) / "result.pkl", pickle.dumps(det_annos))
    num_boxes = sum(len(anno["name"]) for anno in det_annos)
    logger.info(f"Average predicted number of objects ({len(det_annos)} samples): "
                f"{num_boxes / max(1, len(det_annos)):.3f}")
    result_str, result_dict = dataset.evaluation(det_annos, class_names,
                                                 eval_metric=cfg.MODEL.POST_PROCESSING.get("EVAL_METRIC", "kitti"),
                                                 output_path=final_output_dir)
    logger.info(result_str)
    ret_dict.update(result_dict)
    logger.info("****************Evaluation done.*****************")
    return ret_dict


def prediction_folder(result_dir: str | Path) -> Path:
    """Where eval_one_epoch(save_to_file=True) writes KITTI labels with scores: <folder>/<source>/<frame id>.txt."""
    return Path(result_dir) / "final_result" / "data"


def split_config(cfg, split: str):
    """A copy of cfg whose evaluation split (DATA_CONFIG.DATA_SPLIT.test) is `split` ('val': the 30 % of the mix)."""
    cfg = copy.deepcopy(cfg)
    cfg.DATA_CONFIG.DATA_SPLIT.test = split
    return cfg
