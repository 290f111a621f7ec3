"""Fixtures of the model tests: the person SECOND's full range and the dataset attributes build_network reads."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pcdet_memslidar.models import load_data_to_device
from pcdet_memslidar.runtime.optimization import build_optimizer, build_scheduler
from pcdet_memslidar.runtime.train_loop import train_model


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


@pytest.fixture(scope="session")
def overfit(small_optim_cfg):
    """overfit(model, dataset, epochs, out_dir) -> the model trained on `dataset` (batches of 4, in order) for
    `epochs` with small_optim_cfg, its BatchNorm statistics then recomputed on the final weights (momentum 0.01
    needs thousands of steps to settle); returns the loader of single frames for eval_one_epoch."""
    def train(model, dataset, epochs: int, out_dir):
        optim_cfg = small_optim_cfg()
        loader = DataLoader(dataset, batch_size=4, shuffle=False, collate_fn=dataset.collate_batch)
        optimizer = build_optimizer(model, optim_cfg)
        scheduler = build_scheduler(optimizer, len(loader), epochs, -1, optim_cfg)
        train_model(model, optimizer, loader, scheduler, optim_cfg, 0, epochs, 0, 0, None, out_dir, "cpu",
                    ckpt_save_interval=100, use_tqdm_to_record=True)
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.reset_running_stats()
                module.momentum = None  # cumulative average
        model.train()
        with torch.no_grad():
            for batch in loader:
                model(load_data_to_device(batch, "cpu"))
        return DataLoader(dataset, batch_size=1, shuffle=False, collate_fn=dataset.collate_batch)
    return train
