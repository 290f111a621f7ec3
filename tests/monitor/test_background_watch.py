"""detect with a site's background: a turned sensor is realigned and gives the unturned detections back; a changed
site is reported once, naming the frames, as an event in summary.json."""
import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcdet_memslidar.config import load_config
from pcdet_memslidar.experiments.site_detector import learn_background, site_config
from pcdet_memslidar.geometry.background import BackgroundModel, turn_about_vertical
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.monitor.background_watch import MISMATCH_FRAMES
from pcdet_memslidar.monitor.detect import DetectOptions, detect
from pcdet_memslidar.sim.composite import read_background
from pcdet_memslidar.sim.site import Background, load_site

ROOM = Path(__file__).parents[2] / "examples" / "blickfeld_room.yaml"
PEOPLE = [(4.0, 0.0), (6.0, -1.5)]  # where two people stand in every frame [m]


def person(x: float, y: float) -> np.ndarray:
    """(60, 4) points of a standing person's near side, from 0.1 m to 1.7 m above the floor."""
    t = np.linspace(0.0, 1.0, 60)
    return np.stack([x - 0.1 * np.cos(9 * t), y + 0.4 * (t - 0.5), 0.1 + 1.6 * np.abs(np.sin(13 * t)),
                     np.full(60, 100.0)], axis=1).astype(np.float32)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """(classical config, folders): the room's background from frames 0-6; held-out frames 7-9 with two people, as
    recorded ('frames'), turned by 0.3, 1, 4 and 10 deg ('turned_<yaw>') and, MISMATCH_FRAMES + 2 times over, one metre
    nearer everywhere ('changed')."""
    tmp = tmp_path_factory.mktemp("room")
    site = load_site(ROOM)
    train = dataclasses.replace(site, background=Background(site.background.recording, (0, 7)))
    learn_background(train).save(tmp / "background.npz")
    config = site_config(site, tmp / "data", {"TOTAL": 20, "SOURCES": [{"NAME": "train", "RATIO": 1.0}]},
                         tmp / "background.npz", "background", {})
    (tmp / "classical.yaml").write_text(yaml.safe_dump(config))
    cfg = load_config(tmp / "classical.yaml", profile="smoke")
    mount = site.viewpoints[0].mount
    held = read_background(Background(site.background.recording, (7, 10)), site.pattern)
    frames = [np.concatenate([ground.normalise_points(frame.points[frame.returned], mount),
                              *(person(x, y) for x, y in PEOPLE)]) for frame in held]
    changed = [np.c_[f[:, 0] - 1.0, f[:, 1:]] for f in frames]
    variants = {"frames": frames, "changed": (changed * MISMATCH_FRAMES)[:MISMATCH_FRAMES + 2],
                **{f"turned_{yaw:g}": [turn_about_vertical(f, -yaw) for f in frames] for yaw in (0.3, 1.0, 4.0, 10.0)}}
    for name, clouds in variants.items():
        for index, points in enumerate(clouds):
            write_frame(KittiLayout(tmp / name), f"{index:06d}", points.astype(np.float32), [], np.zeros((0, 7)), {})
    return cfg, tmp


def run_detect(cfg, folder: Path, out: Path) -> tuple[list[np.ndarray], dict]:
    summary = detect(cfg, None, DetectOptions(src=folder, out=out, fmt="kitti"), logging.getLogger("test"))
    records = [json.loads(line) for line in (out / "detections.jsonl").read_text().splitlines()]
    return [np.array([d["box"] for d in record["detections"]]).reshape(-1, 7) for record in records], summary


def test_the_classical_detector_finds_the_two_people_of_every_frame_and_nothing_else(room):
    cfg, tmp = room
    boxes, summary = run_detect(cfg, tmp / "frames", tmp / "out_frames")
    assert [len(frame) for frame in boxes] == [2, 2, 2]
    for frame in boxes:
        centres = frame[np.argsort(frame[:, 0]), :2]
        np.testing.assert_allclose(centres, np.array(PEOPLE), atol=0.2)
    assert summary["background_events"] == []


@pytest.mark.parametrize("yaw", [0.3, 1.0, 4.0, 10.0])
def test_a_turned_sensor_is_realigned_from_its_first_frame_and_gives_the_unturned_detections(room, yaw):
    cfg, tmp = room
    expected, _ = run_detect(cfg, tmp / "frames", tmp / f"out_reference_{yaw:g}")
    boxes, summary = run_detect(cfg, tmp / f"turned_{yaw:g}", tmp / f"out_turned_{yaw:g}")
    for got, want in zip(boxes, expected):
        assert len(got) == len(want)
        np.testing.assert_allclose(got[np.argsort(got[:, 0]), :3], want[np.argsort(want[:, 0]), :3], atol=0.03)
    (event,) = summary["background_events"]
    assert event["type"] == "sensor_turned" and event["frames"] == ["000000.bin"]
    assert abs(event["yaw_deg"] - yaw) <= 0.1 and event["foreground_share_after"] < 0.05


@pytest.mark.slow
def test_a_site_that_changed_is_reported_once_naming_its_frames(room, caplog):
    cfg, tmp = room
    with caplog.at_level(logging.WARNING):
        _, summary = run_detect(cfg, tmp / "changed", tmp / "out_changed")
    (event,) = summary["background_events"]  # one event for the whole stretch, from its first frame on
    assert event["type"] == "background_mismatch" and event["foreground_share"] > 0.05
    assert event["frames"] == [f"{index:06d}.bin" for index in range(MISMATCH_FRAMES + 2)]
    warnings = [r.getMessage() for r in caplog.records if "site train" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith("frames 000000.bin to 000009.bin: ")


@pytest.mark.slow
def test_with_a_background_from_three_frames_the_other_seven_empty_frames_raise_no_alarm(tmp_path):
    site = load_site(ROOM)
    learn_background(dataclasses.replace(site, background=Background(site.background.recording, (0, 3)))).save(
        tmp_path / "background.npz")
    config = site_config(site, tmp_path / "data", {"TOTAL": 20, "SOURCES": [{"NAME": "train", "RATIO": 1.0}]},
                         tmp_path / "background.npz", "background", {})
    (tmp_path / "classical.yaml").write_text(yaml.safe_dump(config))
    mount = site.viewpoints[0].mount
    for index, frame in enumerate(read_background(Background(site.background.recording, (3, 10)), site.pattern)):
        write_frame(KittiLayout(tmp_path / "empty"), f"{index:06d}", ground.normalise_points(
            frame.points[frame.returned], mount), [], np.zeros((0, 7)), {})
    boxes, summary = run_detect(load_config(tmp_path / "classical.yaml", profile="quick"), tmp_path / "empty",
                                tmp_path / "out")
    assert summary["frames"] == 7 and summary["detections"] == 0 and summary["background_events"] == []


@pytest.mark.slow
def test_a_long_mismatch_searches_for_a_turn_once_every_mismatch_frames(room, monkeypatch):
    cfg, tmp = room
    searches = []
    original = BackgroundModel.estimate_yaw
    monkeypatch.setattr(BackgroundModel, "estimate_yaw",
                        lambda self, points, seed=0: searches.append(1) or original(self, points, seed))
    run_detect(cfg, tmp / "changed", tmp / "out_changed_searches")
    assert len(searches) == 2  # the first frame, then the tenth: 12 frames off the background
