"""ROS 2 bags: their sensor_msgs/msg/PointCloud2 messages read as frames, and frames written as such messages, with
the `rosbags` library (pure Python: no ROS installation).

A bag is a rosbag2 folder (metadata.yaml beside .db3 or .mcap files: sqlite3 or MCAP storage) or a bare .mcap or
.db3 file. Reading (io.formats' 'rosbag2') takes the bag's only PointCloud2 topic, or the one named (--topic); per
message its header stamp [ns], its frame_id and its points as columns by name for io.pointclouds.cloud_from_fields
(x, y, z, intensity or reflectivity, a time field; NaN / zero points dropped and counted). Organised (height > 1)
and unorganised clouds, either byte order and padding inside point_step or at the end of rows are read. The unit
of the time field (io.pointclouds.TIME_FIELDS: `t`, `time`, `timestamp`, `offset_time`, ...) follows its datatype:
integers are nanoseconds (Ouster's `t`, Livox's `offset_time`), float32 seconds (Velodyne's `time`); float64 is
seconds for some drivers (Hesai, RoboSense) and nanoseconds for others (Livox), so its times are used only with
--time-unit, which, given, applies to a time field of any datatype. A bag is read twice, to list its frames (all
layouts checked) and to load them, so that its length does not matter: it is held in memory one message (MCAP: one
chunk) at a time. Errors (DataFormatError) name the file, the topic and the message index, counting from 0.

Writing: bag_writer (messages of any type, by topic), cloud_message (points as a PointCloud2) and export_bag
(frames -> a rosbag2 folder: `memslidar export-bag`).
"""
from __future__ import annotations

import contextlib
import functools
import itertools
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.frames import SequentialReader, SourceFrame, frame_stamp_ns
from pcdet_memslidar.io.pointclouds import LoadedCloud, cloud_from_fields, time_field
from pcdet_memslidar.utils.atomic import atomic_dir
from pcdet_memslidar.utils.progress import progress_bar

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
BAG_SUFFIXES = (".mcap", ".db3")  # the storage files of a rosbag2 folder, and the bare bags read
STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}  # sensor_msgs/msg/PointField
EXPORT_COMMAND = "memslidar export-bag"  # the owner of the bag folders export_bag writes (utils.atomic.atomic_dir)
DAMAGED = ("the bag is truncated or damaged: record it again, or repair it (`ros2 bag reindex` for a rosbag2 folder, "
           "`mcap recover` for an .mcap file)")


@functools.cache
def typestore() -> Typestore:
    """The message types read and written: ROS 2 Humble's (rosbags' built-in definitions)."""
    return get_typestore(Stores.ROS2_HUMBLE)


def is_bag(folder: Path) -> bool:
    """Whether `folder` is a rosbag2 folder: metadata.yaml and at least one .db3 or .mcap file (maybe .zstd)."""
    return (folder / "metadata.yaml").is_file() and any(set(path.suffixes) & set(BAG_SUFFIXES)
                                                         for path in folder.iterdir())


# ---------------------------------------------------------------- reading
def read_bag(path: Path, topic: str | None = None, time_unit_s: float | None = None) -> list[SourceFrame]:
    """The frames of the PointCloud2 topic `topic` (None: the bag's only one) of the bag `path`, in the bag's order,
    named '<bag>#<index>', with their header stamps and frame ids; every message's layout is checked here, and its
    cloud read again and decoded when loaded (BagMessages), so that a bag of any length fits in memory.
    time_unit_s: seconds per unit of the time field (None: from its datatype, module docstring)."""
    with contextlib.closing(_opened(path)) as reader:
        connections = _topic_connections(reader, path, topic)
        messages = BagMessages(path, connections[0].topic)
        frames = []
        for index, raw in _raw_messages(reader, connections, path, messages.topic):
            message, _ = messages.decode(index, raw)
            stamp_ns = message.header.stamp.sec * 10 ** 9 + message.header.stamp.nanosec
            frames.append(SourceFrame(f"{path.name}#{index}", functools.partial(messages.cloud, index, time_unit_s),
                                      stamp_ns=stamp_ns, frame_id=message.header.frame_id))
    if not frames:
        raise DataFormatError(path, f"topic {messages.topic} holds no messages: give a bag with at least one point "
                                    "cloud")
    return frames


