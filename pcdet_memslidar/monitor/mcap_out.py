"""`memslidar detect --mcap FILE`: the run's detections as an MCAP file of ROS 2 messages, for RViz and Foxglove
(visualization_msgs, drawn without plugins) and for programs (vision_msgs), written with io.rosbag's writer.

Per frame, stamped with the frame's recorded time (a bag's header stamp, a .bfpc frame's start; else its time since
the first frame), one message on each topic:

    /memslidar/markers     visualization_msgs/msg/MarkerArray  a DELETEALL (the frame before is cleared), then the
                                                               boxes (CUBE: red in a protective zone, orange in a
                                                               warning zone, green elsewhere, grey while tentative),
                                                               their track id and score, the zones' outlines and
                                                               names, and the frame's events (TEXT_VIEW_FACING)
    /memslidar/detections  vision_msgs/msg/Detection3DArray    the boxes: class_id Pedestrian, score, id = the track
                                                               id ('' while tentative)
    /memslidar/events      std_msgs/msg/String                 the frame's events: the JSON list of detections.jsonl
    /tf                    tf2_msgs/msg/TFMessage              with a mount only: GROUND_FRAME -> the recording's frame
    /memslidar/points      sensor_msgs/msg/PointCloud2         with --save-points only: the points the detector saw

The values are those of detections.jsonl. Boxes, zones and points are in the frame the detector saw the points in:
GROUND_FRAME where a mount brought them into the ground frame, else the recording's frame_id (SENSOR_FRAME where
the format has none). vision_msgs is not among rosbags' built-in types: its messages (vision_msgs 4, as in ROS 2
Humble and later) are registered from their definitions below. FILE is written in a temporary folder beside it and
renamed onto it at the end: it is whole, or untouched.
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from rosbags.typesys import get_types_from_msg
from scipy.spatial.transform import Rotation

from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io.kitti import CLASS_NAME
from pcdet_memslidar.io.rosbag import bag_writer, cloud_message, header, typestore
from pcdet_memslidar.monitor.zones import Zone
from pcdet_memslidar.utils.atomic import scratch_dir

GROUND_FRAME, SENSOR_FRAME = "memslidar_ground", "lidar"
MARKERS, DETECTIONS, EVENTS, TF, POINTS = ("/memslidar/markers", "/memslidar/detections", "/memslidar/events", "/tf",
                                           "/memslidar/points")
VISION_MSGS = {  # vision_msgs 4 (ROS 2 Humble and later), the messages of a Detection3DArray
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\nBoundingBox3D bbox\n"
                                   "string id\n",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nDetection3D[] detections\n",
}
COLOURS = {"protective": (1.0, 0.1, 0.1, 0.6), "warning": (1.0, 0.6, 0.0, 0.6), None: (0.1, 0.8, 0.2, 0.6),
           "tentative": (0.6, 0.6, 0.6, 0.3), "text": (1.0, 1.0, 1.0, 1.0)}  # RGBA of markers by zone level
TEXT_M = 0.3  # height of the text markers [m]
CUBE, LINE_STRIP, TEXT, DELETEALL = 1, 4, 9, 3  # visualization_msgs/msg/Marker's type and action numbers


@contextlib.contextmanager
def mcap_out(path: Path, zones: list[Zone], mount: Mount | None, save_points: bool
             ) -> Iterator[Callable[[dict, np.ndarray, int, str | None], None]]:
    """Write the MCAP file `path` (module docstring); yields write(record, points, stamp_ns, frame_id) for one frame:
    its detections.jsonl record, its points (N, 4) as the detector saw them (written with save_points only), its
    stamp [ns since the epoch] and its recording's frame_id (None: the format has none)."""
    for msgtype, text in VISION_MSGS.items():
        typestore().register(get_types_from_msg(text, msgtype))
    with scratch_dir(path) as scratch:
        with bag_writer(scratch / "bag", "mcap") as write:
            def write_frame(record: dict, points: np.ndarray, stamp_ns: int, frame_id: str | None) -> None:
                sensor = frame_id or SENSOR_FRAME
                frame = GROUND_FRAME if mount is not None else sensor
                write(MARKERS, _markers(record, zones, header(stamp_ns, frame)), stamp_ns)
                write(DETECTIONS, _detections(record, header(stamp_ns, frame)), stamp_ns)
                write(EVENTS, _type("std_msgs/msg/String")(data=json.dumps(record["events"])), stamp_ns)
                if mount is not None:
                    write(TF, _transform(mount, header(stamp_ns, GROUND_FRAME), sensor), stamp_ns)
                if save_points:
                    write(POINTS, cloud_message(points, stamp_ns, frame), stamp_ns)
            yield write_frame
        os.replace(scratch / "bag" / "bag.mcap", path)


def _type(msgtype: str):
    return typestore().types[msgtype]


def _vector(x: float, y: float, z: float):
    return _type("geometry_msgs/msg/Vector3")(x=float(x), y=float(y), z=float(z))


