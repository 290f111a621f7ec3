"""Fixtures of the model tests: the person SECOND's full range and the dataset attributes build_network reads."""
from types import SimpleNamespace

import numpy as np
import pytest


@pytest.fixture(scope="session")
def person_range() -> list[float]:
    """The person SECOND's point cloud range: 512 x 512 x 40 voxels of person_voxel."""
    return [0.0, -20.48, -0.5, 40.96, 20.48, 3.5]


@pytest.fixture(scope="session")
def fake_dataset(person_range, person_voxel):
    """fake_dataset(point_cloud_range=person_range, voxel_size=person_voxel, class_names=("Pedestrian",)) -> the
    attributes build_network reads from an OpenPCDet dataset."""
    def dataset(point_cloud_range=person_range, voxel_size=person_voxel, class_names=("Pedestrian",)):
        return SimpleNamespace(point_feature_encoder=SimpleNamespace(num_point_features=4),
                               point_cloud_range=np.asarray(point_cloud_range, dtype=np.float32),
                               voxel_size=list(voxel_size), class_names=list(class_names), depth_downsample_factor=None)
    return dataset