class BagMessages:
    """The PointCloud2 messages of one topic of a bag by index, decoded for listing and again for loading its frames
    (io.frames.SequentialReader: one open reader, in order). Reading a message twice costs less than keeping a
    bag's messages (benchmarks.md)."""

    def __init__(self, path: Path, topic: str):
        self.path, self.topic = path, topic
        self.raw = SequentialReader(self._open_messages, lambda index: DataFormatError(
            self._where(index), "is gone: the bag changed after it was listed; read it again"))

    def decode(self, index: int, raw: bytes) -> tuple[object, np.dtype]:
        """The PointCloud2 of message `index` and its points' record (_point_dtype: the layout checked); its data is
        a view of `raw`, not a copy."""
        where = self._where(index)
        try:
            message = typestore().deserialize_cdr(memoryview(raw), POINTCLOUD2)
        except Exception as error:  # rosbags' decoder on damaged bytes (SerdeError, struct's, unicode's)
            raise DataFormatError(where, f"cannot be decoded as a PointCloud2 ({error}): {DAMAGED}") from None
        return message, _point_dtype(message, where)

    def cloud(self, index: int, time_unit_s: float | None) -> LoadedCloud:
        """The cloud of message `index` (time_unit_s: read_bag's)."""
        return _cloud(*self.decode(index, self.raw.item(index)), self._where(index), time_unit_s)

    def _open_messages(self) -> tuple[Iterator[tuple[int, bytes]], Callable[[], None]]:
        reader = _opened(self.path)
        return _raw_messages(reader, _topic_connections(reader, self.path, self.topic), self.path,
                             self.topic), reader.close

    def _where(self, index: int) -> str:
        return f"{self.path}: topic {self.topic}, message {index}"


def _opened(path: Path) -> Reader:
    """rosbags' reader of the bag `path`, open; DataFormatError naming the file where it cannot be opened."""
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # rosbags' ReaderError, and sqlite's or the MCAP parser's errors on damaged files
        raise DataFormatError(path, f"cannot be opened as a ROS 2 bag ({error}): {DAMAGED}") from None
    return reader


def _topic_connections(reader: Reader, path: Path, topic: str | None) -> list:
    """The bag's connections of the PointCloud2 topic `topic` (None: its only one); DataFormatError listing the
    PointCloud2 topics where there is none, several or not the one named."""
    clouds = sorted({connection.topic for connection in reader.connections if connection.msgtype == POINTCLOUD2})
    if topic is None and len(clouds) != 1:
        if not clouds:
            others = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            raise DataFormatError(path, f"holds no {POINTCLOUD2} messages (its topics: {others}): record the "
                                        "LiDAR's point-cloud topic")
        raise DataFormatError(path, f"holds {len(clouds)} PointCloud2 topics ({', '.join(clouds)}): name one with "
                                    "--topic (in a site file: background.topic)")
    if topic is not None and topic not in clouds:
        types = {connection.topic: connection.msgtype for connection in reader.connections}
        what = f"is of type {types[topic]}" if topic in types else "is not in it"
        raise DataFormatError(path, f"topic {topic} {what}; its PointCloud2 topics: {', '.join(clouds) or 'none'}")
    topic = topic or clouds[0]
    return [c for c in reader.connections if c.topic == topic and c.msgtype == POINTCLOUD2]


def _raw_messages(reader: Reader, connections: list, path: Path, topic: str) -> Iterator[tuple[int, bytes]]:
    """(index, serialised message) of the connections' messages; DataFormatError naming the message at which the
    bag cannot be read on."""
    messages = reader.messages(connections=connections)
    for index in itertools.count():
        try:
            _, _, raw = next(messages)
        except StopIteration:
            return
        except Exception as error:  # the storage's parser on damaged bytes (ReaderError, sqlite's, zstd's, ...)
            raise DataFormatError(path, f"topic {topic}, message {index}: cannot be read ({error}): {DAMAGED}"
                                  ) from None
        yield index, raw


def _point_dtype(message, where: str) -> np.dtype:
    """The numpy record of one point of the PointCloud2 `message`: its single-valued fields at their offsets in
    point_step bytes; DataFormatError (where: file, topic, message) for a layout that does not fit its data."""
    order = ">" if message.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for field in message.fields:
        if field.datatype not in DATATYPES:
            raise DataFormatError(where, f"field {field.name!r} has datatype {field.datatype}, which "
                                         "sensor_msgs/msg/PointField does not define (1 to 8)")
        end = field.offset + np.dtype(DATATYPES[field.datatype]).itemsize * field.count
        if end > message.point_step:
            raise DataFormatError(where, f"field {field.name!r} ends at byte {end} of a point but point_step is "
                                         f"{message.point_step}: point_step does not match the fields (fix the "
                                         "recorder's driver, or record again)")
        if field.count == 1 and field.name not in names:
            names.append(field.name)
            formats.append(order + DATATYPES[field.datatype])
            offsets.append(field.offset)
    missing = [axis for axis in "xyz" if axis not in {name.lower() for name in names}]
    if missing:
        raise DataFormatError(where, f"no field(s) {', '.join(missing)}; the message has "
                                     f"{', '.join(field.name for field in message.fields) or 'none'}: a point "
                                     "cloud needs x, y and z (record the driver's point-cloud topic)")
    size = message.height * message.row_step
    if message.row_step < message.width * message.point_step or len(message.data) != size:
        raise DataFormatError(where, f"data holds {len(message.data)} bytes for height {message.height} x width "
                                     f"{message.width} points of {message.point_step} bytes in rows of "
                                     f"{message.row_step} bytes ({size} bytes): the message is truncated or its "
                                     "sizes are wrong")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": message.point_step})


