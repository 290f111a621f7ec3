"""memslidar detect end to end on an untrained smoke-profile SECOND: what it writes, what it keeps from the user's
data (nothing but detections unless asked), ROS 2 bags in and MCAP out, and its errors. What the detections are worth
is not tested here."""
import json
import logging
import re
import runpy
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from pcdet_memslidar import cli
from pcdet_memslidar.config import load_config
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.io.formats import list_frames
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.models import build_network
from pcdet_memslidar.monitor.detect import DetectOptions, FrameVoxeliser, detect
from pcdet_memslidar.monitor.zones import read_zones
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, save_checkpoint
from pcdet_memslidar.sim.site import get_domain
from pcdet_memslidar.sim.writer import simulate_sequence_dataset

REPO_CFG = "cfgs/m3.yaml"
RECORDING = "pcdet_memslidar/assets/blickfeld/cube1_sample_2020.bfpc"
RECORDING_SHA256 = "f2fafd8bf6d63a6e579a8c510985f12c81feed00e783c2edcc6f54ab13a0f492"
ZONES = "zones:\n  - {name: near, level: protective, polygon: [[2, -10], [12, -10], [12, 10], [2, 10]]}\n"


def untrained_checkpoint(path, profile: str):
    cfg = load_config(REPO_CFG, profile=profile)
    model = build_network(cfg.MODEL, num_class=1, dataset=FrameVoxeliser(cfg, logging.getLogger("test")))
    model.profile = profile
    return save_checkpoint(checkpoint_state(model, epoch=1), path)


@pytest.fixture(scope="module")
def smoke_checkpoint(tmp_path_factory):
    return untrained_checkpoint(tmp_path_factory.mktemp("ckpt") / "smoke.pth", "smoke")


@pytest.fixture
def frames_folder(tmp_path, make_people_frame):
    """.npy frames: 000 with people, 001 without points, 002 with people and 5 NaN rows."""
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    people, _ = make_people_frame(rng, 3, (0.0, 1.0))
    nan_frame = np.concatenate([people, np.full((5, 4), np.nan, np.float32)])
    for name, points in (("000", people), ("001", np.zeros((0, 4), np.float32)), ("002", nan_frame)):
        np.save(folder / f"{name}.npy", points)
    return folder


def written_files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


@pytest.mark.slow
def test_detect_on_the_real_recording_keeps_detections_not_points(tmp_path, bundled_asset, smoke_checkpoint):
    recording = bundled_asset(RECORDING, RECORDING_SHA256)
    zones = tmp_path / "zones.yaml"
    zones.write_text(ZONES)
    out = tmp_path / "out"
    assert cli.main(["detect", "--cfg", REPO_CFG, "--profile", "smoke", "--ckpt", str(smoke_checkpoint),
                     "--src", str(recording), "--estimate-ground", "--zones", str(zones), "--out", str(out)]) == 0
    records = [json.loads(line) for line in (out / "detections.jsonl").read_text().splitlines()]
    assert [r["frame"] for r in records] == [f"{k:06d}" for k in range(10)]
    assert [r["source"] for r in records] == [f"cube1_sample_2020.bfpc#{k}" for k in range(10)]
    assert records[0]["time_s"] == 0.0 and all(b["time_s"] > a["time_s"] for a, b in zip(records, records[1:]))
    assert all(set(r) == {"frame", "source", "time_s", "detections", "events"} for r in records)
    for record in records:
        for detection in record["detections"]:
            assert set(detection) == {"box", "score", "track_id", "zones"} and len(detection["box"]) == 7
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["frames"], summary["format"], summary["points_written"]) == (10, "bfpc", False)
    assert summary["frames_with_point_times"] == 10  # a .bfpc gives its times in seconds: the box step's drift
    assert summary["precision"] == "fp32"  # the default
    assert summary["mount"]["source"] == "estimated from the ground plane"
    assert summary["detections"] == sum(len(r["detections"]) for r in records)
    # GDPR default: only detections leave; no point file of any format, no plots
    assert written_files(out) == sorted(["detections.jsonl", "summary.json", ".memslidar-output",
                                         *[f"labels/{k:06d}.txt" for k in range(10)]])


