"""OpenPCDet's HOOK block: DisableAugmentationHook turns augmentations off for the last epochs, in our loop and
through DataAugmentor.disable_augmentation (the call OpenPCDet's loop makes); bad blocks are refused in one line."""
import logging
from pathlib import Path

import pytest
import yaml
from easydict import EasyDict

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.augmentor import DataAugmentor
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.runtime.hooks import DisableAugmentationHook
from pcdet_memslidar.runtime.train import train as train_run

CFGS = Path(__file__).resolve().parents[2] / "cfgs"
STEPS = [{"NAME": "random_world_flip", "ALONG_AXIS_LIST": ["x"]}, {"NAME": "random_world_rotation",
         "WORLD_ROT_ANGLE": [-0.1, 0.1]}, {"NAME": "random_world_scaling", "WORLD_SCALE_RANGE": [0.95, 1.05]}]


def test_disable_augmentation_rebuilds_the_queue_and_keeps_disabled_steps_off():
    augmentor = DataAugmentor(EasyDict(AUG_CONFIG_LIST=STEPS, DISABLE_AUG_LIST=["random_world_rotation"]),
                              ["Pedestrian"])
    assert augmentor.names == ["random_world_flip", "random_world_scaling"]
    # OpenPCDet's hook: DATA_AUGMENTOR with its DISABLE_AUG_LIST replaced by the hook's list
    augmentor.disable_augmentation(EasyDict(AUG_CONFIG_LIST=STEPS, DISABLE_AUG_LIST=["random_world_flip"]))
    assert augmentor.names == ["random_world_scaling"] and len(augmentor.queue) == 1
    augmentor.disable_augmentation(EasyDict(AUG_CONFIG_LIST=STEPS))  # a list only: nothing new off, nothing back on
    assert augmentor.names == ["random_world_scaling"]


def _cfg(hook) -> EasyDict:
    return EasyDict({"HOOK": hook, "DATA_CONFIG": {"DATA_AUGMENTOR": {"AUG_CONFIG_LIST": STEPS}}})


def test_the_hook_turns_its_steps_off_from_the_first_of_the_last_epochs_once(caplog):
    hook = DisableAugmentationHook.from_cfg(_cfg({"DisableAugmentationHook": {
        "DISABLE_AUG_LIST": ["random_world_flip"], "NUM_LAST_EPOCHS": 2}}))
    augmentor_cfg = EasyDict(AUG_CONFIG_LIST=STEPS)
    augmentor = DataAugmentor(augmentor_cfg, ["Pedestrian"])
    logger = logging.getLogger("hook")
    seen = []
    for epoch in range(5):
        with caplog.at_level(logging.INFO, logger="hook"):
            hook.before_epoch(augmentor, augmentor_cfg, epoch, 5, logger)
        seen.append(list(augmentor.names))
    assert seen == [[step["NAME"] for step in STEPS]] * 3 + [["random_world_rotation", "random_world_scaling"]] * 2
    assert [record.getMessage() for record in caplog.records] == [
        "epoch 4: augmentations ['random_world_flip'] off for the last 2 epochs (HOOK.DisableAugmentationHook); on: "
        "['random_world_rotation', 'random_world_scaling']"]
    assert DisableAugmentationHook.from_cfg(EasyDict(DATA_CONFIG={})) is None


@pytest.mark.parametrize("hook, message", [
    ({"EarlyStopHook": {}}, "HOOK is {'EarlyStopHook': {}}: the hooks supported are ['DisableAugmentationHook'], "
                            "e.g. HOOK: {DisableAugmentationHook: {DISABLE_AUG_LIST: [gt_sampling], "
                            "NUM_LAST_EPOCHS: 1}}"),
    ({"DisableAugmentationHook": {"DISABLE_AUG_LIST": ["random_world_flip"]}},
     "HOOK.DisableAugmentationHook is {'DISABLE_AUG_LIST': ['random_world_flip']}: give exactly DISABLE_AUG_LIST "
     "(augmentation NAMEs) and NUM_LAST_EPOCHS (a number of epochs)"),
    ({"DisableAugmentationHook": {"DISABLE_AUG_LIST": ["gt_sampling"], "NUM_LAST_EPOCHS": 1}},
     "HOOK.DisableAugmentationHook.DISABLE_AUG_LIST is ['gt_sampling']: list NAMEs of DATA_CONFIG.DATA_AUGMENTOR."
     "AUG_CONFIG_LIST, which has ['random_world_flip', 'random_world_rotation', 'random_world_scaling']"),
    ({"DisableAugmentationHook": {"DISABLE_AUG_LIST": ["random_world_flip"], "NUM_LAST_EPOCHS": 1.5}},
     "HOOK.DisableAugmentationHook.NUM_LAST_EPOCHS is 1.5: give a whole number of epochs >= 0"),
])
def test_a_bad_hook_block_is_refused_in_one_line(hook, message):
    with pytest.raises(ConfigError) as error:
        DisableAugmentationHook.from_cfg(_cfg(hook))
    assert str(error.value) == message


@pytest.mark.slow
def test_training_with_the_hook_drops_gt_sampling_for_the_last_epoch(memslidar_data, tmp_path, caplog):
    config = tmp_path / "m3_hook.yaml"
    config.write_text(yaml.safe_dump({"_BASE_CONFIG_": str(CFGS / "m3.yaml"), "HOOK": {"DisableAugmentationHook": {
        "DISABLE_AUG_LIST": ["gt_sampling"], "NUM_LAST_EPOCHS": 1}}}))
    cfg = load_config(config, ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(memslidar_data),
                               "OPTIMIZATION.NUM_EPOCHS", "2"])
    with caplog.at_level(logging.INFO):
        train_run(cfg, tmp_path / "run", logging.getLogger("hooked"), seed=0)
    messages = [record.getMessage() for record in caplog.records if "HOOK" in record.getMessage()]
    assert len(messages) == 1 and messages[0].startswith("epoch 2: augmentations ['gt_sampling'] off for the last 1")
    with pytest.raises(ConfigError, match="HOOKS"):  # a misspelt block is an unknown key
        config.write_text(yaml.safe_dump({"_BASE_CONFIG_": str(CFGS / "m3.yaml"), "HOOKS": {}}))
        load_config(config)