def _pose(x: float, y: float, z: float, heading: float = 0.0):
    """A geometry_msgs/msg/Pose at x, y, z [m], turned by `heading` [rad] about z."""
    position = _type("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=float(z))
    turn = _type("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=float(np.sin(heading / 2)),
                                                 w=float(np.cos(heading / 2)))
    return _type("geometry_msgs/msg/Pose")(position=position, orientation=turn)


def _marker(head, ns: str, index: int, kind: int, pose, scale, colour, points=(), text: str = "", action: int = 0):
    """A visualization_msgs/msg/Marker: no lifetime (the next frame's DELETEALL clears it), no texture or mesh."""
    point, empty = _type("geometry_msgs/msg/Point"), np.zeros(0, np.uint8)
    forever = _type("builtin_interfaces/msg/Duration")(sec=0, nanosec=0)
    return _type("visualization_msgs/msg/Marker")(
        header=head, ns=ns, id=index, type=kind, action=action, pose=pose, scale=_vector(*scale),
        color=_type("std_msgs/msg/ColorRGBA")(*colour), lifetime=forever, frame_locked=False,
        points=[point(x=float(x), y=float(y), z=float(z)) for x, y, z in points], colors=[], texture_resource="",
        texture=_type("sensor_msgs/msg/CompressedImage")(header=head, format="", data=empty), uv_coordinates=[],
        text=text, mesh_resource="", mesh_file=_type("visualization_msgs/msg/MeshFile")(filename="", data=empty),
        mesh_use_embedded_materials=False)


def _markers(record: dict, zones: list[Zone], head):
    """The frame's MarkerArray (module docstring)."""
    levels = {zone.name: zone.level for zone in zones}
    markers = [_marker(head, "", 0, CUBE, _pose(0, 0, 0), (1, 1, 1), COLOURS["text"], action=DELETEALL)]
    for index, detection in enumerate(record["detections"]):
        x, y, z, dx, dy, dz, heading = detection["box"]
        in_levels = {levels[name] for name in detection["zones"]}
        level = "tentative" if detection["track_id"] is None else next(
            (level for level in ("protective", "warning") if level in in_levels), None)
        label = f"{detection['score']:.2f}" if detection["track_id"] is None else \
            f"#{detection['track_id']} {detection['score']:.2f}"
        markers += [_marker(head, "boxes", index, CUBE, _pose(x, y, z, heading), (dx, dy, dz), COLOURS[level]),
                    _marker(head, "labels", index, TEXT, _pose(x, y, z + dz / 2 + TEXT_M), (0, 0, TEXT_M),
                            COLOURS["text"], text=label)]
    centres = {zone.name: zone.polygon.mean(axis=0) for zone in zones}
    for index, zone in enumerate(zones):
        outline = [(x, y, 0.02) for x, y in (*zone.polygon, zone.polygon[0])]
        markers += [_marker(head, "zones", index, LINE_STRIP, _pose(0, 0, 0), (0.05, 0, 0), COLOURS[zone.level],
                            points=outline),
                    _marker(head, "zone_names", index, TEXT, _pose(*centres[zone.name], TEXT_M), (0, 0, TEXT_M),
                            COLOURS[zone.level], text=zone.name)]
    for index, event in enumerate(record["events"]):
        text = f"{event['event']} {event['zone']}: track {event['track_id']}" + (
            f" ({event['reason']})" if "reason" in event else "")
        markers.append(_marker(head, "events", index, TEXT, _pose(*centres[event["zone"]], (index + 2) * TEXT_M),
                               (0, 0, TEXT_M), COLOURS[event["level"]], text=text))
    return _type("visualization_msgs/msg/MarkerArray")(markers=markers)


def _detections(record: dict, head):
    """The frame's Detection3DArray: per box its centre pose, size, score and track id."""
    detections = []
    for detection in record["detections"]:
        x, y, z, dx, dy, dz, heading = detection["box"]
        pose = _pose(x, y, z, heading)
        hypothesis = _type("vision_msgs/msg/ObjectHypothesisWithPose")(
            hypothesis=_type("vision_msgs/msg/ObjectHypothesis")(class_id=CLASS_NAME, score=detection["score"]),
            pose=_type("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=np.zeros(36)))
        detections.append(_type("vision_msgs/msg/Detection3D")(
            header=head, results=[hypothesis],
            bbox=_type("vision_msgs/msg/BoundingBox3D")(center=pose, size=_vector(dx, dy, dz)),
            id="" if detection["track_id"] is None else str(detection["track_id"])))
    return _type("vision_msgs/msg/Detection3DArray")(header=head, detections=detections)


def _transform(mount: Mount, head, sensor: str):
    """A TFMessage of the sensor's pose in the ground frame (the mount: sensor -> ground)."""
    x, y, z, w = Rotation.from_matrix(mount.rotation).as_quat()
    transform = _type("geometry_msgs/msg/Transform")(
        translation=_vector(*mount.origin),
        rotation=_type("geometry_msgs/msg/Quaternion")(x=float(x), y=float(y), z=float(z), w=float(w)))
    stamped = _type("geometry_msgs/msg/TransformStamped")(header=head, child_frame_id=sensor, transform=transform)
    return _type("tf2_msgs/msg/TFMessage")(transforms=[stamped])