def test_demo_flags_and_saved_points(tmp_path, frames_folder, smoke_checkpoint, monkeypatch):
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["demo.py", "--cfg_file", REPO_CFG, "--data_path", str(frames_folder), "--ckpt",
                                      str(smoke_checkpoint), "--ext", ".npy", "--out", str(out), "--save-points",
                                      "--plot", "--precision", "bf16", "--profile", "smoke"])
    with pytest.raises(SystemExit) as done:
        runpy.run_path("tools/demo.py", run_name="__main__")
    assert done.value.code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["frames"], summary["frames_without_points"], summary["dropped_invalid_points"]) == (3, 1, 5)
    assert summary["format"] == "npy" and summary["points_written"] is True and summary["precision"] == "bf16"
    assert summary["frames_with_point_times"] == 0  # no time field
    saved = np.fromfile(out / "points" / "000000.bin", dtype=np.float32).reshape(-1, 4)
    np.testing.assert_array_equal(saved, np.load(frames_folder / "000.npy"))  # no mount: stored as read
    assert (out / "points" / "000001.bin").stat().st_size == 0
    assert sorted(p.name for p in (out / "plots").iterdir()) == ["000000.png", "000001.png", "000002.png"]


def test_the_voxeliser_keeps_each_points_time_through_the_range_mask():
    voxeliser = FrameVoxeliser(load_config(REPO_CFG, profile="smoke"), logging.getLogger("test"))
    x = np.linspace(-100.0, 100.0, 401, dtype=np.float32)  # most of them out of range
    points = np.stack([x, np.zeros_like(x), np.ones_like(x), np.zeros_like(x)], axis=1)
    sample = voxeliser(points, "000000", point_times=x.copy())  # a point's time = its x, to check the order
    assert 0 < len(sample["points"]) < len(points)
    np.testing.assert_array_equal(sample["point_times"], sample["points"][:, 0])
    assert "point_times" not in voxeliser(points, "000001")


def test_a_kitti_folder_gives_its_time_offsets_with_its_valid_points(tmp_path):
    layout = KittiLayout(tmp_path / "sim")
    points = np.array([[5, 0, 1, 0], [6, 0, 1, 0], [0, 0, 0, 0], [7, 0, 1, 0]], np.float32)
    times = np.array([0.1, 0.2, 0.3, 0.35], np.float32)  # the all-zero point is dropped on reading, with its time
    write_frame(layout, "000000", points, [], np.zeros((0, 7)), {}, time_offset=times)
    write_frame(layout, "000001", points[:2], [], np.zeros((0, 7)), {})  # no time offsets
    timed, untimed = (frame.load() for frame in list_frames("kitti", tmp_path / "sim"))
    assert timed.dropped == 1 and timed.time_offsets().tolist() == pytest.approx([0.0, 0.1, 0.25])
    assert untimed.time_offsets() is None and len(untimed.points) == 2


def test_a_checkpoint_of_another_grid_is_refused_and_nothing_is_written(tmp_path, frames_folder):
    paper = untrained_checkpoint(tmp_path / "paper.pth", "paper")
    cfg = load_config(REPO_CFG, profile="smoke")
    out = tmp_path / "out"
    with pytest.raises(DataFormatError, match="paper.pth.*trained on .*--set PROFILE paper"):
        detect(cfg, paper, DetectOptions(src=frames_folder, out=out))
    assert not out.exists()


def test_a_bad_frame_midway_leaves_no_output(tmp_path, frames_folder, smoke_checkpoint):
    (frames_folder / "003.npy").write_bytes(b"not an array")
    out = tmp_path / "out"
    with pytest.raises(DataFormatError, match="003.npy: not a readable .npy array"):
        detect(load_config(REPO_CFG, profile="smoke"), smoke_checkpoint, DetectOptions(src=frames_folder, out=out))
    assert not out.exists() and written_files(tmp_path / "frames") == ["000.npy", "001.npy", "002.npy", "003.npy"]


