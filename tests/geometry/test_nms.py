"""Rotated NMS against a brute-force reference built on shapely polygons."""
import numpy as np
import pytest
import torch
from shapely.geometry import Polygon

from pcdet_memslidar.geometry.boxes import boxes_to_corners_3d
from pcdet_memslidar.geometry.nms import nms_rotated


def brute_force_nms(boxes, scores, threshold, pre_max=None, post_max=None):
    order = sorted(range(len(scores)), key=lambda i: -scores[i])[:pre_max]
    footprints = [Polygon(c) for c in boxes_to_corners_3d(boxes)[:, :4, :2]]
    kept = []
    for i in order:
        ious = [footprints[i].intersection(footprints[j]).area
                / (footprints[i].area + footprints[j].area - footprints[i].intersection(footprints[j]).area)
                for j in kept]
        if all(iou <= threshold for iou in ious):
            kept.append(i)
    return kept[:post_max]


def clustered_boxes(rng, count):
    centres = rng.uniform(-5, 5, (count // 10, 2))
    xy = centres[rng.integers(0, len(centres), count)] + rng.normal(0, 0.15, (count, 2))
    return np.column_stack([xy, rng.uniform(0.8, 1.0, count), rng.uniform(0.4, 0.9, (count, 2)),
                            rng.uniform(1.5, 1.9, count), rng.uniform(-np.pi, np.pi, count)])


@pytest.mark.parametrize("threshold, pre_max, post_max", [(0.1, None, None), (0.01, 150, 20), (0.5, None, 7)])
def test_matches_brute_force(threshold, pre_max, post_max):
    rng = np.random.default_rng(int(threshold * 100))
    boxes, scores = clustered_boxes(rng, 200), rng.permutation(200) / 200.0
    kept = nms_rotated(torch.from_numpy(boxes).float(), torch.from_numpy(scores).float(), threshold, pre_max, post_max)
    assert kept.dtype == torch.long
    expected = brute_force_nms(boxes.astype(np.float32).astype(np.float64), scores, threshold, pre_max, post_max)
    assert kept.tolist() == expected
    assert 1 < len(expected) < 200


def test_identical_boxes_keep_only_the_best_and_empty_input():
    boxes = torch.tensor([[1.0, 2.0, 0.9, 0.6, 0.5, 1.8, 0.4]]).repeat(5, 1)
    assert nms_rotated(boxes, torch.tensor([0.1, 0.9, 0.3, 0.9, 0.2]), 0.5).tolist() == [1]
    assert nms_rotated(torch.zeros((0, 7)), torch.zeros(0), 0.5).tolist() == []


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_gpu_matches_cpu():
    rng = np.random.default_rng(7)
    boxes, scores = torch.from_numpy(clustered_boxes(rng, 2000)), torch.from_numpy(rng.uniform(size=2000))
    kept_gpu = nms_rotated(boxes.cuda(), scores.cuda(), 0.1)
    assert kept_gpu.device.type == "cuda"
    assert kept_gpu.cpu().tolist() == nms_rotated(boxes, scores, 0.1).tolist()
