"""The MCAP file of `memslidar detect --mcap` (monitor.mcap_out) on made-up frames: what RViz and Foxglove draw, the
mount as a transform, points only when asked, and a file that is whole or not there."""
import json

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.monitor.mcap_out import COLOURS, GROUND_FRAME, mcap_out
from pcdet_memslidar.monitor.zones import Zone

ZONES = [Zone("press", "protective", np.array([[3.0, -1.0], [6.0, -1.0], [6.0, 1.5], [3.0, 1.5]]))]
EVENT = {"event": "enter", "zone": "press", "level": "protective", "track_id": 2, "time_s": 0.4}
RECORDS = [  # two frames of detections.jsonl
    {"frame": "000000", "source": "a#0", "time_s": 0.0, "events": [],
     "detections": [{"box": [8.0, 3.0, 0.9, 0.7, 0.6, 1.8, 0.5], "score": 0.4, "track_id": None, "zones": []}]},
    {"frame": "000001", "source": "a#1", "time_s": 0.4, "events": [EVENT],
     "detections": [{"box": [4.0, 0.0, 0.9, 0.7, 0.6, 1.8, -1.0], "score": 0.8, "track_id": 2, "zones": ["press"]}]},
]


def read(path) -> dict[str, list]:
    with AnyReader([path]) as reader:
        topics = {}
        for connection, stamp_ns, raw in reader.messages():
            topics.setdefault(connection.topic, []).append((stamp_ns, reader.deserialize(raw, connection.msgtype)))
    return topics


def test_boxes_zones_events_and_the_mount_as_rviz_and_foxglove_draw_them(tmp_path):
    mount = Mount(height=3.2, tilt_deg=12.0, roll_deg=1.5)
    points = np.array([[5.0, 0.0, 1.0, 10.0], [6.0, 1.0, 0.5, 20.0]], np.float32)
    path = tmp_path / "run.mcap"
    with mcap_out(path, ZONES, mount, save_points=True) as write:
        for index, record in enumerate(RECORDS):
            write(record, points * (index + 1), 10 ** 18 + index * 400_000_000, "cube")
    topics = read(path)
    assert sorted(topics) == ["/memslidar/detections", "/memslidar/events", "/memslidar/markers",
                              "/memslidar/points", "/tf"]
    assert [stamp for stamp, _ in topics["/tf"]] == [10 ** 18, 10 ** 18 + 400_000_000]
    _, tf = topics["/tf"][1]
    transform = tf.transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id) == (GROUND_FRAME, "cube")
    rotation = transform.transform.rotation
    quaternion = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w])
    np.testing.assert_allclose(quaternion.apply([1.0, 0.0, 0.0]), mount.rotation @ [1.0, 0.0, 0.0], atol=1e-12)
    assert transform.transform.translation.z == 3.2
    _, cloud = topics["/memslidar/points"][1]
    assert cloud.header.frame_id == GROUND_FRAME and cloud.width == 2
    np.testing.assert_array_equal(np.frombuffer(cloud.data, np.float32).reshape(-1, 4), points * 2)
    (_, first), (_, second) = topics["/memslidar/markers"]
    boxes = [marker for marker in second.markers if marker.ns == "boxes"]
    assert len(boxes) == 1 and boxes[0].header.frame_id == GROUND_FRAME
    colour = boxes[0].color
    assert (colour.r, colour.g, colour.b, colour.a) == pytest.approx(COLOURS["protective"])  # in the press
    tentative = next(marker for marker in first.markers if marker.ns == "boxes").color
    assert (tentative.r, tentative.g, tentative.b, tentative.a) == pytest.approx(COLOURS["tentative"])
    assert [marker.text for marker in second.markers if marker.ns in ("labels", "events", "zone_names")] == [
        "#2 0.80", "press", "enter press: track 2"]
    outline = next(marker for marker in second.markers if marker.ns == "zones").points
    assert [(p.x, p.y) for p in outline] == [(3.0, -1.0), (6.0, -1.0), (6.0, 1.5), (3.0, 1.5), (3.0, -1.0)]
    assert [json.loads(message.data) for _, message in topics["/memslidar/events"]] == [[], [EVENT]]


def test_a_run_that_fails_leaves_no_file_and_no_leftovers(tmp_path):
    path = tmp_path / "run.mcap"
    path.write_bytes(b"an earlier run")
    with pytest.raises(RuntimeError), mcap_out(path, [], None, save_points=False) as write:
        write(RECORDS[0], np.zeros((0, 4), np.float32), 0, None)
        raise RuntimeError("frame 2 cannot be read")
    assert path.read_bytes() == b"an earlier run" and sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]
    with mcap_out(path, [], None, save_points=False) as write:
        write(RECORDS[0], np.zeros((0, 4), np.float32), 0, None)
    assert [message.header.frame_id for _, message in read(path)["/memslidar/detections"]] == ["lidar"]
