"""BackgroundSubtraction: the classical detector of a static site, as a site engineer or a commercial people counter
would build it, under the same interface as the learned detectors (MODEL.NAME, batch_dict in, pred_dicts out).

    points with background_depth (the site's background model, geometry.background)
    -> foreground: background_depth > 0 (nearer than the background by more than its margin)
    -> clusters in bird's-eye view: points at most CLUSTER_RADIUS [m] apart join (connected components)
    -> person-size filter: at least MIN_POINTS points, top of the cluster within HEIGHT_RANGE [m], its longest
       horizontal extent at most MAX_LENGTH [m]
    -> a box per cluster: BOX_SIZE [m] long and wide, from the floor to the cluster's top, at the cluster's mean,
       then centre and heading from the foreground points (POST_PROCESSING.BOX_FROM_POINTS, as after the learned
       heads)
    -> score n / (n + MIN_POINTS) for a cluster of n points (more points, more confidence; MIN_POINTS gives 0.5)

It has no weights: `memslidar test` and `detect` run it without --ckpt; its settings are chosen on a site's
composited validation frames (experiments.site_detector) and written into the site's config.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from pcdet_memslidar.datasets.dataset import BACKGROUND_FEATURE
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.box_from_points import fit_boxes_to_points
from pcdet_memslidar.models.post_processing import box_from_points
from pcdet_memslidar.policy import ExecutionPolicy
from pcdet_memslidar.utils.compiled import kernel

SETTINGS = {"CLUSTER_RADIUS": 0.25, "MIN_POINTS": 8, "HEIGHT_RANGE": [0.8, 2.3], "MAX_LENGTH": 1.2,
            "BOX_SIZE": [0.8, 0.6]}  # defaults of MODEL.BACKGROUND_SUBTRACTION


def settings_of(model_cfg) -> dict:
    """MODEL.BACKGROUND_SUBTRACTION merged over SETTINGS; ConfigError naming an unknown or out-of-range key."""
    given = dict(model_cfg.get("BACKGROUND_SUBTRACTION") or {})
    unknown = sorted(set(given) - set(SETTINGS))
    if unknown:
        raise ConfigError(f"MODEL.BACKGROUND_SUBTRACTION: unknown keys {unknown}; known: {', '.join(SETTINGS)}")
    settings = {**SETTINGS, **given}
    low, high = settings["HEIGHT_RANGE"]
    if not (0 < settings["CLUSTER_RADIUS"] < 5 and int(settings["MIN_POINTS"]) >= 2 and 0 <= low < high
            and settings["MAX_LENGTH"] > 0 and min(settings["BOX_SIZE"]) > 0):
        raise ConfigError(f"MODEL.BACKGROUND_SUBTRACTION {settings}: need 0 < CLUSTER_RADIUS < 5 m, MIN_POINTS >= 2, "
                          f"HEIGHT_RANGE [low, high] with 0 <= low < high m, MAX_LENGTH > 0 m, BOX_SIZE > 0 m")
    return settings


def clusters(xy: np.ndarray, radius: float) -> np.ndarray:
    """(N,) cluster index of (N, 2) points [m]: points at most `radius` [m] apart share one (connected components),
    numbered in the order of each cluster's first point."""
    return _components(len(xy), cKDTree(xy).query_pairs(radius, output_type="ndarray"))


@kernel
def _components(count: int, pairs: np.ndarray) -> np.ndarray:
    """(count,) component of each node of the undirected graph with the edges `pairs` (P, 2), numbered in the order
    of each component's first node: union-find, every set rooted at its smallest node."""
    parent = np.arange(count)
    for k in range(len(pairs)):
        a, b = _root(parent, pairs[k, 0]), _root(parent, pairs[k, 1])
        parent[max(a, b)] = min(a, b)
    label = np.empty(count, np.int64)
    found = 0
    for node in range(count):  # a root comes before the rest of its set
        root = _root(parent, node)
        if root == node:
            label[node] = found
            found += 1
        else:
            label[node] = label[root]
    return label


@kernel(inline="always")
def _root(parent: np.ndarray, node: int) -> int:
    """The root of `node`'s set in the forest `parent`, halving the path on the way."""
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


