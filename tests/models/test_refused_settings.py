"""OpenPCDet settings the standalone SECOND does not support are refused with ConfigError (one line on the CLI),
naming the key and the value to use."""
from pathlib import Path

import pytest
import torch

from pcdet_memslidar.cli import main
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime.optimization import build_optimizer

CFGS = Path(__file__).resolve().parents[2] / "cfgs"
QUICK_RANGE, QUICK_VOXEL = [2.56, -23.2, 0.1, 40.96, 23.2, 2.5], [0.1, 0.1, 0.06]


@pytest.mark.parametrize("key, value, message", [
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.MATCH_HEIGHT", "True", "MATCH_HEIGHT True is not supported: use False"),
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.POS_FRACTION", "0.5", r"POS_FRACTION >= 0 \(sampling\) is not supported"),
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.NORM_BY_NUM_EXAMPLES", "True", "NORM_BY_NUM_EXAMPLES True is not"),
    ("MODEL.DENSE_HEAD.USE_MULTIHEAD", "True", "USE_MULTIHEAD is not supported by AnchorHeadSingle: set it False"),
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.NAME", "ATSSTargetAssigner", "only AxisAlignedTargetAssigner"),
])
def test_unsupported_model_settings_are_config_errors(key, value, message):
    cfg = load_config(CFGS / "m3.yaml", ["PROFILE", "quick", key, value])
    with pytest.raises(ConfigError, match=message):
        build_network(cfg.MODEL, 1, SyntheticPersonDataset(QUICK_RANGE, QUICK_VOXEL, num_frames=0))


def test_an_unknown_optimizer_is_a_config_error():
    cfg = load_config(CFGS / "m3.yaml", ["OPTIMIZATION.OPTIMIZER", "lion"])
    with pytest.raises(ConfigError, match=r"OPTIMIZATION\.OPTIMIZER 'lion' is unknown: use adam_onecycle, adam or sgd"):
        build_optimizer(torch.nn.Linear(2, 2), cfg.OPTIMIZATION)


@pytest.mark.parametrize("key, value", [
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.MATCH_HEIGHT", "True"),
    ("MODEL.DENSE_HEAD.TARGET_ASSIGNER_CONFIG.POS_FRACTION", "0.5"),
    ("MODEL.DENSE_HEAD.USE_MULTIHEAD", "True"),
    ("OPTIMIZATION.OPTIMIZER", "lion"),
    ("HOOK.DisableAugmentationHook.NUM_LAST_EPOCHS", "1"),
    ("MODEL.POST_PROCESSING.BOX_FROM_POINTS.MIN_POINTS", "1"),
])
def test_each_refused_value_is_one_line_through_the_cli(key, value, memslidar_data, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["train", "--cfg", str(CFGS / "m3.yaml"), "--out", str(tmp_path), "--set", "PROFILE", "smoke",
              "DATA_CONFIG.DATA_PATH", str(memslidar_data), key, value])
    printed = capsys.readouterr().err  # the log of the start, then the error
    error = printed.splitlines()[-1]
    assert exit_.value.code == 2 and error.startswith("memslidar train: error: ") and "Traceback" not in printed
    assert key.split(".")[-1] in error or key.split(".")[0] in error
