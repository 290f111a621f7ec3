"""Pre-training, then fine-tuning (M5): a config with a PRETRAIN block trains in two stages within its own epochs.

    PRETRAIN: {SOURCES: [{NAME: sim, RATIO: 1.0}], EPOCH_SHARE: 0.5, FINETUNE_LR_SCALE: 1.0}

Stage 1 trains the config on PRETRAIN.SOURCES (its MIX with those sources: the same TOTAL and 70/30 split) for
round(NUM_EPOCHS x EPOCH_SHARE) epochs into <run_dir>/pretrain. Stage 2 trains the config's own MIX for the other
epochs into <run_dir>, starting from stage 1's final weights (OpenPCDet's --pretrained_model: weights only, a fresh
optimizer and OneCycle) with the learning rate times FINETUNE_LR_SCALE. When both mixes hold the same number of
frames, the two stages take the optimizer steps of the config without PRETRAIN (M5 against M3: the same compute).
OpenPCDet's own tools/train.py ignores PRETRAIN: there, run stage 1 and stage 2 as two trainings
(docs/getting_started.md, "Sweeps and fine-tuning").
"""
from __future__ import annotations

import copy

from pcdet_memslidar.errors import ConfigError

PRETRAIN_DIR = "pretrain"  # stage 1's run folder, inside the run folder


def split_stages(cfg) -> tuple[object | None, object]:
    """(stage-1 config, stage-2 config) of a config with PRETRAIN; (None, cfg) without. Neither has PRETRAIN."""
    block = cfg.get("PRETRAIN")
    if not block:
        return None, cfg
    epochs, share = int(cfg.OPTIMIZATION.NUM_EPOCHS), float(block.get("EPOCH_SHARE", 0.5))
    first = round(epochs * share)
    if not 1 <= first < epochs:
        raise ConfigError(f"{cfg.get('CFG_FILE', 'the config')}: PRETRAIN.EPOCH_SHARE {share} of {epochs} epochs "
                          f"leaves {first} for pre-training and {epochs - first} for fine-tuning; both need at "
                          f"least one: raise OPTIMIZATION.NUM_EPOCHS (e.g. --set OPTIMIZATION.NUM_EPOCHS 2) or "
                          f"change EPOCH_SHARE")
    stages = []
    for sources, stage_epochs, lr_scale in ((block.SOURCES, first, 1.0),
                                            (cfg.DATA_CONFIG.MIX.SOURCES, epochs - first,
                                             float(block.get("FINETUNE_LR_SCALE", 1.0)))):
        stage = copy.deepcopy(cfg)
        stage.pop("PRETRAIN")
        stage.DATA_CONFIG.MIX.SOURCES = copy.deepcopy(sources)
        stage.OPTIMIZATION.NUM_EPOCHS = stage_epochs
        stage.OPTIMIZATION.LR = float(cfg.OPTIMIZATION.LR) * lr_scale
        stages.append(stage)
    return stages[0], stages[1]
