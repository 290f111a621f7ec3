"""POST_PROCESSING.BOX_FROM_POINTS: the config block and the step after either head's post-processing, and the
points' time offsets of a KITTI-layout folder reaching it through `memslidar test`."""
import logging
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from easydict import EasyDict

from pcdet_memslidar import cli
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.infos import create_domain_infos
from pcdet_memslidar.datasets.mixing import split_sources
from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.models import build_network, load_data_to_device
from pcdet_memslidar.models.post_processing import box_from_points, fit_to_points
from pcdet_memslidar.runtime import predict
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, save_checkpoint

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


def walker(at, drift: float, speed: float = 1.2):
    """(126, 4) float32 points and (126,) float32 times [s] of a person at `at` (x, y) [m] walking along heading
    `drift` [rad] at `speed` [m/s]: shoulders 0.6 m wide across the walk, 0.2 m deep, seen at 0.0, 0.1 and 0.2 s and
    at 0.8 and 1.4 m height. The main axis of the points is the shoulders' (variance 0.04 m^2 against 0.0163 m^2
    along the walk), their drift the walk: the two headings are a quarter turn apart."""
    shoulders = drift - np.pi / 2
    u, w, t, z = (a.ravel() for a in np.meshgrid(np.linspace(-0.3, 0.3, 7), [-0.1, 0.0, 0.1], [0.0, 0.1, 0.2],
                                                 [0.8, 1.4], indexing="ij"))
    along, ahead = np.array([np.cos(shoulders), np.sin(shoulders)]), np.array([np.cos(drift), np.sin(drift)])
    xy = np.asarray(at) + u[:, None] * along + (w + speed * t)[:, None] * ahead
    return np.column_stack([xy, z, np.full(len(z), 50.0)]).astype(np.float32), t.astype(np.float32)


def half_turn(heading: float) -> float:
    """A heading folded into [-pi/2, pi/2), as the box step writes it (a person box is symmetric)."""
    return float(np.mod(heading + np.pi / 2, np.pi) - np.pi / 2)


def test_point_times_of_a_kitti_folder_turn_the_boxes_of_memslidar_test_along_the_drift(tmp_path):
    """Frames as `memslidar simulate` writes them (training/time_offset/*.bin beside velodyne/), tested by `memslidar
    test` (smoke profile, both frames in one batch) with a checkpoint whose head fires where the BEV features are
    strongest (near the walker) and regresses nothing (boxes = anchors, heading pi). The boxes the step fits (those at
    the walker's mean moved CENTER_DEPTH 0.08 m along the ray) lie along the drift with the time offsets, along the
    shoulders once the time_offset files are gone; every other box is the same in both runs."""
    cfg_file = CFGS / "m3.yaml"
    settings = ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(tmp_path / "data")]
    walks = {"000000": ((8.0, 1.0), np.pi / 3), "000001": ((12.0, -2.0), -np.pi / 4)}
    layout = KittiLayout(tmp_path / "data" / "industrial")  # the smoke profile's TEST_SOURCE
    for frame_id, (at, drift) in walks.items():
        points, times = walker(at, drift)
        write_frame(layout, frame_id, points, ["Pedestrian"], np.array([[*at, 0.85, 0.6, 0.5, 1.7, drift]]), {},
                    time_offset=times)
    cfg = load_config(cfg_file, settings)
    create_domain_infos(split_sources(cfg.DATA_CONFIG, "test", tmp_path / "data")[0])

    torch.manual_seed(0)
    _, loader = predict.test_loader(cfg, logging.getLogger(__name__))  # as `memslidar test` reads
    model = build_network(cfg.MODEL, num_class=1, dataset=loader.dataset).eval()
    head = model.dense_head
    with torch.no_grad():
        for conv in (head.conv_cls, head.conv_box, head.conv_dir_cls):
            conv.weight.zero_()
            conv.bias.zero_()
        batch = load_data_to_device(next(iter(loader)), "cpu")
        assert batch["point_times"].shape == (2 * 126,)  # read from the folder, both frames
        for module in model.module_list[:-1]:
            batch = module(batch)
        strongest = batch["spatial_features_2d"].sum(dim=1).flatten(1).max(dim=1).values.min().item()
        head.conv_cls.weight.fill_(20.0 / strongest)  # logit 10 at the weaker frame's strongest cell, -10 far away
        head.conv_cls.bias.fill_(-10.0)
    model.profile = "smoke"
    checkpoint = save_checkpoint(checkpoint_state(model, epoch=1), tmp_path / "fires_near_points.pth")

    def boxes(tag: str) -> list[np.ndarray]:
        assert cli.main(["test", "--cfg", str(cfg_file), "--ckpt", str(checkpoint), "--workers", "0", "--output_dir",
                         str(tmp_path / "output"), "--extra_tag", tag, "--set", *settings]) == 0
        result = next((tmp_path / "output").rglob(f"{tag}/**/result.pkl"))
        annos = pickle.loads(result.read_bytes())
        assert [anno["frame_id"] for anno in annos] == ["industrial/000000", "industrial/000001"]
        return [anno["boxes_lidar"] for anno in annos]

    timed = boxes("timed")
    for path in (layout.training / "time_offset").iterdir():
        path.unlink()
    untimed = boxes("untimed")

    for index, (at, drift) in enumerate(walks.values()):
        mean = walker(at, drift)[0][:, :2].astype(np.float64).mean(axis=0)
        centre = mean * (1 + 0.08 / np.hypot(*mean))
        fitted = np.hypot(*(timed[index][:, :2] - centre).T) < 1e-4
        assert 1 <= fitted.sum() == (np.hypot(*(untimed[index][:, :2] - centre).T) < 1e-4).sum()
        assert timed[index][fitted, 6] == pytest.approx([half_turn(drift)] * fitted.sum(), abs=1e-4)
        assert untimed[index][fitted, 6] == pytest.approx([half_turn(drift - np.pi / 2)] * fitted.sum(), abs=1e-4)
        np.testing.assert_array_equal(timed[index][~fitted], untimed[index][~fitted])
        assert timed[index][~fitted, 6] == pytest.approx(np.pi, abs=1e-6)  # anchors as the head left them
