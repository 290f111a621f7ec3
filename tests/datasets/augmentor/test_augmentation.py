"""Augmentations keep points inside their boxes; gt_sampling pastes same-domain people without overlaps."""
import pickle

import numpy as np
import pytest
from easydict import EasyDict

from pcdet_memslidar.datasets.augmentor import DataAugmentor, DataBaseSampler, GtDatabase, augmentor_utils
from pcdet_memslidar.datasets.infos import DBINFO_FILE
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.geometry.iou import boxes_iou_bev


@pytest.mark.parametrize("augment", [
    lambda b, p, rng: augmentor_utils.random_flip_along_x(b, p, rng, probability=1.0),
    lambda b, p, rng: augmentor_utils.global_rotation(b, p, [-0.785, 0.785], rng),
    lambda b, p, rng: augmentor_utils.global_scaling(b, p, [0.95, 1.05], rng),
], ids=["flip", "rotation", "scaling"])
def test_augmented_boxes_still_contain_their_points(augment, make_people_frame, intensity_bands):
    points, boxes = make_people_frame(np.random.default_rng(0), 4, intensity_bands["sim"])
    before = points_in_boxes_mask(points, boxes)
    assert before.sum() > 100
    new_boxes, new_points = augment(boxes, points, np.random.default_rng(5))
    assert not np.allclose(new_points[:, :3], points[:, :3])
    assert new_points.dtype == np.float32 and new_points.shape == points.shape
    np.testing.assert_array_equal(new_points[:, 3], points[:, 3])
    np.testing.assert_array_equal(points_in_boxes_mask(new_points, new_boxes), before)


def test_flip_mirrors_y_and_heading_exactly():
    boxes = np.array([[10.0, 2.0, 0.9, 0.8, 0.6, 1.8, 0.3]])
    points = np.array([[10.0, 2.0, 0.5, 7.0]], dtype=np.float32)
    new_boxes, new_points = augmentor_utils.random_flip_along_x(boxes, points, np.random.default_rng(0), 1.0)
    np.testing.assert_allclose(new_boxes, [[10.0, -2.0, 0.9, 0.8, 0.6, 1.8, -0.3]])
    np.testing.assert_allclose(new_points, [[10.0, -2.0, 0.5, 7.0]])


def test_unknown_augmentation_and_flip_axis_are_config_errors():
    with pytest.raises(ConfigError, match="unknown augmentation 'random_world_jitter'"):
        DataAugmentor(EasyDict(AUG_CONFIG_LIST=[{"NAME": "random_world_jitter"}]), ["Pedestrian"])
    with pytest.raises(ConfigError, match="ALONG_AXIS_LIST"):
        DataAugmentor(EasyDict(AUG_CONFIG_LIST=[{"NAME": "random_world_flip", "ALONG_AXIS_LIST": ["x", "y"]}]),
                      ["Pedestrian"])


def _sampler(memslidar_data, groups="Pedestrian:12"):
    config = EasyDict(NAME="gt_sampling", PREPARE={"filter_by_min_points": ["Pedestrian:5"]},
                      SAMPLE_GROUPS=[groups], NUM_POINT_FEATURES=4, REMOVE_EXTRA_WIDTH=[0.0, 0.0, 0.0],
                      LIMIT_WHOLE_SCENE=True)
    databases = {name: GtDatabase(memslidar_data / name,
                                  pickle.loads((memslidar_data / name / DBINFO_FILE).read_bytes()))
                 for name in ("sim", "real")}
    return DataBaseSampler(config, ["Pedestrian"], databases)


def test_gt_sampling_adds_same_domain_people_without_overlaps(memslidar_data, make_people_frame, intensity_bands):
    sampler = _sampler(memslidar_data)
    rng = np.random.default_rng(0)
    added = 0
    for seed in range(20):
        points, boxes = make_people_frame(np.random.default_rng(100 + seed), 3, intensity_bands["real"])
        data = sampler({"points": points, "gt_boxes": boxes.astype(np.float32),
                        "gt_names": np.array(["Pedestrian"] * 3),
                        "gt_boxes_mask": np.ones(3, dtype=bool), "metadata": {"source": "real"}}, rng)
        new_boxes = data["gt_boxes"]
        assert len(new_boxes) <= 12 and len(data["gt_names"]) == len(new_boxes) == len(data["gt_boxes_mask"])
        iou = boxes_iou_bev(new_boxes, new_boxes)
        np.fill_diagonal(iou, 0.0)
        assert iou.max() == 0.0
        pasted = points_in_boxes_mask(data["points"], new_boxes[3:]).any(axis=1)
        low, high = intensity_bands["real"]
        assert ((data["points"][pasted, 3] >= low) & (data["points"][pasted, 3] <= high)).all()
        added += len(new_boxes) - 3
    assert added > 20


def test_gt_sampling_without_database_for_the_source_says_what_to_run(memslidar_data):
    with pytest.raises(ConfigError, match="create-infos"):
        _sampler(memslidar_data)({"points": np.zeros((0, 4), np.float32), "gt_boxes": np.zeros((0, 7)),
                                  "gt_names": np.zeros(0, str), "gt_boxes_mask": np.zeros(0, bool),
                                  "metadata": {"source": "industrial"}}, np.random.default_rng(0))
