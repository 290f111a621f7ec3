"""Training augmentations: gt_sampling, world flip / rotation / scaling."""
from .data_augmentor import DataAugmentor
from .database_sampler import DataBaseSampler, GtDatabase

__all__ = ["DataAugmentor", "DataBaseSampler", "GtDatabase"]
