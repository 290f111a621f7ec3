"""Training augmentations: gt_sampling, world flip / rotation / scaling."""
from pcdet_memslidar.datasets.augmentor.data_augmentor import DataAugmentor
from pcdet_memslidar.datasets.augmentor.database_sampler import DataBaseSampler, GtDatabase

__all__ = ["DataAugmentor", "DataBaseSampler", "GtDatabase"]
