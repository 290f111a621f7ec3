"""ROS 2 bags (io.rosbag, registered as the format 'rosbag2'): a bag written by rosbags' own writer with a driver's
PointCloud2 layout imports with its points and times intact; topics are picked or refused by name; damaged bags
and layouts are refused in one line naming the file, the topic and the message; `memslidar export-bag` writes a
KITTI-layout dataset as a bag that reads back the same; a bag is a site's background; a bag is read in memory
that does not grow with its length, its frames loaded in any order."""
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from pcdet_memslidar import cli
from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.io.formats import format_files, get_format, list_frames
from pcdet_memslidar.io.layout import KittiLayout, read_frame, write_frame
from pcdet_memslidar.io.rosbag import cloud_message, typestore
from pcdet_memslidar.monitor.detect import resolve_format
from pcdet_memslidar.sim.composite import read_background
from pcdet_memslidar.sim.site import load_site

TYPES = typestore().types
STAMP_NS = 1_700_000_000 * 10 ** 9  # the first frame's header stamp
PERIOD_NS = 100_000_000  # 10 Hz
DATATYPES = {"f4": 7, "f8": 8, "u4": 6, "u2": 4}  # numpy type -> sensor_msgs/msg/PointField datatype
# An Ouster-like point of 32 bytes: x, y, z, 4 bytes of padding, intensity, t [ns] from the scan start (uint32), ring
DRIVER_POINT = np.dtype({"names": ["x", "y", "z", "intensity", "t", "ring"], "formats": ["f4"] * 4 + ["u4", "u2"],
                         "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})


def driver_points(frame: int) -> np.ndarray:
    """(2, 3) points of an organised cloud (2 rings of 3 points), the middle of ring 0 without return (NaN)."""
    points = np.zeros((2, 3), DRIVER_POINT)
    points["x"] = [[1.5, np.nan, 3.25], [4.5, 5.75, 6.0]]
    points["y"] = [[-0.5, np.nan, 0.25], [0.5, -1.25, 2.0]]
    points["z"] = [[0.125, np.nan, 1.0], [-1.5, 0.75, 0.5]]
    points["intensity"] = [[10.0, 0.0, 12.5], [7.0, 3.0, 255.0]]
    points["t"] = np.array([[0, 25_000, 50_000], [75_000, 100_000, 125_000]]) + 1_000 * frame
    points["ring"] = [[0, 0, 0], [1, 1, 1]]
    return points


def pointcloud2(points: np.ndarray, frame: int = 0, big_endian: bool = False, row_padding: int = 8,
                drop: str | None = None, point_step: int | None = None, data: np.ndarray | None = None):
    """The PointCloud2 of the (H, W) points as a driver publishes it, stamped PERIOD_NS apart: its points' bytes in
    rows of `row_padding` more bytes; a field dropped from the list, another point_step or other data for broken
    messages."""
    if big_endian:
        points = points.astype(points.dtype.newbyteorder(">"))
    height, width = points.shape
    step = points.dtype.itemsize
    rows = np.zeros((height, width * step + row_padding), np.uint8)
    rows[:, :width * step] = points.view(np.uint8).reshape(height, -1)
    fields = [TYPES["sensor_msgs/msg/PointField"](name=name, offset=offset, count=1,
                                                  datatype=DATATYPES[kind.newbyteorder("=").str[1:]])
              for name, (kind, offset) in points.dtype.fields.items() if name != drop]
    stamp_ns = STAMP_NS + frame * PERIOD_NS
    stamp = TYPES["builtin_interfaces/msg/Time"](sec=stamp_ns // 10 ** 9, nanosec=stamp_ns % 10 ** 9)
    return TYPES["sensor_msgs/msg/PointCloud2"](
        header=TYPES["std_msgs/msg/Header"](stamp=stamp, frame_id="os_sensor"), height=height, width=width,
        fields=fields, is_bigendian=big_endian, point_step=point_step or step, row_step=rows.shape[1],
        data=rows.reshape(-1) if data is None else data, is_dense=False)


def write_bag(path: Path, messages: dict[str, list], storage: str = "mcap") -> Path:
    """A rosbag2 folder written by rosbags' own writer: {topic: [message, ...]}, logged 1 ms after their stamps; a
    message given as bytes is written as they are (damaged data), with the type of the topic's first message."""
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        for topic, items in messages.items():
            connection = writer.add_connection(topic, items[0].__msgtype__, typestore=typestore())
            for index, message in enumerate(items):
                raw = message if isinstance(message, bytes) else typestore().serialize_cdr(message, message.__msgtype__)
                writer.write(connection, STAMP_NS + index * PERIOD_NS + 1_000_000, raw)
    return path


def text(words: str):
    return TYPES["std_msgs/msg/String"](data=words)


def import_error(argv: list[str], out: Path, capsys) -> str:
    """The one error line of `memslidar import`, after checking that it wrote nothing."""
    assert cli.main(["import", *argv, "--out", str(out)]) == 1
    error, *rest = capsys.readouterr().err.splitlines()
    assert rest == [f"(nothing was written to {out})"] and not out.exists()
    return error


def driver_bag(path: Path, frames: int = 2, storage: str = "mcap", **options) -> Path:
    """A bag of `frames` driver clouds on /points (pointcloud2 options)."""
    return write_bag(path, {"/points": [pointcloud2(driver_points(k), k, **options) for k in range(frames)]}, storage)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("big_endian", [False, True])
def test_a_driver_like_bag_imports_with_its_points_and_times_intact(tmp_path, storage, big_endian, capsys):
    clouds = [pointcloud2(driver_points(k), k, big_endian) for k in range(2)]
    bag = write_bag(tmp_path / "drive", {"/ouster/points": clouds, "/chatter": [text("not a cloud")]}, storage)
    out = tmp_path / "real"
    assert cli.main(["import", "--format", "rosbag2", "--src", str(bag), "--out", str(out)]) == 0
    assert "imported 2 frames (rosbag2)" in capsys.readouterr().out
    expected = np.array([[1.5, -0.5, 0.125, 10.0], [3.25, 0.25, 1.0, 12.5], [4.5, 0.5, -1.5, 7.0],
                         [5.75, -1.25, 0.75, 3.0], [6.0, 2.0, 0.5, 255.0]], np.float32)  # rows first, NaN dropped
    for frame in range(2):
        stored = read_frame(KittiLayout(out), f"{frame:06d}")
        np.testing.assert_array_equal(stored["points"], expected)
        times = np.fromfile(KittiLayout(out).time_offset(f"{frame:06d}"), np.float32)
        np.testing.assert_array_equal(times, np.array([0, 50e-6, 75e-6, 100e-6, 125e-6], np.float32))  # t in ns
        assert stored["metadata"]["source"] == f"drive#{frame}" and stored["metadata"]["dropped_invalid_points"] == 1
        assert stored["metadata"]["point_time"] == [1000.0 * frame + t for t in (0, 50_000, 75_000, 100_000, 125_000)]
    frames = list_frames("rosbag2", bag)
    assert [f.stamp_ns for f in frames] == [STAMP_NS, STAMP_NS + PERIOD_NS]  # the header stamps, not the log times
    assert [f.time_s for f in frames] == [0.0, PERIOD_NS * 1e-9] and {f.frame_id for f in frames} == {"os_sensor"}


def test_a_bag_is_told_by_its_folder_or_its_mcap_file(tmp_path):
    bag = driver_bag(tmp_path / "drive")
    assert resolve_format(bag, "auto") == "rosbag2" and format_files(bag, get_format("rosbag2")) == [bag]
    bare = tmp_path / "drive.mcap"
    shutil.copy(bag / "drive.mcap", bare)
    assert resolve_format(bare, "auto") == "rosbag2" and list_frames("rosbag2", bare)[1].name == "drive.mcap#1"
    np.testing.assert_array_equal(list_frames("rosbag2", bare)[1].load().points,
                                  list_frames("rosbag2", bag)[1].load().points)


def test_topics_are_picked_by_name_and_several_are_refused_listing_them(tmp_path, capsys):
    clouds = [pointcloud2(driver_points(k), k) for k in range(2)]
    bag = write_bag(tmp_path / "two", {"/front/points": clouds[:1], "/rear/points": clouds, "/chatter": [text("x")]})
    out = tmp_path / "out"
    assert import_error(["--format", "rosbag2", "--src", str(bag)], out, capsys) == (
        f"error: {bag}: holds 2 PointCloud2 topics (/front/points, /rear/points): name one with --topic (in a site "
        "file: background.topic)")
    assert len(list_frames("rosbag2", bag, topic="/rear/points")) == 2
    assert import_error(["--format", "rosbag2", "--src", str(bag), "--topic", "/top/points"], out, capsys) == (
        f"error: {bag}: topic /top/points is not in it; its PointCloud2 topics: /front/points, /rear/points")
    assert import_error(["--format", "rosbag2", "--src", str(bag), "--topic", "/chatter"], out, capsys) == (
        f"error: {bag}: topic /chatter is of type std_msgs/msg/String; its PointCloud2 topics: /front/points, "
        "/rear/points")
    with pytest.raises(ConfigError, match="--topic is for rosbag2 recordings: format npy has no topics; drop --topic"):
        list_frames("npy", tmp_path, topic="/points")


DAMAGED = ("{bag}: cannot be opened as a ROS 2 bag ({why}): the bag is truncated or damaged: record it again, or "
           "repair it (`ros2 bag reindex` for a rosbag2 folder, `mcap recover` for an .mcap file)")


def _cut_off(bag: Path) -> None:
    data = (bag / f"{bag.name}.mcap").read_bytes()
    (bag / f"{bag.name}.mcap").write_bytes(data[:len(data) // 2])  # a recorder that was killed


def _serialised(points: np.ndarray) -> bytes:
    message = pointcloud2(points, 1)
    return bytes(typestore().serialize_cdr(message, message.__msgtype__))


def _overwritten(bag: Path) -> None:
    data = (bag / f"{bag.name}.db3").read_bytes()
    (bag / f"{bag.name}.db3").write_bytes(b"\0" * 100 + data[100:])  # no SQLite header


@pytest.mark.parametrize("make, message", [
    (lambda path: write_bag(path, {"/chatter": [text("x")]}),
     "{bag}: holds no sensor_msgs/msg/PointCloud2 messages (its topics: /chatter (std_msgs/msg/String)): record the "
     "LiDAR's point-cloud topic"),
    (lambda path: write_bag(path, {"/points": [pointcloud2(driver_points(0)),
                                               pointcloud2(driver_points(1), 1, drop="z")]}),
     "{bag}: topic /points, message 1: no field(s) z; the message has x, y, intensity, t, ring: a point cloud needs "
     "x, y and z (record the driver's point-cloud topic)"),
    (lambda path: driver_bag(path, 1, "sqlite3", point_step=20),
     "{bag}: topic /points, message 0: field 't' ends at byte 24 of a point but point_step is 20: point_step does "
     "not match the fields (fix the recorder's driver, or record again)"),
    (lambda path: write_bag(path, {"/points": [pointcloud2(driver_points(0)),
                                               pointcloud2(driver_points(1), 1, data=np.zeros(100, np.uint8))]}),
     "{bag}: topic /points, message 1: data holds 100 bytes for height 2 x width 3 points of 32 bytes in rows of "
     "104 bytes (208 bytes): the message is truncated or its sizes are wrong"),
    (lambda path: write_bag(path, {"/points": [pointcloud2(driver_points(0)), _serialised(driver_points(1))[:60]]}),
     "{bag}: topic /points, message 1: cannot be decoded as a PointCloud2 ({why}): the bag is truncated or damaged: "
     "record it again, or repair it (`ros2 bag reindex` for a rosbag2 folder, `mcap recover` for an .mcap file)"),
    (lambda path: _cut_off(driver_bag(path, 3)) or path, DAMAGED),  # why: the library's words
    (lambda path: _overwritten(driver_bag(path, 3, "sqlite3")) or path, DAMAGED),
])
def test_a_bad_bag_is_refused_in_one_line_naming_file_topic_and_message(tmp_path, capsys, make, message):
    bag = make(tmp_path / "bad")
    out = tmp_path / "out"
    error = import_error(["--format", "rosbag2", "--src", str(bag)], out, capsys)
    assert re.fullmatch(".+".join(map(re.escape, ("error: " + message.format(bag=bag, why="\0")).split("\0"))), error)


def test_a_float64_time_field_is_used_with_its_unit_only(tmp_path):
    """Drivers write float64 times in seconds (Hesai) or in nanoseconds (Livox): --time-unit says which."""
    points = np.zeros((1, 2), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("timestamp", "f8")])
    points["x"], points["timestamp"] = [[5.0, 6.0]], [[1.7e18, 1.7e18 + 51_200]]  # float64 steps 256 ns there
    bag = write_bag(tmp_path / "livox", {"/livox/lidar": [pointcloud2(points)]})
    assert list_frames("rosbag2", bag)[0].load().time_offsets() is None
    np.testing.assert_array_equal(list_frames("rosbag2", bag, time_unit_s=1e-9)[0].load().time_offsets(),
                                  np.array([0.0, 51_200 * 1e-9], np.float32))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_bag_is_read_in_memory_that_does_not_grow_with_its_length(tmp_path, storage, peak_bytes):
    rng = np.random.default_rng(0)
    clouds = [rng.uniform(1, 9, (4000, 4)).astype(np.float32) for _ in range(80)]  # 64 kB messages
    messages = [cloud_message(points, STAMP_NS + k * PERIOD_NS, "cube") for k, points in enumerate(clouds)]
    short, long = (write_bag(tmp_path / name, {"/points": messages[:count]}, storage)
                   for name, count in (("short", 20), ("long", 80)))
    peak = peak_bytes("rosbag2", long)
    assert peak < 1.5 * peak_bytes("rosbag2", short) and peak < sum(len(m.data) for m in messages) / 2  # MCAP: ~a chunk


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_frames_load_the_same_in_any_order_and_a_changed_bag_is_named(tmp_path, storage):
    bag = driver_bag(tmp_path / "drive", 3, storage)
    in_order = [frame.load() for frame in list_frames("rosbag2", bag)]
    frames = list_frames("rosbag2", bag)
    for index in (2, 0, 1, 1):  # back to the start, and the same message twice
        np.testing.assert_array_equal(frames[index].load().points, in_order[index].points)
        np.testing.assert_array_equal(frames[index].load().time, in_order[index].time)
    listed = list_frames("rosbag2", bag)
    shutil.rmtree(bag)
    driver_bag(bag, 2, storage)  # recorded again, shorter, after it was listed
    with pytest.raises(DataFormatError, match=re.escape(f"{bag}: topic /points, message 2: is gone: the bag changed "
                                                        "after it was listed; read it again")):
        listed[2].load()


def kitti_frames(root: Path, count: int = 3) -> list[np.ndarray]:
    """A KITTI layout of `count` frames with time offsets; their points."""
    rng = np.random.default_rng(0)
    clouds = []
    for index in range(count):
        points = np.column_stack([rng.uniform(2, 20, (50, 3)), rng.uniform(0, 255, 50)]).astype(np.float32)
        write_frame(KittiLayout(root), f"{index:06d}", points, [], np.zeros((0, 7)), {},
                    time_offset=np.sort(rng.uniform(0, 0.1, 50)).astype(np.float32))
        clouds.append(points)
    return clouds


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_export_bag_writes_a_kitti_layout_that_reads_back_the_same(tmp_path, storage, capsys):
    kitti_frames(tmp_path / "sim")
    bag = tmp_path / "sim_bag"
    assert cli.main(["export-bag", "--src", str(tmp_path / "sim"), "--out", str(bag), "--storage", storage,
                     "--frame-period", "0.25"]) == 0
    assert "exported 3 frames" in capsys.readouterr().out
    assert sorted(p.name for p in bag.iterdir()) == sorted([".memslidar-output", "metadata.yaml",
                                                            f"sim_bag.{'db3' if storage == 'sqlite3' else 'mcap'}"])
    exported, source = list_frames("rosbag2", bag), list_frames("kitti", tmp_path / "sim")
    for index, (frame, original) in enumerate(zip(exported, source, strict=True)):
        read, expected = frame.load(), original.load()
        np.testing.assert_array_equal(read.points, expected.points)
        np.testing.assert_array_equal(read.time_offsets(), expected.time_offsets())
        assert (frame.stamp_ns, frame.frame_id) == (index * 250_000_000, "lidar")


def test_a_bag_is_a_site_background(tmp_path, real_bfpc):
    frames = [frame.points[frame.first_returns()] for frame in real_bfpc.frames[:2]]
    messages = [cloud_message(points, STAMP_NS + k * PERIOD_NS, "cube") for k, points in enumerate(frames)]
    bag = write_bag(tmp_path / "empty_room", {"/cube/points": messages, "/other/points": messages[:1]})
    site = tmp_path / "room.yaml"
    site.write_text(f"""\
name: room
sensor: {{pattern: cube1_2020, physics: calibrated}}
mount: {{height: 1.6, tilt_deg: 0}}
background: {{recording: {bag}, topic: /cube/points}}
walkable: [[2, -3], [8, -3], [8, 1], [2, 1]]
people: {{count: [1, 1]}}
""")
    loaded = load_site(site)
    assert loaded.background.topic == "/cube/points" and "topic" in loaded.to_dict()["background"]
    for frame, points in zip(read_background(loaded.background, loaded.pattern), frames, strict=True):
        assert frame.returned.sum() == len(points) and frame.source.startswith("empty_room#")
        np.testing.assert_array_equal(np.sort(frame.points[frame.returned, 0]), np.sort(points[:, 0]))
    assert read_background(loaded.background, loaded.pattern)[1].time_s == pytest.approx(0.1)
