"""The classical detector's settings for one site (models.background_subtraction), chosen as a site engineer would:
a small grid of its few settings, each scored by AP 3D R40 on the validation part of the site's composited training
frames (never on held-out frames); the best goes into the site's config, every trial into its results."""
from __future__ import annotations

import copy
import itertools
import warnings

import numpy as np

from pcdet_memslidar.datasets.memslidar_dataset import MEMSLidarDataset
from pcdet_memslidar.datasets.processor.data_processor import mask_points_by_range
from pcdet_memslidar.evaluation.metrics import evaluate
from pcdet_memslidar.models.background_subtraction import SETTINGS, clusters, detect_people
from pcdet_memslidar.models.post_processing import box_from_points
from pcdet_memslidar.utils.progress import progress_bar

# BOX_SIZE: a person box of the anchor's footprint, and one of the mean labelled footprint of the composited people
GRID = {"CLUSTER_RADIUS": (0.1, 0.15, 0.25), "MIN_POINTS": (3, 5, 10), "HEIGHT_RANGE": ([0.5, 2.3], [0.9, 2.3]),
        "BOX_SIZE": ([0.8, 0.6], [0.67, 0.53])}
MAX_FRAMES = 150  # validation frames scored per trial (the first of the split)


def choose_settings(cfg, logger) -> tuple[dict, list[dict]]:
    """(the best MODEL.BACKGROUND_SUBTRACTION of GRID on cfg's validation split, [{settings, AP3D_R40}] of every
    trial); cfg: a config whose POINT_FEATURE_ENCODING has background_depth (the site's background)."""
    data_cfg = copy.deepcopy(cfg.DATA_CONFIG)
    data_cfg.DATA_SPLIT = {"train": "train", "test": "val"}
    dataset = MEMSLidarDataset(data_cfg, cfg.CLASS_NAMES, training=False, logger=logger)
    count = min(len(dataset), MAX_FRAMES)
    column = dataset.point_feature_encoder.src_feature_list.index("background_depth")
    limits = np.asarray(cfg.DATA_CONFIG.POINT_CLOUD_RANGE)
    frames = []  # (points (N, 3+) float64, background_depth (N,), times (N,) or None) inside the grid
    for index in range(count):
        frame = dataset.get_frame(index)
        inside = mask_points_by_range(frame["points"], limits)
        times = frame.get("point_times")
        frames.append((frame["points"][inside].astype(np.float64), frame["points"][inside, column],
                       None if times is None else times[inside]))
    box_step = box_from_points(cfg.MODEL.POST_PROCESSING)
    gt_annos = dataset.gt_annos()[:count]
    trials, labels = [], {}  # labels: (frame, radius) -> its foreground points' clusters, shared by the trials
    combinations = list(itertools.product(*GRID.values()))
    for values in progress_bar(combinations, desc="classical detector settings", unit="trial"):
        settings = {**SETTINGS, **dict(zip(GRID, values))}
        dt_annos = []
        for index, (points, depth, times) in enumerate(frames):
            key = (index, settings["CLUSTER_RADIUS"])
            if key not in labels:
                labels[key] = clusters(points[depth > 0, :2], settings["CLUSTER_RADIUS"])
            boxes, scores = detect_people(points, depth, settings, box_step, times, labels[key])
            dt_annos.append({"name": np.full(len(boxes), cfg.CLASS_NAMES[0]), "score": scores, "boxes_lidar": boxes})
        with warnings.catch_warnings():  # a distance bin without people: its AP is NaN, the one used is not
            warnings.filterwarnings("ignore", message="no ground-truth")
            ap = float(evaluate(gt_annos, dt_annos, class_name=cfg.CLASS_NAMES[0])["AP3D_R40"])
        trials.append({"settings": settings, "AP3D_R40": ap})
    best = max(trials, key=lambda trial: trial["AP3D_R40"])
    logger.info(f"classical detector: {best['settings']} (validation AP 3D R40 {best['AP3D_R40']:.4f} on {count} "
                f"frames; {len(trials)} trials)")
    return best["settings"], trials