def person_clusters(points: np.ndarray, settings: dict, label: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Foreground points (N, 3+) [m] -> (boxes (K, 7) before the box step, scores (K,)) of the clusters that pass
    the person-size filter (module docstring); label: the points' clusters at CLUSTER_RADIUS where known."""
    boxes, scores = [], []
    if len(points):
        label = clusters(points[:, :2], settings["CLUSTER_RADIUS"]) if label is None else label
        for index in np.flatnonzero(np.bincount(label) >= settings["MIN_POINTS"]):
            own = points[label == index, :3]
            top, extent = own[:, 2].max(), np.ptp(own[:, :2], axis=0)
            low, high = settings["HEIGHT_RANGE"]
            if not low <= top <= high or np.hypot(*extent) > settings["MAX_LENGTH"]:
                continue
            length, width = settings["BOX_SIZE"]
            boxes.append([*own[:, :2].mean(axis=0), top / 2, length, width, top, 0.0])
            scores.append(len(own) / (len(own) + settings["MIN_POINTS"]))
    return np.array(boxes, dtype=np.float64).reshape(-1, 7), np.array(scores, dtype=np.float64)


def detect_people(points: np.ndarray, depth: np.ndarray, settings: dict, box_step: tuple | None,
                  times: np.ndarray | None = None, label: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One frame: points (N, 3+) [m] and their background_depth (N,) [m] (and time offsets (N,) [s] or None) ->
    (boxes (K, 7), scores (K,)); box_step: post_processing.box_from_points' settings (None: boxes as clustered),
    applied to the foreground points only (the background around a person is known, unlike after a network);
    label: the foreground points' clusters at CLUSTER_RADIUS where known (None: found here)."""
    foreground = depth > 0
    boxes, scores = person_clusters(points[foreground], settings, label)
    if box_step is not None and len(boxes):
        min_points, margin, min_height, center_depth, min_drift_speed = box_step
        boxes, _ = fit_boxes_to_points(boxes, points[foreground], min_points, margin, min_height, center_depth,
                                       None if times is None else times[foreground], min_drift_speed)
    return boxes, scores


class BackgroundSubtraction(nn.Module):
    """The module docstring's detector; eval only (it has nothing to train)."""

    display_name = "BackgroundSubtraction"
    learned = False  # no weights: no training, no checkpoint

    def __init__(self, model_cfg, num_class: int, dataset):
        super().__init__()
        features = dataset.point_feature_encoder.used_feature_list
        if BACKGROUND_FEATURE not in features:
            raise ConfigError(f"MODEL.NAME BackgroundSubtraction needs the point feature {BACKGROUND_FEATURE}: add it "
                              f"to POINT_FEATURE_ENCODING.used_feature_list and src_feature_list, with "
                              f"DATA_CONFIG.BACKGROUND_MODEL")
        self.model_cfg, self.settings = model_cfg, settings_of(model_cfg)
        self.column = 1 + features.index(BACKGROUND_FEATURE)  # batch points: [frame, x, y, z, ...]
        self.box_from_points = box_from_points(model_cfg.POST_PROCESSING)
        self.register_buffer("global_step", torch.LongTensor(1).zero_())

    def set_policy(self, policy: ExecutionPolicy) -> None:
        """Nothing to set: no network."""

    def set_precision(self, precision: str, training: bool = False) -> None:
        """Nothing to set: no network."""

    def forward(self, batch_dict: dict) -> tuple[list[dict], dict]:
        if self.training:
            raise ConfigError("MODEL.NAME BackgroundSubtraction has nothing to train: run `memslidar test` or "
                              "`memslidar detect` with its config")
        points = batch_dict["points"].detach().cpu().double().numpy()
        times = batch_dict.get("point_times")
        times = None if times is None else times.detach().cpu().double().numpy()
        pred_dicts, device = [], batch_dict["points"].device
        for index in range(int(batch_dict["batch_size"])):
            own = points[:, 0] == index
            boxes, scores = detect_people(points[own, 1:4], points[own, self.column], self.settings,
                                          self.box_from_points, None if times is None else times[own])
            pred_dicts.append({"pred_boxes": torch.as_tensor(boxes, dtype=torch.float32, device=device),
                               "pred_scores": torch.as_tensor(scores, dtype=torch.float32, device=device),
                               "pred_labels": torch.ones(len(boxes), dtype=torch.long, device=device)})
        return pred_dicts, {}
