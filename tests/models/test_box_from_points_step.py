"""POST_PROCESSING.BOX_FROM_POINTS: the config block and the step after either head's post-processing."""
from pathlib import Path

import numpy as np
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar.config import load_config
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.models.post_processing import box_from_points, fit_to_points

CFGS = Path(__file__).resolve().parents[2] / "cfgs"


@pytest.mark.parametrize("cfg_file", ["m3.yaml", "centerpoint/m3.yaml"])
def test_both_heads_fit_boxes_to_points_unless_disabled(cfg_file):
    assert box_from_points(load_config(CFGS / cfg_file).MODEL.POST_PROCESSING)[:2] == (5, 0.1)
    cfg = load_config(CFGS / cfg_file, ["MODEL.POST_PROCESSING.BOX_FROM_POINTS.ENABLED", "False"])
    assert box_from_points(cfg.MODEL.POST_PROCESSING) is None  # the network's own heading


GOOD = {"ENABLED": True, "MIN_POINTS": 5, "MARGIN": 0.1, "MIN_HEIGHT": 0.5, "CENTER_DEPTH": 0.08,
        "MIN_DRIFT_SPEED": 0.5}


def test_a_good_block_gives_its_five_settings():
    assert box_from_points(EasyDict({"BOX_FROM_POINTS": GOOD})) == (5, 0.1, 0.5, 0.08, 0.5)
    assert box_from_points(EasyDict({"BOX_FROM_POINTS": {**GOOD, "CENTER_DEPTH": None, "MIN_DRIFT_SPEED": None}})) \
        == (5, 0.1, 0.5, None, None)


@pytest.mark.parametrize("change, message", [
    ({"MIN_HEIGHT": None}, r"BOX_FROM_POINTS is .*: write \{ENABLED: True, MIN_POINTS: 5, MARGIN: 0.1, MIN_HEI"),
    ({"RADIUS": 1}, "write {ENABLED: True, MIN_POINTS: 5, MARGIN: 0.1, MIN_HEIGHT: 0.4, CENTER_DEPTH: 0.08, "
                    "MIN_DRIFT_SPEED: 0.5}"),
    ({"MIN_DRIFT_SPEED": -1}, r"MIN_DRIFT_SPEED is -1: use metres per second in \[0, 10\) or null"),
    ({"MIN_DRIFT_SPEED": True}, r"MIN_DRIFT_SPEED is True: use metres per second in \[0, 10\) or null"),
    ({"CENTER_DEPTH": -0.1}, r"CENTER_DEPTH is -0.1: use metres in \[0, 10\) or null"),
    ({"CENTER_DEPTH": "0.1"}, r"CENTER_DEPTH is '0.1': use metres in \[0, 10\) or null"),
    ({"ENABLED": "yes"}, r"ENABLED is 'yes': use True or False"),
    ({"MIN_POINTS": 1}, r"MIN_POINTS is 1: use an integer >= 2"),
    ({"MIN_POINTS": 5.5}, r"MIN_POINTS is 5.5: use an integer >= 2"),
    ({"MARGIN": -0.1}, r"MARGIN is -0.1: use metres in \[0, 10\)"),
    ({"MARGIN": float("nan")}, r"MARGIN is nan"),
    ({"MIN_HEIGHT": 12}, r"MIN_HEIGHT is 12: use metres in \[0, 10\)"),
])
def test_a_malformed_block_is_refused_naming_the_fix(change, message):
    block = {key: value for key, value in {**GOOD, **change}.items() if value is not None}
    with pytest.raises(ConfigError, match=message):
        box_from_points(EasyDict({"BOX_FROM_POINTS": block}))


def test_a_block_that_is_not_a_mapping_is_refused():
    with pytest.raises(ConfigError, match="write {ENABLED: True"):
        box_from_points(EasyDict({"BOX_FROM_POINTS": [5, 0.1]}))


def test_each_frame_of_a_batch_fits_its_boxes_to_its_own_points():
    line = np.linspace(-0.3, 0.3, 9)
    frame_1 = np.column_stack([np.ones(9), 4.0 + line, line, np.full(9, 0.8)])  # frame 1: points along x + y
    pred_dicts = [{"pred_boxes": torch.tensor([[4.0, 0.0, 0.8, 0.5, 0.6, 1.7, 1.0]])},
                  {"pred_boxes": torch.tensor([[4.0, 0.0, 0.8, 0.5, 0.6, 1.7, 1.0]])},
                  {"pred_boxes": torch.zeros((0, 7))}]
    fit_to_points(pred_dicts, torch.tensor(frame_1, dtype=torch.float32), 5, 0.0, 0.0, None, None)
    assert pred_dicts[0]["pred_boxes"].tolist() == [[4.0, 0.0, 0.800000011920929, 0.5, 0.6000000238418579,
                                                     1.7000000476837158, 1.0]]  # frame 0 has no points: as it was
    assert pred_dicts[1]["pred_boxes"].dtype == torch.float32
    assert pred_dicts[1]["pred_boxes"][0, 3:5].tolist() == pytest.approx([0.6, 0.5])  # long side first
    assert pred_dicts[1]["pred_boxes"][0, 6].item() == pytest.approx(np.pi / 4, abs=1e-6)
    assert pred_dicts[2]["pred_boxes"].shape == (0, 7)


def test_the_batch_point_times_of_each_frame_turn_its_box_along_the_drift():
    times = np.repeat([0.0, 0.1, 0.2, 0.3], 4)
    walker = np.column_stack([np.ones(16), 8.0 + np.tile([-0.25, -0.1, 0.1, 0.25], 4), 1.0 * times,
                              np.full(16, 1.0)])  # frame 1: 0.5 m wide along x, walking along y at 1 m/s
    box = [8.0, 0.15, 0.9, 0.6, 0.6, 1.8, 0.3]
    pred_dicts = [{"pred_boxes": torch.tensor([box])}, {"pred_boxes": torch.tensor([box])}]
    fit_to_points(pred_dicts, torch.tensor(walker, dtype=torch.float32), 5, 0.1, 0.0, None, 0.5,
                  point_times=torch.tensor(times, dtype=torch.float32))
    assert abs(np.cos(pred_dicts[1]["pred_boxes"][0, 6].item())) < 1e-6  # along y, where the points drift
    assert pred_dicts[0]["pred_boxes"][0, 6].item() == pytest.approx(0.3)  # frame 0 has no points
    without_times = [{"pred_boxes": torch.tensor([box])}, {"pred_boxes": torch.tensor([box])}]
    fit_to_points(without_times, torch.tensor(walker, dtype=torch.float32), 5, 0.1, 0.0, None, 0.5)
    assert without_times[1]["pred_boxes"][0, 6].item() == pytest.approx(0.0, abs=1e-6)  # the main axis, along x
