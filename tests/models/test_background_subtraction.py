"""The classical detector: foreground clusters, the person-size filter, the box and its score, settings refused
with the key, and the same detector through build_network and a batch."""
import numpy as np
import pytest
import torch
from easydict import EasyDict
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network, is_learned
from pcdet_memslidar.models.background_subtraction import (
    SETTINGS,
    clusters,
    detect_people,
    person_clusters,
    settings_of,
)


def column(x: float, y: float, top: float, count: int, width: float = 0.3) -> np.ndarray:
    """(count, 3) points on a vertical line pattern around (x, y), from 0.1 m up to `top` [m]."""
    t = np.linspace(0.0, 1.0, count)
    return np.stack([x + width * (t - 0.5), y + 0.2 * np.sin(7 * t), 0.1 + (top - 0.1) * t], axis=1)


def test_points_closer_than_the_radius_join_one_cluster_and_chains_join_too():
    xy = np.array([[0.0, 0.0], [0.2, 0.0], [0.4, 0.0], [1.0, 0.0], [5.0, 5.0]])
    assert clusters(xy, 0.25).tolist() == [0, 0, 0, 1, 2]
    assert clusters(np.array([[0.0, 0.0], [0.5, 0.0], [0.75, 0.0]]), 0.25).tolist() == [0, 1, 1]  # 0.25 apart: join
    assert clusters(np.zeros((0, 2)), 0.25).tolist() == []


def test_clusters_are_scipys_connected_components_of_the_same_pairs():
    """The compiled union-find numbers clusters as scipy's connected_components does (by their first point), on
    random clouds with points on a 0.05 m lattice (many pairs exactly at the radius) and without."""
    rng = np.random.default_rng(0)
    for trial in range(60):
        xy = rng.uniform(0, rng.uniform(0.5, 8), (int(rng.integers(1, 300)), 2))
        xy = np.round(xy * 20) / 20 if trial % 2 else xy
        for radius in (0.05, 0.1, 0.25):
            pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")
            graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy), len(xy)))
            np.testing.assert_array_equal(clusters(xy, radius), connected_components(graph, directed=False)[1])


def test_a_person_sized_cluster_gives_one_box_from_the_floor_to_its_top_and_the_score_of_its_count():
    person = column(4.0, 1.0, 1.75, 24)
    boxes, scores = person_clusters(person, SETTINGS)
    assert boxes.shape == (1, 7)
    np.testing.assert_allclose(boxes[0], [*person[:, :2].mean(axis=0), 0.875, 0.8, 0.6, 1.75, 0.0])
    assert scores.tolist() == [24 / (24 + 8)]


@pytest.mark.parametrize("points", [column(4.0, 1.0, 1.75, 5),  # too few points
                                    column(4.0, 1.0, 0.5, 24),  # too low: a box on the floor
                                    column(4.0, 1.0, 2.6, 24),  # too tall
                                    column(4.0, 1.0, 1.75, 60, width=2.0)])  # too long: a cart, a forklift
def test_clusters_that_no_person_makes_are_dropped(points):
    boxes, scores = person_clusters(points, SETTINGS)
    assert boxes.shape == (0, 7) and scores.shape == (0,)


def test_background_points_are_never_clustered():
    person = column(4.0, 1.0, 1.75, 24)
    depth = np.r_[np.zeros(12), np.full(12, 0.8)]
    boxes, _ = detect_people(person, depth, SETTINGS, None)
    assert boxes.shape == (1, 7)
    np.testing.assert_allclose(boxes[0, :2], person[12:, :2].mean(axis=0))
    assert detect_people(person, np.zeros(24), SETTINGS, None)[0].shape == (0, 7)


@pytest.mark.parametrize("block, key", [({"RADIUS": 0.2}, "unknown keys"), ({"MIN_POINTS": 1}, "MIN_POINTS >= 2"),
                                        ({"HEIGHT_RANGE": [2.0, 1.0]}, "HEIGHT_RANGE")])
def test_bad_settings_are_refused_naming_the_key(block, key):
    with pytest.raises(ConfigError, match=key):
        settings_of(EasyDict({"BACKGROUND_SUBTRACTION": block}))


class _Dataset:
    class point_feature_encoder:  # noqa: N801 - the attribute a detector reads
        used_feature_list = ["x", "y", "z", "intensity", "background_depth"]


def test_built_by_name_it_detects_per_frame_of_a_batch_and_has_nothing_to_train():
    model_cfg = EasyDict({"NAME": "BackgroundSubtraction", "POST_PROCESSING": {}})
    model = build_network(model_cfg, 1, _Dataset()).eval()
    assert not is_learned(model_cfg) and not list(model.parameters())
    person = column(4.0, 1.0, 1.75, 24)
    rows = [np.c_[np.full(24, frame), person + [frame, 0, 0], np.zeros(24), np.full(24, 0.8)] for frame in (0, 1)]
    pred_dicts, _ = model({"points": torch.tensor(np.concatenate(rows), dtype=torch.float32), "batch_size": 2})
    assert [len(pred["pred_boxes"]) for pred in pred_dicts] == [1, 1]
    assert pred_dicts[1]["pred_boxes"][0, 0] - pred_dicts[0]["pred_boxes"][0, 0] == pytest.approx(1.0, abs=1e-6)
    assert pred_dicts[0]["pred_labels"].tolist() == [1]
    with pytest.raises(ConfigError, match="nothing to train"):
        model.train()({"points": torch.zeros((0, 6)), "batch_size": 1})


def test_a_config_without_the_background_feature_is_refused():
    class NoFeature:
        class point_feature_encoder:  # noqa: N801
            used_feature_list = ["x", "y", "z", "intensity"]
    with pytest.raises(ConfigError, match="background_depth"):
        build_network(EasyDict({"NAME": "BackgroundSubtraction", "POST_PROCESSING": {}}), 1, NoFeature())
