"""`memslidar site check|train` on the bundled recording: the time split, the background model from the training part
only, the held-out sets, the three detectors' configs and the side-by-side report; a scene site's simulated empty
recording; refusals in one line."""
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.cli import main
from pcdet_memslidar.config import load_config
from pcdet_memslidar.experiments.site_classical import GRID
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.sim.frame import simulate_frame
from pcdet_memslidar.sim.site import load_site
from pcdet_memslidar.sim.writer import simulate_empty_recording

pytestmark = pytest.mark.slow  # minutes of training, simulation or installing: `pytest -m 'not slow'` leaves it out

ROOT = Path(__file__).resolve().parents[2]
SITE = ROOT / "examples" / "blickfeld_room.yaml"
RECORDING = ROOT / "pcdet_memslidar" / "assets" / "blickfeld" / "cube1_sample_2020.bfpc"


def test_site_check_draws_the_floor_to_look_at(tmp_path, capsys):
    assert main(["site", "check", "--site", str(SITE), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "'height': 1.61" in printed and "of the returns lie within 0.1 m of the floor" in printed
    assert (tmp_path / "ground_check.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    assert main(["site", "train", "--site", str(SITE), "--profile", "smoke", "--frames", "12", "--test-frames", "6",
                 "--detectors", "background", "second", "second_background", "--out", str(out)]) == 0
    return out


def test_site_train_splits_the_recording_by_time(trained):
    def backgrounds(name):
        layout = KittiLayout(trained / "data" / name)
        return {json.loads(layout.metadata(i).read_text())["background"] for i in layout.frame_ids()}

    assert len(KittiLayout(trained / "data" / "train").frame_ids()) == 12
    assert backgrounds("train") == {f"cube1_sample_2020.bfpc#{k}" for k in range(7)}
    for name in ("test", "pairs", "test_distractors", "distractors"):
        assert backgrounds(name) == {f"cube1_sample_2020.bfpc#{k}" for k in range(7, 10)}
    results = json.loads((trained / "results.json").read_text())
    assert results["held_out_frames"] == [7, 10]
    assert results["background_model"]["frames"] == 7  # learned from the training part only


def test_the_empty_held_out_frames_are_the_recording_as_it_is(trained):
    layout = KittiLayout(trained / "data" / "empty")
    mount = load_site(SITE).viewpoints[0].mount
    frames = read_bfpc(RECORDING).frames[7:]
    assert len(layout.frame_ids()) == 3
    for frame_id, frame in zip(layout.frame_ids(), frames):
        stored = np.fromfile(layout.velodyne(frame_id), dtype=np.float32).reshape(-1, 4)
        assert stored.tobytes() == ground.normalise_points(frame.points[frame.first_returns()], mount).tobytes()
        assert layout.label(frame_id).read_text() == ""


def test_site_train_writes_a_config_that_fits_the_site_and_a_report(trained):
    results = json.loads((trained / "results.json").read_text())
    for profile in ("paper", "quick", "smoke"):
        cfg = load_config(trained / "site.yaml", profile=profile)  # the grid rule is checked at load
        x0, y0, _, x1, y1, _ = cfg.DATA_CONFIG.POINT_CLOUD_RANGE
        corners = np.array(load_site(SITE).walkable)
        assert x0 <= corners[:, 0].min() - 0.4 and x1 >= corners[:, 0].max() + 0.4
        assert y0 <= corners[:, 1].min() - 0.4 and y1 >= corners[:, 1].max() + 0.4
        assert x1 - x0 <= np.ptp(corners[:, 0]) + 0.8 + 1.6 and y1 - y0 <= np.ptp(corners[:, 1]) + 0.8 + 1.6
    assert set(results["scores"]) == {"background", "second", "second_background"}
    assert results["command"].endswith(f"--out {trained} --detectors background second second_background")
    for detector, config in results["configs"].items():
        cfg = load_config(config, profile="smoke")
        assert cfg.DATA_CONFIG.BACKGROUND_MODEL == str(trained / "background.npz")
        assert ("background_depth" in cfg.DATA_CONFIG.POINT_FEATURE_ENCODING.used_feature_list) == (
            detector != "second")
        assert results["false_alarms"]["empty"][detector]["frames"] == 3
        assert results["false_alarms"]["distractors"][detector]["frames"] == 3
        for name in ("test", "pairs", "test_distractors"):
            low, high = results["scores"][detector][name]["interval"]["AP3D_R40"]
            assert low <= results["scores"][detector][name]["AP3D_R40"] <= high
    assert load_config(results["configs"]["background"], profile="smoke").MODEL.BACKGROUND_SUBTRACTION == \
        results["classical"]["settings"]
    assert len(results["classical"]["trials"]) == np.prod([len(values) for values in GRID.values()])
    assert results["checkpoints"]["background"] is None
    report = (trained / "report.md").read_text()
    assert "## The detectors side by side" in report and "SECOND + background_depth" in report
    assert report.count("memslidar detect --cfg") == 3
    assert (trained / "site_detections.png").stat().st_size > 10_000


def test_site_train_mixes_in_the_share_of_simulated_frames_asked_for(tmp_path):
    assert main(["site", "train", "--site", str(SITE), "--profile", "smoke", "--frames", "12", "--test-frames", "2",
                 "--sim-share", "0.25", "--detectors", "second", "--out", str(tmp_path)]) == 0
    layout = KittiLayout(tmp_path / "data" / "sim")
    assert len(layout.frame_ids()) == 3
    assert all("background" not in json.loads(layout.metadata(i).read_text()) for i in layout.frame_ids())
    cfg = load_config(tmp_path / "site.yaml", profile="smoke")
    assert [(source.NAME, source.RATIO) for source in cfg.DATA_CONFIG.MIX.SOURCES] == [("train", 0.75), ("sim", 0.25)]


def test_the_background_detectors_refuse_simulated_frames_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["site", "train", "--site", str(SITE), "--sim-share", "0.25", "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in error and "--detectors second" in error


@pytest.mark.parametrize("share", ["1", "-0.1"])
def test_site_train_refuses_a_sim_share_outside_0_to_1_in_one_line(tmp_path, capsys, share):
    with pytest.raises(SystemExit) as exit_:
        main(["site", "train", "--site", str(SITE), "--sim-share", share, "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and error == (f"memslidar site: error: --sim-share must be at least 0 and below 1 "
                                               f"(the share of training frames from --sim-site), got {float(share)}")


def test_a_scene_site_gets_a_simulated_empty_recording_in_the_sensor_frame(tmp_path):
    site = load_site(ROOT / "examples" / "doorway.yaml")
    background = simulate_empty_recording(site, 2, tmp_path / "empty")
    mount = site.viewpoints[0].mount
    assert background.background.recording == str(tmp_path / "empty") and background.viewpoints[0].scene is None
    for index in range(2):
        stored = np.fromfile(tmp_path / "empty" / f"{index:06d}.bin", dtype=np.float32).reshape(-1, 4)
        frame = simulate_frame(dataclasses.replace(site, people=(0, 0)), 0, index)
        np.testing.assert_allclose(mount.sensor_to_ground(stored[:, :3]), frame.points[:, :3], atol=1e-5)
    before = (tmp_path / "empty" / "000000.bin").stat().st_mtime_ns
    simulate_empty_recording(site, 2, tmp_path / "empty")  # read back, not made again
    assert (tmp_path / "empty" / "000000.bin").stat().st_mtime_ns == before


def test_site_train_refuses_a_site_with_several_viewpoints_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["site", "train", "--site", str(ROOT / "cfgs" / "sites" / "sim.yaml"), "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in error
    assert error == ("memslidar site: error: site 'sim' has 4 viewpoints: a site's empty recording is made from one "
                     "mount; give it `scene` and `mount`")