@pytest.mark.parametrize("files, message", [(["a.txt", "b.txt"], r"cannot tell the format \(found .txt\): pass "
                                                                  "--format"),
                                            (["a.npy", "b.pcd"], "cannot tell the format")])
def test_unknown_or_mixed_formats_are_refused(tmp_path, smoke_checkpoint, files, message):
    folder = tmp_path / "src"
    folder.mkdir()
    for name in files:
        (folder / name).write_text("x")
    with pytest.raises(DataFormatError, match=message) as error:
        detect(load_config(REPO_CFG, profile="smoke"), smoke_checkpoint, DetectOptions(src=folder,
                                                                                       out=tmp_path / "out"))
    assert str(folder) in str(error.value)


def test_cli_errors_name_the_file(tmp_path, frames_folder, smoke_checkpoint, capsys):
    zones = tmp_path / "zones.yaml"
    zones.write_text("zones:\n  - {name: x, level: warning, polygon: [[0, 0], [2, 2], [2, 0], [0, 2]]}\n")
    with pytest.raises(SystemExit) as error:
        cli.main(["detect", "--cfg", REPO_CFG, "--profile", "smoke", "--ckpt", str(smoke_checkpoint), "--src",
                  str(frames_folder), "--zones", str(zones), "--out", str(tmp_path / "out")])
    assert error.value.code == 2
    assert f"{zones}" in capsys.readouterr().err and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_recordings_out_of_time_order_are_refused(tmp_path, bundled_asset, smoke_checkpoint):
    recording = bundled_asset(RECORDING, RECORDING_SHA256)
    folder = tmp_path / "recordings"
    folder.mkdir()
    for name in ("a.bfpc", "b.bfpc"):  # the same recording twice: b starts again at a's first time stamp
        (folder / name).write_bytes(recording.read_bytes())
    out = tmp_path / "out"
    with pytest.raises(DataFormatError, match=r"frame b.bfpc#0 starts 1.222 s before the frame listed before it"):
        detect(load_config(REPO_CFG, profile="smoke"), smoke_checkpoint,
               DetectOptions(src=folder, out=out, mount=None, estimate_ground=True))
    assert not out.exists()


