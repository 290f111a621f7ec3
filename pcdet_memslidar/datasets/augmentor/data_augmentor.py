"""Training augmentation, each step chosen by NAME from DATA_AUGMENTOR.AUG_CONFIG_LIST (OpenPCDet's names)."""
from __future__ import annotations

import numpy as np

from pcdet_memslidar.datasets.augmentor import augmentor_utils
from pcdet_memslidar.datasets.augmentor.database_sampler import DataBaseSampler, GtDatabase
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.geometry.boxes import limit_period


class DataAugmentor:
    """Applies the configured augmentations in order; `databases` feeds gt_sampling, per source name."""

    def __init__(self, augmentor_cfg, class_names: list[str], databases: dict[str, GtDatabase] | None = None):
        self.class_names, self.databases, self.disabled = class_names, databases or {}, set()
        self.disable_augmentation(augmentor_cfg)

    def disable_augmentation(self, augmentor_cfg) -> None:
        """Rebuild the queue from augmentor_cfg (DATA_AUGMENTOR, or its AUG_CONFIG_LIST) without the steps in its
        DISABLE_AUG_LIST or disabled before: what OpenPCDet's DisableAugmentationHook calls (runtime.hooks). Unlike
        OpenPCDet's, a step once disabled stays off when a later list omits it."""
        configs = augmentor_cfg if isinstance(augmentor_cfg, list) else augmentor_cfg.AUG_CONFIG_LIST
        if not isinstance(augmentor_cfg, list):
            self.disabled |= set(augmentor_cfg.get("DISABLE_AUG_LIST") or [])
        self.queue, self.names = [], []
        for config in configs:
            if config.NAME in self.disabled:
                continue
            build = getattr(self, f"_build_{config.NAME}", None)
            if build is None:
                raise ConfigError(f"DATA_AUGMENTOR: unknown augmentation {config.NAME!r}; known: {self.known()}")
            self.queue.append(build(config, self.class_names, self.databases))
            self.names.append(config.NAME)

    @classmethod
    def known(cls) -> list[str]:
        """The augmentation NAMEs this augmentor builds."""
        return sorted(name[len("_build_"):] for name in dir(cls) if name.startswith("_build_"))

    def forward(self, data_dict: dict, rng: np.random.Generator) -> dict:
        """data_dict with points (N, 3+C), gt_boxes (M, 7), gt_names (M,), gt_boxes_mask (M,) bool -> augmented.

        Boxes outside gt_boxes_mask (classes not trained) are dropped at the end; headings wrapped to [-pi, pi).
        """
        for step in self.queue:
            data_dict = step(data_dict, rng)
        gt_boxes = np.asarray(data_dict["gt_boxes"]).copy()
        gt_boxes[:, 6] = limit_period(gt_boxes[:, 6], offset=0.5, period=2 * np.pi)
        mask = data_dict.pop("gt_boxes_mask")
        data_dict["gt_boxes"], data_dict["gt_names"] = gt_boxes[mask], np.asarray(data_dict["gt_names"])[mask]
        return data_dict

    @staticmethod
    def _build_gt_sampling(config, class_names, databases):
        return DataBaseSampler(config, class_names, databases)

    @staticmethod
    def _build_random_world_flip(config, class_names, databases):
        axes = list(config.get("ALONG_AXIS_LIST", ["x"]))
        if axes != ["x"]:
            raise ConfigError(f"random_world_flip: only ALONG_AXIS_LIST ['x'] keeps a forward-looking sensor's "
                              f"field of view, got {axes}")

        def flip(data_dict, rng):
            boxes, points = augmentor_utils.random_flip_along_x(data_dict["gt_boxes"], data_dict["points"], rng)
            return {**data_dict, "gt_boxes": boxes, "points": points}
        return flip

    @staticmethod
    def _build_random_world_rotation(config, class_names, databases):
        rot_range = config.WORLD_ROT_ANGLE
        rot_range = [-rot_range, rot_range] if np.isscalar(rot_range) else list(rot_range)

        def rotate(data_dict, rng):
            boxes, points = augmentor_utils.global_rotation(data_dict["gt_boxes"], data_dict["points"], rot_range, rng)
            return {**data_dict, "gt_boxes": boxes, "points": points}
        return rotate

    @staticmethod
    def _build_random_world_scaling(config, class_names, databases):
        scale_range = list(config.WORLD_SCALE_RANGE)

        def scale(data_dict, rng):
            boxes, points = augmentor_utils.global_scaling(data_dict["gt_boxes"], data_dict["points"], scale_range, rng)
            return {**data_dict, "gt_boxes": boxes, "points": points}
        return scale