def _cloud(message, dtype: np.dtype, where: str, time_unit_s: float | None) -> LoadedCloud:
    """The cloud of the PointCloud2 `message` with points of `dtype`, rows first (an organised cloud's padding at
    the end of its rows left out)."""
    rows = np.asarray(message.data, np.uint8).reshape(message.height, message.row_step)
    points = np.ascontiguousarray(rows[:, :message.width * message.point_step]).view(dtype).reshape(-1)
    columns = {name: points[name] for name in dtype.names}
    time_name = time_field(columns)
    if time_unit_s is None and time_name is not None:
        kind, size = dtype[time_name].kind, dtype[time_name].itemsize
        time_unit_s = 1e-9 if kind in "iu" else 1.0 if size == 4 else None  # float64: s or ns, --time-unit says
    return cloud_from_fields(columns, where, time_unit_s)


# ---------------------------------------------------------------- writing
def header(stamp_ns: int, frame_id: str):
    """A std_msgs/msg/Header of the time `stamp_ns` [ns since the epoch] in the frame `frame_id`."""
    types = typestore().types
    stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10 ** 9, nanosec=stamp_ns % 10 ** 9)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def cloud_message(points: np.ndarray, stamp_ns: int, frame_id: str, time_s: np.ndarray | None = None):
    """A PointCloud2 of points (N, 4) x, y, z, intensity and, if given, their times (N,) [s] as the field `time`
    (Velodyne's driver's name and unit), all float32: unorganised (height 1), little-endian."""
    names = ["x", "y", "z", "intensity", *(["time"] if time_s is not None else [])]
    columns = [points[:, :4], *([time_s[:, None]] if time_s is not None else [])]
    data = np.ascontiguousarray(np.concatenate(columns, axis=1), "<f4").reshape(-1).view(np.uint8)
    field = typestore().types["sensor_msgs/msg/PointField"]
    return typestore().types[POINTCLOUD2](
        header=header(stamp_ns, frame_id), height=1, width=len(points),
        fields=[field(name=name, offset=4 * k, datatype=7, count=1) for k, name in enumerate(names)],
        is_bigendian=False, point_step=4 * len(names), row_step=4 * len(names) * len(points), data=data,
        is_dense=bool(np.isfinite(points[:, :3]).all()))


@contextlib.contextmanager
def bag_writer(folder: Path, storage: str = "mcap") -> Iterator[Callable[[str, object, int], None]]:
    """Write the new rosbag2 folder `folder` with rosbags' writer (storage 'mcap' or 'sqlite3': the file
    <folder name>.mcap or .db3 beside metadata.yaml); yields write(topic, message, stamp_ns) for messages of the
    types of typestore(), which adds a topic at its first message."""
    connections = {}
    with Writer(folder, version=9, storage_plugin=STORAGES[storage]) as writer:
        def write(topic: str, message, stamp_ns: int) -> None:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=typestore())
            writer.write(connections[topic], stamp_ns, typestore().serialize_cdr(message, message.__msgtype__))
        yield write


def export_bag(frames: list[SourceFrame], out: str | Path, frame_period_s: float, storage: str = "mcap",
               topic: str = "/points", frame_id: str = "lidar") -> int:
    """Write `frames` as PointCloud2 messages (cloud_message: with their points' time offsets [s] where known) on
    `topic` into the rosbag2 folder `out`, replaced whole on success (utils.atomic.atomic_dir); each stamped with
    its recorded time, else its time since the first frame (frame_period_s [s] apart where it has none), in its
    own frame_id, else `frame_id`. Returns the number of frames."""
    out = Path(out)
    with atomic_dir(out, EXPORT_COMMAND) as tmp:
        bag = tmp / out.name  # the writer makes the folder and names its data file after it
        with bag_writer(bag, storage) as write:
            for index, frame in enumerate(progress_bar(frames, desc="export", unit="frame")):
                cloud = frame.load()
                time_s = frame.time_s if frame.time_s is not None else index * frame_period_s
                stamp_ns = frame_stamp_ns(frame, time_s)
                write(topic, cloud_message(cloud.points, stamp_ns, frame.frame_id or frame_id,
                                           cloud.time_offsets()), stamp_ns)
        for path in bag.iterdir():
            path.rename(tmp / path.name)
        bag.rmdir()
    return len(frames)
