"""MEMSLidarDataset, augmentation, voxelisation and sim/real mixing (OpenPCDet's DatasetTemplate contract).

DATASETS is the registry build_dataloader looks DATA_CONFIG.DATASET up in (OpenPCDet's pcdet.datasets.__all__).
"""
from __future__ import annotations

import torch
from torch.utils.data import DataLoader, DistributedSampler

from pcdet_memslidar.datasets.dataset import DatasetTemplate
from pcdet_memslidar.datasets.memslidar_dataset import MEMSLidarDataset
from pcdet_memslidar.datasets.mixing import MixedBatchSampler
from pcdet_memslidar.errors import ConfigError

DATASETS = {"DatasetTemplate": DatasetTemplate, "MEMSLidarDataset": MEMSLidarDataset}


def build_dataloader(dataset_cfg, class_names, batch_size, dist, root_path=None, workers=4, seed=None, logger=None,
                     training=True, merge_all_iters_to_one_epoch=False, total_epochs=0):
    """(dataset, dataloader, sampler) as OpenPCDet's build_dataloader; sampler is None unless distributed or
    DATA_CONFIG.MIX.BALANCE_BATCHES (then a MixedBatchSampler, which has set_epoch)."""
    if dataset_cfg.DATASET not in DATASETS:
        raise ConfigError(f"DATA_CONFIG.DATASET {dataset_cfg.DATASET!r} is unknown; known: {sorted(DATASETS)}")
    dataset = DATASETS[dataset_cfg.DATASET](dataset_cfg=dataset_cfg, class_names=class_names, root_path=root_path,
                                            training=training, logger=logger)
    rank, world_size = (torch.distributed.get_rank(), torch.distributed.get_world_size()) if dist else (0, 1)
    if seed is not None:
        dataset.reseed([seed, rank])
    if merge_all_iters_to_one_epoch:
        dataset.merge_all_iters_to_one_epoch(merge=True, epochs=total_epochs)
    common = dict(num_workers=workers, collate_fn=dataset.collate_batch, pin_memory=torch.cuda.is_available(),
                  timeout=0)
    if training and dataset_cfg.get("MIX", {}).get("BALANCE_BATCHES", False):
        if merge_all_iters_to_one_epoch:
            raise ConfigError("DATA_CONFIG.MIX.BALANCE_BATCHES does not combine with --merge-all-iters-to-one-epoch")
        sampler = MixedBatchSampler(dataset.sample_sources, batch_size, seed=seed or 0, num_replicas=world_size,
                                    rank=rank)
        return dataset, DataLoader(dataset, batch_sampler=sampler, **common), sampler
    sampler = DistributedSampler(dataset, num_replicas=world_size, rank=rank, shuffle=training) if dist else None
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=(sampler is None) and training, sampler=sampler,
                        drop_last=False, **common)
    return dataset, loader, sampler


__all__ = ["DATASETS", "DatasetTemplate", "MEMSLidarDataset", "MixedBatchSampler", "build_dataloader"]
