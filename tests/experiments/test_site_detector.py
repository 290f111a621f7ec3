"""`memslidar site check|train` on the bundled recording: the time split, the held-out frames as recorded, the site's
grid, the report; refusals in one line."""
import json
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.cli import main
from pcdet_memslidar.config import load_config
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.io.layout import KittiLayout
from pcdet_memslidar.sim.site import load_site

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
                 "--sim-share", "0.25", "--out", str(out)]) == 0
    return out


def test_site_train_splits_the_recording_by_time(trained):
    def backgrounds(name):
        layout = KittiLayout(trained / "data" / name)
        return {json.loads(layout.metadata(i).read_text())["background"] for i in layout.frame_ids()}

    assert len(KittiLayout(trained / "data" / "train").frame_ids()) == 9
    assert backgrounds("train") == {f"cube1_sample_2020.bfpc#{k}" for k in range(7)}
    assert backgrounds("test") == {f"cube1_sample_2020.bfpc#{k}" for k in range(7, 10)}
    results = json.loads((trained / "results.json").read_text())
    assert results["held_out_frames"] == [7, 10]


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
    alarms = results["false_alarms"]["site"]
    assert alarms["frames"] == 3 and alarms["detections_per_frame"] >= 0
    report = (trained / "report.md").read_text()
    assert "## False alarms on the held-out empty frames" in report and "memslidar detect --cfg" in report
    assert (trained / "site_detections.png").stat().st_size > 10_000
    assert 0 <= results["test"]["AP3D_R40"] <= 1


def test_site_train_mixes_in_the_share_of_simulated_frames_asked_for(trained):
    layout = KittiLayout(trained / "data" / "sim")
    assert len(layout.frame_ids()) == 3
    assert all("background" not in json.loads(layout.metadata(i).read_text()) for i in layout.frame_ids())
    cfg = load_config(trained / "site.yaml", profile="smoke")
    assert [(source.NAME, source.RATIO) for source in cfg.DATA_CONFIG.MIX.SOURCES] == [("train", 0.75), ("sim", 0.25)]


@pytest.mark.parametrize("share", ["1", "-0.1"])
def test_site_train_refuses_a_sim_share_outside_0_to_1_in_one_line(tmp_path, capsys, share):
    with pytest.raises(SystemExit) as exit_:
        main(["site", "train", "--site", str(SITE), "--sim-share", share, "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and error == (f"memslidar site: error: --sim-share must be at least 0 and below 1 "
                                               f"(the share of training frames from --sim-site), got {float(share)}")


def test_site_train_refuses_a_site_without_a_recording_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["site", "train", "--site", str(ROOT / "cfgs" / "sites" / "real.yaml"), "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in error
    assert error == ("memslidar site: error: site 'real' has no background recording: `site train` needs "
                     "`background:` (a recording of the empty site)")
