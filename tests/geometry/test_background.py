"""The site's background model: foreground and background_depth with exact values, pulses that never returned, the
same feature for a .bfpc frame and its KITTI import, the real recording's held-out frames, and a turned sensor."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from easydict import EasyDict

from pcdet_memslidar.datasets.dataset import BACKGROUND_FEATURE, DatasetTemplate
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.geometry.background import BackgroundModel, turn_about_vertical
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.kitti import read_points
from pcdet_memslidar.sim.composite import read_background
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.site import Background

RECORDING = Path(__file__).parents[2] / "pcdet_memslidar" / "assets" / "blickfeld" / "cube1_sample_2020.bfpc"
ROOM_MOUNT = Mount(1.61, 0.44, -0.13)  # examples/blickfeld_room.yaml
LEVEL = Mount(2.0, 0.0)
AHEAD, LEFT = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
SPACING = np.radians(0.2)


def two_pulse_model() -> BackgroundModel:
    """Two pulses of a level sensor 2 m up: straight ahead with a wall at 5 m, and to the left, never returned."""
    return BackgroundModel.learn(np.stack([AHEAD, LEFT]), [np.array([[5.0, 0.0, 0.0]]), np.zeros((0, 3))], LEVEL,
                                 SPACING)


def ground_points(sensor_points) -> np.ndarray:
    return LEVEL.sensor_to_ground(np.asarray(sensor_points, dtype=np.float64))


def test_a_return_within_the_margin_is_background_and_half_a_metre_in_front_is_foreground_with_its_depth():
    model = two_pulse_model()
    assert model.range.tolist() == [5.0, np.inf]
    assert model.margin(np.array([5.0])).tolist() == [0.25]  # 0.2 m + 0.01 x 5 m
    points = ground_points([[4.99, 0.0, 0.0], [4.5, 0.0, 0.0], [4.76, 0.0, 0.0], [4.74, 0.0, 0.0], [0.5, 0, 0]])
    assert model.foreground(points).tolist() == [False, True, False, True, True]
    depth = model.depth(points)
    assert depth.dtype == np.float32
    assert depth[:3].tolist() == [0.0, 0.5, 0.0]
    assert depth[3] == np.float32(5.0 - 4.74)
    assert depth[4] == 2.0  # 4.5 m in front: clipped to DEPTH_CLIP_M


def test_every_return_of_a_pulse_whose_background_never_returned_is_foreground_at_the_clip():
    model = two_pulse_model()
    points = ground_points([[0.0, 0.5, 0.0], [0.0, 30.0, 0.0]])
    assert model.foreground(points).tolist() == [True, True]
    assert model.depth(points).tolist() == [2.0, 2.0]


def test_the_background_is_the_nearest_return_of_a_pulse_and_its_neighbours_over_all_frames():
    near = np.array([np.cos(SPACING), np.sin(SPACING), 0.0])  # one spacing to the left: a neighbour
    far = np.array([np.cos(5 * SPACING), np.sin(5 * SPACING), 0.0])  # five spacings: not one
    frames = [np.array([5.0 * AHEAD, 7.0 * far]), np.array([6.0 * AHEAD, 4.0 * near, 8.0 * far])]
    model = BackgroundModel.learn(np.stack([AHEAD, near, far]), frames, LEVEL, SPACING)
    assert model.range.tolist() == [4.0, 4.0, np.linalg.norm(7.0 * far)]  # 7 m, to the last bit of its norm
    assert model.own_range.tolist() == [5.0, 4.0, np.linalg.norm(7.0 * far)]  # each pulse's own nearest return


def test_the_model_survives_saving_and_a_broken_file_is_refused_naming_it(tmp_path):
    model = two_pulse_model()
    model.save(tmp_path / "background.npz")
    loaded = BackgroundModel.load(tmp_path / "background.npz")
    assert loaded.range.tolist() == model.range.tolist() and loaded.mount == LEVEL and loaded.frames == 2
    (tmp_path / "broken.npz").write_text("not a model")
    with pytest.raises(DataFormatError, match="broken.npz.*site train"):
        BackgroundModel.load(tmp_path / "broken.npz")
    with pytest.raises(DataFormatError, match="missing.npz: background model not found"):
        BackgroundModel.load(tmp_path / "missing.npz")


def room_model(frames: int) -> tuple[BackgroundModel, list[np.ndarray]]:
    """The bundled recording's background from its first `frames` frames; its other frames' returns (ground frame)."""
    pattern = get_pattern("cube1_2020")
    recorded = read_background(Background(str(RECORDING)), "cube1_2020")
    returns = [frame.points[frame.returned] for frame in recorded]
    model = BackgroundModel.learn(pattern.pulses()[0], [r[:, :3] for r in returns[:frames]], ROOM_MOUNT,
                                  np.radians(pattern.angle_spacing_deg))
    return model, [ground.normalise_points(r, ROOM_MOUNT) for r in returns[frames:]]


def test_held_out_frames_of_the_empty_room_are_background_but_for_a_few_stray_returns():
    for frames in (3, 7):
        model, held_out = room_model(frames)
        for points in held_out:
            assert model.foreground(points).sum() <= 15  # of about 11,600 returns


@pytest.mark.parametrize("yaw", [1.0, 4.0, 10.0])
def test_a_sensor_turned_about_the_vertical_is_found_again_without_labels(yaw):
    model, held_out = room_model(7)
    turned = turn_about_vertical(held_out[0], -yaw)  # what the sensor sees after a turn of yaw
    assert model.foreground_share(turned) > 0.05
    found, share = model.estimate_yaw(turned)
    assert abs(found - yaw) <= 0.1 and share < 0.002


@pytest.mark.slow
def test_the_feature_is_the_same_for_a_bfpc_frame_and_its_kitti_import(tmp_path):
    model, _ = room_model(7)
    model.save(tmp_path / "background.npz")
    subprocess.run([sys.executable, "-m", "pcdet_memslidar.cli", "import", "--format", "bfpc", "--src",
                    str(RECORDING), "--out", str(tmp_path / "room"), "--mount", "1.61,0.44,-0.13"], check=True,
                   capture_output=True)
    frame = read_bfpc(RECORDING).frames[8]
    from_bfpc = ground.normalise_points(frame.points[frame.first_returns()], ROOM_MOUNT)
    imported = read_points(tmp_path / "room" / "training" / "velodyne" / "000008.bin")
    dataset = DatasetTemplate(EasyDict(_data_config(tmp_path / "background.npz")), ["Pedestrian"], training=False,
                              root_path=tmp_path)
    features = dataset.point_features(imported)
    assert features.shape == (len(imported), 5)
    assert np.array_equal(np.sort(features[:, 4]), np.sort(model.depth(from_bfpc)))


def _data_config(background) -> dict:
    features = ["x", "y", "z", "intensity", BACKGROUND_FEATURE]
    return {"POINT_CLOUD_RANGE": [0, -10, -1, 12.8, 10, 3], "BACKGROUND_MODEL": str(background),
            "POINT_FEATURE_ENCODING": {"encoding_type": "absolute_coordinates_encoding",
                                       "used_feature_list": features, "src_feature_list": features},
            "DATA_PROCESSOR": []}


def test_a_config_that_names_the_feature_without_a_model_is_refused_naming_the_key(tmp_path):
    config = _data_config(tmp_path / "background.npz")
    del config["BACKGROUND_MODEL"]
    with pytest.raises(ConfigError, match="DATA_CONFIG.BACKGROUND_MODEL"):
        DatasetTemplate(EasyDict(config), ["Pedestrian"], training=False, root_path=tmp_path)


def test_foreground_only_keeps_the_returns_in_front_of_the_background_with_their_times(tmp_path):
    two_pulse_model().save(tmp_path / "background.npz")
    dataset = DatasetTemplate(EasyDict({**_data_config(tmp_path / "background.npz"), "FOREGROUND_ONLY": True}),
                              ["Pedestrian"], training=False, root_path=tmp_path)
    # straight ahead: 1 cm in front of the wall (background), 0.5 m in front; to the left: no background ever
    points = np.column_stack([ground_points([[4.99, 0, 0], [4.5, 0, 0], [0, 3.0, 0]]), np.zeros(3)])
    frame = dataset.prepare_data({"points": dataset.point_features(points), "frame_id": "0",
                                  "point_times": np.array([0.1, 0.2, 0.3], dtype=np.float32)})
    assert np.array_equal(frame["point_times"], np.array([0.2, 0.3], dtype=np.float32))
    assert np.allclose(frame["points"][:, 4], [0.5, 2.0])


def test_foreground_only_without_the_feature_is_refused_naming_the_key(tmp_path):
    config = {**_data_config(tmp_path / "background.npz"), "FOREGROUND_ONLY": True}
    config["POINT_FEATURE_ENCODING"] = {**config["POINT_FEATURE_ENCODING"],
                                        "src_feature_list": ["x", "y", "z", "intensity"],
                                        "used_feature_list": ["x", "y", "z", "intensity"]}
    del config["BACKGROUND_MODEL"]
    with pytest.raises(ConfigError, match="DATA_CONFIG.FOREGROUND_ONLY needs background_depth"):
        DatasetTemplate(EasyDict(config), ["Pedestrian"], training=False, root_path=tmp_path)