@pytest.mark.slow
def test_batched_frames_give_the_detections_of_single_frames(tmp_path, bundled_asset, smoke_checkpoint):
    """The CPU default (one frame per forward pass) and a GPU-style batch keep the same boxes; every box is kept
    (score thresholds 0) so that an untrained model has detections to compare."""
    cfg = load_config(REPO_CFG, ["MODEL.POST_PROCESSING.SCORE_THRESH", "0.0"], "smoke")
    cfg.TRACKER = {"MIN_SCORE": 0.0}  # the optional block (monitor/tracker.py)
    recording = bundled_asset(RECORDING, RECORDING_SHA256)
    records = {}
    for batch_size in (None, 4):
        out = tmp_path / f"batch_{batch_size}"
        summary = detect(cfg, smoke_checkpoint, DetectOptions(src=recording, out=out, estimate_ground=True,
                                                              batch_size=batch_size))
        assert summary["batch_size"] == (batch_size or 1)
        records[batch_size] = [json.loads(line) for line in (out / "detections.jsonl").read_text().splitlines()]
    single, batched = records[None], records[4]
    assert sum(len(r["detections"]) for r in single) >= 10
    for one, four in zip(single, batched, strict=True):
        assert len(one["detections"]) == len(four["detections"])
        for a, b in zip(one["detections"], four["detections"]):
            np.testing.assert_allclose(a["box"] + [a["score"]], b["box"] + [b["score"]], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("period", ["inf", "nan", "0"])
def test_a_frame_period_that_is_not_a_finite_positive_number_is_refused_in_one_line(tmp_path, capsys, period):
    with pytest.raises(SystemExit) as error:
        cli.main(["detect", "--cfg", REPO_CFG, "--ckpt", "none.pth", "--src", str(tmp_path), "--frame-period", period,
              "--out", str(tmp_path / "out")])
    assert error.value.code == 2
    assert capsys.readouterr().err.strip() == ("memslidar detect: error: --batch-size must be >= 1 and --frame-period "
                                                "a finite number of seconds > 0")


def test_a_time_unit_times_the_frames_of_a_folder_and_is_refused_for_a_kitti_layout(tmp_path, smoke_checkpoint):
    (tmp_path / "npy").mkdir()
    np.save(tmp_path / "npy" / "0.npy", np.array([[5.0, 0.0, 1.0, 3.0, 1e9], [6.0, 0.0, 1.0, 4.0, 1.1e9]]))  # [ns]
    frame, = list_frames("npy", tmp_path / "npy", time_unit_s=1e-9)
    np.testing.assert_array_equal(frame.load().time_offsets(), np.array([0.0, 0.1], np.float32))
    assert list_frames("npy", tmp_path / "npy")[0].load().time_offsets() is None
    assert cli.main(["detect", "--cfg", REPO_CFG, "--profile", "smoke", "--ckpt", str(smoke_checkpoint), "--src",
                     str(tmp_path / "npy"), "--time-unit", "ns", "--out", str(tmp_path / "out")]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["frames_with_point_times"] == 1
    with pytest.raises(ConfigError, match="format kitti records the unit of its point times; drop --time-unit"):
        list_frames("kitti", tmp_path, time_unit_s=1e-9)


@pytest.fixture(scope="module")
def simulated_sequence(tmp_path_factory):
    """Six consecutive simulated frames of the industrial domain: a KITTI layout with the points' time offsets."""
    out = tmp_path_factory.mktemp("sim") / "industrial"
    simulate_sequence_dataset(get_domain("industrial"), 6, out, seed=0, progress=False)
    return out


def every_box_cfg():
    """The smoke config keeping every box (score thresholds 0), so that an untrained model has tracks and events."""
    cfg = load_config(REPO_CFG, ["MODEL.POST_PROCESSING.SCORE_THRESH", "0.0"], "smoke")
    cfg.TRACKER = {"MIN_SCORE": 0.0}
    return cfg


def read_mcap(path) -> dict[str, list]:
    """{topic: [(log time [ns], message), ...]} of an MCAP file, decoded with the definitions it carries."""
    topics = {}
    with AnyReader([path]) as reader:
        for connection, stamp_ns, raw in reader.messages():
            topics.setdefault(connection.topic, []).append((stamp_ns, reader.deserialize(raw, connection.msgtype)))
    return topics


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_bag_of_simulated_frames_gives_the_detections_of_its_kitti_layout_and_an_mcap_of_them(
        tmp_path, simulated_sequence, smoke_checkpoint, storage):
    bag = tmp_path / "bag"
    assert cli.main(["export-bag", "--src", str(simulated_sequence), "--out", str(bag), "--storage", storage,
                     "--topic", "/cube/points"]) == 0
    zones = tmp_path / "zones.yaml"
    zones.write_text("zones:\n  - {name: hall, level: warning, polygon: [[0, -50], [60, -50], [60, 50], [0, 50]]}\n"
                     "  - {name: door, level: protective, polygon: [[0, -20], [20, -20], [20, -15], [0, -15]]}\n")
    records = {}
    for name, src in (("kitti", simulated_sequence), ("bag", bag)):
        out = tmp_path / f"detect_{name}"
        summary = detect(every_box_cfg(), smoke_checkpoint, DetectOptions(src=src, out=out, zones=read_zones(zones),
                                                                          mcap=tmp_path / f"{name}.mcap"))
        assert summary["frames_with_point_times"] == 6 and summary["mcap"] == str(tmp_path / f"{name}.mcap")
        records[name] = [json.loads(line) for line in (out / "detections.jsonl").read_text().splitlines()]
    assert [r["source"] for r in records["bag"]] == [f"bag#{k}" for k in range(6)]
    for record in records["kitti"] + records["bag"]:
        del record["source"]
    assert records["bag"] == records["kitti"]  # boxes, scores, tracks, zones, events and times, to the written digits
    assert sum(len(r["events"]) for r in records["bag"]) > 0
    topics = read_mcap(tmp_path / "bag.mcap")
    assert sorted(topics) == ["/memslidar/detections", "/memslidar/events", "/memslidar/markers"]  # no points
    stamps = [frame.stamp_ns for frame in list_frames("rosbag2", bag)]  # the input's header stamps
    for messages in topics.values():
        assert [stamp for stamp, _ in messages] == stamps
    for record, (_, found), (_, events), (_, markers) in zip(records["bag"], topics["/memslidar/detections"],
                                                             topics["/memslidar/events"], topics["/memslidar/markers"],
                                                             strict=True):
        assert len(found.detections) == len(record["detections"]) and json.loads(events.data) == record["events"]
        for detection, expected in zip(found.detections, record["detections"]):
            box = detection.bbox
            heading = 2 * np.arctan2(box.center.orientation.z, box.center.orientation.w)
            assert [box.center.position.x, box.center.position.y, box.center.position.z, box.size.x, box.size.y,
                    box.size.z] == expected["box"][:6]
            turn = (heading - expected["box"][6] + np.pi) % (2 * np.pi) - np.pi  # a quaternion: the heading mod 2 pi
            assert turn == pytest.approx(0.0, abs=1e-9)
            assert detection.results[0].hypothesis.score == expected["score"]
            assert detection.id == ("" if expected["track_id"] is None else str(expected["track_id"]))
            assert detection.header.frame_id == "lidar"  # export-bag's frame id: no mount, boxes in its frame
        kinds = [(marker.ns, marker.type) for marker in markers.markers]
        assert kinds[0] == ("", 1) and markers.markers[0].action == 3  # DELETEALL first
        assert kinds.count(("boxes", 1)) == len(record["detections"]) and kinds.count(("zones", 4)) == 2
        assert kinds.count(("events", 9)) == len(record["events"])


def test_detect_reads_a_bags_topic_and_writes_its_points_to_the_mcap_only_when_asked(tmp_path, simulated_sequence,
                                                                                     smoke_checkpoint, capsys):
    bag = tmp_path / "bag"
    assert cli.main(["export-bag", "--src", str(simulated_sequence), "--out", str(bag)]) == 0
    detect_cli = ["detect", "--cfg", REPO_CFG, "--profile", "smoke", "--ckpt", str(smoke_checkpoint), "--src",
                  str(bag), "--topic", "/points", "--out", str(tmp_path / "out")]
    assert cli.main([*detect_cli, "--mcap", str(tmp_path / "out" / "ros" / "run.mcap"), "--save-points"]) == 0
    assert f"and {tmp_path / 'out' / 'ros' / 'run.mcap'}" in capsys.readouterr().out
    points = read_mcap(tmp_path / "out" / "ros" / "run.mcap")["/memslidar/points"]  # inside --out: written with it
    np.testing.assert_array_equal(np.frombuffer(points[2][1].data, np.float32).reshape(-1, 4),
                                  np.fromfile(tmp_path / "out" / "points" / "000002.bin", np.float32).reshape(-1, 4))
    for mcap, message in (("run.json", "--mcap run.json: name the file with the suffix .mcap"),
                          (str(bag / "bag.mcap"), f"--mcap .* lies in the input {bag}")):
        with pytest.raises(SystemExit):
            cli.main([*detect_cli, "--mcap", str(mcap)])
        assert re.search(message, capsys.readouterr().err)
    with pytest.raises(SystemExit):
        cli.main([*detect_cli[:-4], "--topic", "/lidar", "--out", str(tmp_path / "out2")])
    assert f"{bag}: topic /lidar is not in it; its PointCloud2 topics: /points" in capsys.readouterr().err
    assert not (tmp_path / "out2").exists()
