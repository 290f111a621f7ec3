"""OpenPCDet's training hooks (the config's HOOK block), run by the training loop before each epoch.

    HOOK: {DisableAugmentationHook: {DISABLE_AUG_LIST: [gt_sampling], NUM_LAST_EPOCHS: 1}}

turns the listed augmentations off for the last NUM_LAST_EPOCHS epochs through DataAugmentor.disable_augmentation,
the call OpenPCDet's own loop makes (so the block means the same under the OpenPCDet launcher).
"""
from __future__ import annotations

import dataclasses
import logging

from easydict import EasyDict

from pcdet_memslidar.datasets.augmentor.data_augmentor import DataAugmentor
from pcdet_memslidar.errors import ConfigError

HOOKS = ("DisableAugmentationHook",)


@dataclasses.dataclass
class DisableAugmentationHook:
    """Augmentations `names` off from epoch `total_epochs - last_epochs` (epochs count from 0) to the end."""

    names: list[str]
    last_epochs: int
    applied: bool = False

    @classmethod
    def from_cfg(cls, cfg) -> DisableAugmentationHook | None:
        """The config's HOOK.DisableAugmentationHook, checked; None without a HOOK block. ConfigError naming the key
        and the fix for another hook, a missing or wrong value, or an augmentation the config does not have."""
        hooks = cfg.get("HOOK")
        if hooks is None:
            return None
        if not isinstance(hooks, dict) or set(hooks) - set(HOOKS):
            raise ConfigError(f"HOOK is {hooks!r}: the hooks supported are {list(HOOKS)}, e.g. HOOK: "
                              "{DisableAugmentationHook: {DISABLE_AUG_LIST: [gt_sampling], NUM_LAST_EPOCHS: 1}}")
        block = hooks.get("DisableAugmentationHook")
        if block is None:
            return None
        key = "HOOK.DisableAugmentationHook"
        if not isinstance(block, dict) or set(block) != {"DISABLE_AUG_LIST", "NUM_LAST_EPOCHS"}:
            raise ConfigError(f"{key} is {block!r}: give exactly DISABLE_AUG_LIST (augmentation NAMEs) and "
                              "NUM_LAST_EPOCHS (a number of epochs)")
        names, last = block["DISABLE_AUG_LIST"], block["NUM_LAST_EPOCHS"]
        configured = [step.NAME for step in cfg.DATA_CONFIG.DATA_AUGMENTOR.AUG_CONFIG_LIST]
        if not isinstance(names, list) or not set(names) <= set(configured):
            raise ConfigError(f"{key}.DISABLE_AUG_LIST is {names!r}: list NAMEs of DATA_CONFIG.DATA_AUGMENTOR."
                              f"AUG_CONFIG_LIST, which has {configured}")
        if isinstance(last, bool) or not isinstance(last, int) or last < 0:
            raise ConfigError(f"{key}.NUM_LAST_EPOCHS is {last!r}: give a whole number of epochs >= 0")
        return cls(list(names), last)

    def before_epoch(self, augmentor: DataAugmentor, augmentor_cfg, epoch: int, total_epochs: int,
                     logger: logging.Logger) -> None:
        """Disable the augmentations in `augmentor` once `epoch` (from 0) is among the last ones."""
        if self.applied or epoch < total_epochs - self.last_epochs:
            return
        augmentor.disable_augmentation(EasyDict({**augmentor_cfg, "DISABLE_AUG_LIST": self.names}))
        self.applied = True
        logger.info(f"epoch {epoch + 1}: augmentations {self.names} off for the last {self.last_epochs} epochs "
                    f"(HOOK.DisableAugmentationHook); on: {augmentor.names}")
