"""Reader for Blickfeld .bfpc point-cloud recordings (Cube 1), with no protobuf dependency.

A .bfpc file is a gzip stream of protobuf messages, each preceded by its length as a varint: one
file.PointCloud.Header, then file.PointCloud.Data messages holding a data.Frame each, and a last Data holding the
footer. Field numbers follow Blickfeld's published .proto files (blickfeld-scanner-lib, protocol/blickfeld/):
frames made of scan lines of points (pulses), each point with a time offset, a direction and up to 3 returns. The
stream is decompressed one message at a time (_stream), so a recording is held one frame at a time: read_pulses
checks every frame while listing them and decodes a frame again when it is loaded. The header, footer and each
frame's own fields are read in Python (_fields); the scan lines of a frame, its bulk, by a compiled walk
(_walk_frame) with the same fields, defaults and errors, about 6 ms for a frame of 12,000 pulses.

Everything returned is in KITTI LiDAR axes (x forward, y left, z up); Blickfeld's own frame is y forward, x right,
z up, so x_k = y_b, y_k = -x_b, z_k = z_b, and azimuth is measured from +x_k, positive to the left.
"""
from __future__ import annotations

import contextlib
import functools
import gzip
import itertools
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.frames import PulseFrame, PulseRecording, SequentialReader
from pcdet_memslidar.utils.compiled import kernel

# protobuf wire types
VARINT, FIXED64, LENGTH_DELIMITED, FIXED32 = 0, 1, 2, 5

# what the compiled frame walker (_walk_frame) and _fields report, by status
_OK, _VARINT_CUT, _VARINT_LONG, _WIRE, _PAST_END, _WRONG_TYPE, _NO_XYZ, _FLOAT64 = range(8)
ERRORS = {_VARINT_CUT: "message ends inside a varint (truncated)", _VARINT_LONG: "varint longer than 64 bits",
          _WIRE: "unsupported wire type {} for field {}",
          _PAST_END: "field runs past the end of its message (truncated or not a protobuf message)",
          _WRONG_TYPE: "field '{}' has the wrong wire type (not a Blickfeld point-cloud message)",
          _NO_XYZ: "a return without its 3 cartesian coordinates",
          _FLOAT64: "field '{}' holds 8 bytes where a float32 has 4 (not a Blickfeld point-cloud message)"}
# the fields _walk_frame reads, by the index it reports a wrong wire type with
WALKED_FIELDS = ("scanline.id", "scanline.points", "point.id", "point.returns", "point.start_offset_ns",
                 "point.ambient_light_level", "point.direction", "direction.azimuth", "direction.elevation",
                 "return.id", "return.cartesian", "return.range", "return.intensity")

HARDWARE_VARIANTS = {0: "CUBE_V0_2", 1: "CUBE_V0_3", 2: "APOLLON_A0", 3: "AURORA_P3", 4: "CUBE_V1_0",
                     5: "ALL_HARDWARE", 6: "UNKNOWN_HARDWARE", 7: "NO_HARDWARE", 8: "APOLLON_A1_BDU"}
PULSE_TYPES = {0: "equi_horizontal_angle", 1: "equi_density", 2: "custom", 3: "interleave"}
FRAME_MODES = {0: "none", 1: "combine_up_down", 2: "up", 3: "down", 4: "separate"}


class _WireError(ValueError):
    """Malformed protobuf bytes; turned into a DataFormatError naming the file and the message."""


def _fields(buf: bytes, start: int, end: int) -> dict[int, list]:
    """Parse one message in buf[start:end] into {field number: [values]}, field by field with the compiled walk's
    _field.

    Values: int for varints, bytes for fixed32 / fixed64, (start, end) index pairs for length-delimited fields.
    """
    data = np.frombuffer(buf, np.uint8)
    fields: dict[int, list] = {}
    pos = start
    while pos < end:
        status, number, wire_type, value, value_end, pos = _field(data, pos, end)
        if status:
            raise _WireError(ERRORS[status].format(number, wire_type))  # _WIRE: (wire type, number)
        if wire_type == VARINT:
            value = int(value)
        elif wire_type == LENGTH_DELIMITED:
            value = (int(value), int(value_end))
        else:  # fixed32 / fixed64
            value = bytes(buf[int(value):int(value_end)])
        fields.setdefault(int(number), []).append(value)
    return fields


def _expect(value, kind: type, what: str):
    """Check that a field value has the wire form `kind` (int, bytes or tuple)."""
    if not isinstance(value, kind):
        raise _WireError(ERRORS[_WRONG_TYPE].format(what))
    return value


def _last(fields: dict, number: int, kind: type, what: str, default=None):
    """The last value of a non-repeated field (protobuf semantics), or `default`."""
    values = fields.get(number)
    return default if not values else _expect(values[-1], kind, what)


def _float(fields: dict, number: int, what: str, default: float = float("nan")) -> float:
    raw = _last(fields, number, bytes, what)
    if raw is not None and len(raw) != 4:
        raise _WireError(ERRORS[_FLOAT64].format(what))
    return default if raw is None else struct.unpack("<f", raw)[0]


def _double(fields: dict, number: int, what: str, default: float = float("nan")) -> float:
    raw = _last(fields, number, bytes, what)
    return default if raw is None else struct.unpack("<d", raw)[0]


def _message(buf: bytes, fields: dict, number: int, what: str) -> dict:
    """Parse the last occurrence of a sub-message field ({} when absent)."""
    span = _last(fields, number, tuple, what)
    return {} if span is None else _fields(buf, *span)


def _string(buf: bytes, fields: dict, number: int, what: str) -> str:
    span = _last(fields, number, tuple, what)
    return "" if span is None else bytes(buf[span[0]:span[1]]).decode("utf-8", errors="replace")


@dataclass(frozen=True)
class BfpcScanPattern:
    """Scan-pattern settings stored in a recording (angles in rad; nan / 0 where the file leaves them out)."""

    hfov: float
    vfov: float
    lines_up: int
    lines_down: int
    angle_spacing: float
    pulse_type: str
    frame_mode: str
    distortion_correction: bool
    frame_rate_target_hz: float
    frame_rate_maximum_hz: float
    max_returns_per_point: int

    @classmethod
    def parse(cls, buf: bytes, fields: dict) -> "BfpcScanPattern":
        horizontal = _message(buf, fields, 1, "scan_pattern.horizontal")
        vertical = _message(buf, fields, 2, "scan_pattern.vertical")
        pulse = _message(buf, fields, 3, "scan_pattern.pulse")
        frame_rate = _message(buf, fields, 4, "scan_pattern.frame_rate")
        filters = _message(buf, fields, 7, "scan_pattern.filter")
        return cls(
            hfov=_float(horizontal, 1, "horizontal.fov"), vfov=_float(vertical, 1, "vertical.fov"),
            lines_up=_last(vertical, 2, int, "vertical.scanlines_up", 40),
            lines_down=_last(vertical, 3, int, "vertical.scanlines_down", 40),
            angle_spacing=_float(pulse, 2, "pulse.angle_spacing"),
            pulse_type=PULSE_TYPES.get(_last(pulse, 3, int, "pulse.type", 3), "unknown"),
            frame_mode=FRAME_MODES.get(_last(pulse, 4, int, "pulse.frame_mode", 1), "unknown"),
            distortion_correction=bool(_last(pulse, 5, int, "pulse.distortion_correction", 1)),
            frame_rate_target_hz=_double(frame_rate, 1, "frame_rate.target"),
            frame_rate_maximum_hz=_double(frame_rate, 2, "frame_rate.maximum"),
            max_returns_per_point=_last(filters, 1, int, "filter.max_number_of_returns_per_point", 1))


@dataclass
class BfpcFrame:
    """One frame. P pulses (laser shots) and K <= 3 P returns.

    Per pulse: time_offset (P,) float64 [s] from start_time_ns, azimuth / elevation (P,) float64 [rad] (KITTI:
    azimuth from +x, positive to the left), scanline (P,) int64, point_id (P,) int64, ambient (P,) int64 ambient
    light level, returned (P,) bool (False: the pulse got no return; such pulses have no point).
    Per return: points (K, 4) float32 [x, y, z, intensity] in KITTI axes [m], ranges (K,) float32 [m],
    return_pulse (K,) int64 index of its pulse, return_id (K,) int64 (0 = strongest).
    """

    frame_id: int
    start_time_ns: int
    scan_pattern: BfpcScanPattern | None
    time_offset: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    scanline: np.ndarray
    point_id: np.ndarray
    ambient: np.ndarray
    returned: np.ndarray
    points: np.ndarray
    ranges: np.ndarray
    return_pulse: np.ndarray
    return_id: np.ndarray

    @property
    def num_pulses(self) -> int:
        return int(self.time_offset.shape[0])

    def first_returns(self) -> np.ndarray:
        """(K1,) indices into the per-return arrays of each returned pulse's strongest return."""
        return np.flatnonzero(self.return_id == 0)


@dataclass
class BfpcRecording:
    """A whole recording: device header, frames, footer statistics (counts as the device wrote them)."""

    path: Path
    serial_number: str
    firmware_version: str
    hardware_variant: str
    start_time_ns: int
    frames: list[BfpcFrame] = field(default_factory=list)
    footer_frames: int | None = None
    footer_points: int | None = None
    footer_returns: int | None = None

    @property
    def scan_pattern(self) -> BfpcScanPattern | None:
        """The scan pattern of the first frame that carries one."""
        return next((frame.scan_pattern for frame in self.frames if frame.scan_pattern is not None), None)


def _blickfeld_to_kitti(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) Blickfeld axes (x right, y forward, z up) -> KITTI axes (x forward, y left, z up)."""
    return np.stack([xyz[:, 1], -xyz[:, 0], xyz[:, 2]], axis=1)


def _frame_lines(buf: bytes, span: tuple[int, int]) -> tuple[dict, np.ndarray, np.ndarray]:
    """One data.Frame message's own fields, the stream as uint8 and the frame's scan lines (L, 2) [start, end)."""
    frame = _fields(buf, *span)
    if 8 in frame:
        raise _WireError("packed frames (BSL >= 2.16 REF_FRAME_PACKED) are not supported: record with the "
                         "default (non-packed) point-cloud stream")
    lines = np.array([_expect(line, tuple, "frame.scanlines") for line in frame.get(2, [])], np.int64).reshape(-1, 2)
    return frame, np.frombuffer(buf, np.uint8), lines


def _walked(data: np.ndarray, lines: np.ndarray, pulses: np.ndarray, returns: np.ndarray) -> tuple[int, int]:
    """_walk_frame's numbers of pulses and returns (rows written where the arrays have room); _WireError where a
    field is broken."""
    status, a, b, pulse_count, return_count = _walk_frame(data, lines, pulses, returns)
    if status:
        arguments = (WALKED_FIELDS[a],) if status in (_WRONG_TYPE, _FLOAT64) else (a, b)
        raise _WireError(ERRORS[status].format(*arguments))
    return pulse_count, return_count


def _checked_frame(buf: bytes, span: tuple[int, int]) -> tuple[dict, tuple[int, int]]:
    """One data.Frame message read and checked through, unkept: its own fields and its numbers of pulses and
    returns."""
    frame, data, lines = _frame_lines(buf, span)
    return frame, _walked(data, lines, np.empty((0, 6)), np.empty((0, 7)))


def _parse_frame(buf: bytes, span: tuple[int, int], counts: tuple[int, int] | None = None) -> BfpcFrame:
    """Decode one data.Frame message: its own fields here, its scan lines by the compiled _walk_frame; counts: its
    numbers of pulses and returns where already known (_checked_frame when the frame was listed)."""
    frame, data, lines = _frame_lines(buf, span)
    if counts is None:
        counts = _walked(data, lines, np.empty((0, 6)), np.empty((0, 7)))
    pulses, returns = np.empty((counts[0], 6)), np.empty((counts[1], 7))
    if _walked(data, lines, pulses, returns) != counts:
        raise _WireError("the frame holds other pulses than when it was listed: the recording changed; read it again")
    returned = np.zeros(len(pulses), dtype=bool)
    returned[returns[:, 5].astype(np.int64)] = True
    xyz = _blickfeld_to_kitti(returns[:, :3])
    pattern_span = _last(frame, 5, tuple, "frame.scan_pattern")
    return BfpcFrame(
        frame_id=_last(frame, 1, int, "frame.id", 0), start_time_ns=_last(frame, 3, int, "frame.start_time_ns", 0),
        scan_pattern=None if pattern_span is None else BfpcScanPattern.parse(buf, _fields(buf, *pattern_span)),
        time_offset=pulses[:, 0] * 1e-9,
        # Blickfeld's azimuth is positive towards +x_b (right); KITTI's positive towards +y_k (left)
        azimuth=-pulses[:, 1], elevation=pulses[:, 2],
        scanline=pulses[:, 3].astype(np.int64), point_id=pulses[:, 4].astype(np.int64),
        ambient=pulses[:, 5].astype(np.int64), returned=returned,
        points=np.concatenate([xyz, returns[:, 4:5]], axis=1).astype(np.float32),
        ranges=returns[:, 3].astype(np.float32), return_pulse=returns[:, 5].astype(np.int64),
        return_id=returns[:, 6].astype(np.int64))


# ---------------------------------------------------------------- the compiled walk of a frame's scan lines
# Each helper returns a status first (_OK or an ERRORS key); buf is the decompressed stream as uint8.
@kernel(inline="always")
def _varint_at(buf: np.ndarray, pos: int, end: int) -> tuple[int, np.uint64, int]:
    """(status, value, position after it) of the varint at buf[pos] (at most 64 bits)."""
    value = np.uint64(0)
    shift = 0
    while pos < end:
        byte = np.uint64(buf[pos])
        pos += 1
        if shift == 63 and byte > 1:
            return _VARINT_LONG, value, pos
        value |= (byte & np.uint64(0x7F)) << np.uint64(shift)
        if byte < 0x80:
            return _OK, value, pos
        shift += 7
    return _VARINT_CUT, value, pos


@kernel(inline="always")
def _field(buf: np.ndarray, pos: int, end: int) -> tuple[int, int, int, np.uint64, int, int]:
    """(status, number, wire type, value, value end, next position) of the field at buf[pos] of a message ending
    at `end`: value is a varint's value, else where the field's bytes start (value end: where they end). A
    wire-type error reports (wire type, number) as (number, wire type)."""
    status, key, pos = _varint_at(buf, pos, end)
    if status:
        return status, 0, 0, np.uint64(0), 0, pos
    number, wire = np.int64(key >> np.uint64(3)), np.int64(key & np.uint64(7))
    value = np.uint64(pos)
    if wire == VARINT:
        status, value, pos = _varint_at(buf, pos, end)
        if status:
            return status, 0, 0, value, 0, pos
    elif wire == LENGTH_DELIMITED:
        status, length, pos = _varint_at(buf, pos, end)
        if status:
            return status, 0, 0, length, 0, pos
        if length > np.uint64(end - pos):
            return _PAST_END, 0, 0, length, 0, end
        value = np.uint64(pos)
        pos += np.int64(length)
    elif wire == FIXED32:
        pos += 4
    elif wire == FIXED64:
        pos += 8
    else:
        return _WIRE, wire, number, value, 0, pos
    if pos > end or number == 0:
        return _PAST_END, 0, 0, value, 0, pos
    return _OK, number, wire, value, pos, pos


@kernel
def _read_message(buf: np.ndarray, start: int, end: int, last: np.ndarray) -> tuple[int, int, int]:
    """(status, a, b) of reading every field of the message buf[start:end] (as _fields does), keeping the last field of
    each number n in 1..5 as last[n] = (wire type, value, value end) (wire type -1: none; value: _field's)."""
    last[:, 0] = -1
    pos = start
    while pos < end:
        status, number, wire, value, value_end, pos = _field(buf, pos, end)
        if status:
            return status, number, wire
        if number < last.shape[0]:
            last[number, 0], last[number, 1], last[number, 2] = wire, np.int64(value), value_end
    return _OK, 0, 0


@kernel(inline="always")
def _next_message(buf: np.ndarray, pos: int, end: int, number: int) -> tuple[int, int, int, int]:
    """(status, position after it, start, end) of the next sub-message field `number` from buf[pos] on, in a read
    message ending at `end`; start -1 where there is none (a field of another wire type: _WRONG_TYPE)."""
    while pos < end:
        _, field_number, wire, value, value_end, pos = _field(buf, pos, end)
        if field_number == number:
            return (_OK if wire == LENGTH_DELIMITED else _WRONG_TYPE), pos, np.int64(value), value_end
    return _OK, pos, -1, -1


@kernel(inline="always")
def _int_field(last: np.ndarray, number: int, default: float) -> tuple[int, float]:
    """(status, value as float64) of the varint field `number` of a read message (as _last(..., int, ...)), or
    `default`."""
    if last[number, 0] == -1:
        return _OK, default
    if last[number, 0] != VARINT:
        return _WRONG_TYPE, 0.0
    return _OK, float(np.uint64(last[number, 1]))


@kernel(inline="always")
def _float_field(buf: np.ndarray, last: np.ndarray, number: int) -> tuple[int, float]:
    """(status, value) of the float32 field `number` of a read message (as _float), or nan."""
    wire, at = last[number, 0], last[number, 1]
    if wire == -1:
        return _OK, np.nan
    if wire != FIXED32:
        return (_FLOAT64 if wire == FIXED64 else _WRONG_TYPE), 0.0
    return _OK, float(buf[at:at + 4].view(np.float32)[0])


@kernel
def _walk_frame(buf: np.ndarray, lines: np.ndarray, pulses: np.ndarray, returns: np.ndarray
                ) -> tuple[int, int, int, int, int]:
    """Read the scan lines (L, 2) [start, end) of one frame: each pulse's row (time offset [ns], azimuth and
    elevation [rad, Blickfeld's], scan line, point id, ambient light) into `pulses` (P, 6) and each return's (x, y,
    z [m, Blickfeld's axes], range [m], intensity, its pulse's row, return id) into `returns` (K, 7), where they
    have room (a walk with empty arrays counts them). Fields are read as the Python helpers would (_last, _float,
    their defaults). Returns (status, a, b, P, K): a failing status with its ERRORS arguments (a field: its index
    in WALKED_FIELDS)."""
    fields = np.empty((4, 6, 3), np.int64)  # _read_message's record of a line, a point, a direction, a return
    line_fields, point_fields, direction, echo_fields = fields[0], fields[1], fields[2], fields[3]
    pulse, echo = 0, 0
    for line in range(lines.shape[0]):
        start, end = lines[line, 0], lines[line, 1]
        status, a, b = _read_message(buf, start, end, line_fields)
        if status:
            return status, a, b, pulse, echo
        status, line_id = _int_field(line_fields, 1, float(line))
        if status:
            return status, 0, 0, pulse, echo
        pos = start
        while True:  # the points (field 3) in order
            status, pos, point, point_end = _next_message(buf, pos, end, 3)
            if status:
                return status, 1, 0, pulse, echo
            if point < 0:
                break
            status, a, b = _read_message(buf, point, point_end, point_fields)
            if status:
                return status, a, b, pulse, echo
            azimuth = elevation = np.nan
            if point_fields[5, 0] != -1:
                if point_fields[5, 0] != LENGTH_DELIMITED:
                    return _WRONG_TYPE, 6, 0, pulse, echo
                status, a, b = _read_message(buf, point_fields[5, 1], point_fields[5, 2], direction)
                if status:
                    return status, a, b, pulse, echo
                azimuth_status, azimuth = _float_field(buf, direction, 1)
                elevation_status, elevation = _float_field(buf, direction, 2)
                for status, what in ((azimuth_status, 7), (elevation_status, 8)):
                    if status:
                        return status, what, 0, pulse, echo
            time_status, time_ns = _int_field(point_fields, 3, 0.0)
            id_status, point_id = _int_field(point_fields, 1, float(pulse))
            ambient_status, ambient = _int_field(point_fields, 4, 0.0)
            for status, what in ((time_status, 4), (id_status, 2), (ambient_status, 5)):
                if status:
                    return status, what, 0, pulse, echo
            if pulse < pulses.shape[0]:
                pulses[pulse, 0], pulses[pulse, 1], pulses[pulse, 2] = time_ns, azimuth, elevation
                pulses[pulse, 3], pulses[pulse, 4], pulses[pulse, 5] = line_id, point_id, ambient
            number_in_point = 0
            inner = point
            while True:  # the returns (field 2) in order
                status, inner, echo_start, echo_end = _next_message(buf, inner, point_end, 2)
                if status:
                    return status, 3, 0, pulse, echo
                if echo_start < 0:
                    break
                status, a, b = _read_message(buf, echo_start, echo_end, echo_fields)
                if status:
                    return status, a, b, pulse, echo
                if echo_fields[2, 0] not in (-1, LENGTH_DELIMITED):
                    return _WRONG_TYPE, 10, 0, pulse, echo
                xyz = echo_fields[2, 1]
                if echo_fields[2, 0] == -1 or echo_fields[2, 2] - xyz != 12:
                    return _NO_XYZ, 0, 0, pulse, echo
                distance_status, distance = _float_field(buf, echo_fields, 3)
                intensity_status, intensity = _int_field(echo_fields, 4, 0.0)
                id_status, return_id = _int_field(echo_fields, 1, float(number_in_point))
                for status, what in ((distance_status, 11), (intensity_status, 12), (id_status, 9)):
                    if status:
                        return status, what, 0, pulse, echo
                if echo < returns.shape[0]:
                    returns[echo, :3] = buf[xyz:xyz + 12].view(np.float32)
                    returns[echo, 3], returns[echo, 4], returns[echo, 5] = distance, intensity, pulse
                    returns[echo, 6] = return_id
                echo += 1
                number_in_point += 1
            pulse += 1
    return _OK, 0, 0, pulse, echo


@contextlib.contextmanager
def _gzip_errors(path: Path) -> Iterator[None]:
    """DataFormatError naming the file for a missing, unreadable or damaged gzip stream."""
    try:
        yield
    except FileNotFoundError:
        raise DataFormatError(path, "file not found: give the path of a .bfpc recording") from None
    except (gzip.BadGzipFile, EOFError, zlib.error) as error:  # CRC or length check failed, bad deflate data, cut off
        raise DataFormatError(path, f"corrupt or truncated gzip data ({error}): copy the recording again") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot be read ({error.strerror or error})") from None


@contextlib.contextmanager
def _message_errors(path: Path, where: str) -> Iterator[None]:
    """DataFormatError naming the file and the message (`where`) for bytes that are no Blickfeld message."""
    try:
        yield
    except (_WireError, struct.error) as error:
        raise DataFormatError(path, f"{where}: {error}") from None


def _stream(path: Path) -> Iterator[tuple[str, bytes]]:
    """('message <index> at byte <offset>', bytes) of each length-prefixed message of the .bfpc `path`,
    decompressed one message at a time (offset: in the decompressed stream, after the length)."""
    with _gzip_errors(path), open(path, "rb") as file:
        if file.read(2) != b"\x1f\x8b":
            raise DataFormatError(path, "not a gzip stream (it does not start with the gzip bytes 1f 8b): a .bfpc "
                                        "recording is gzip-compressed; check that the file is a Blickfeld "
                                        "point-cloud recording")
        file.seek(0)
        with gzip.GzipFile(fileobj=file) as stream:
            pos = 0
            for index in itertools.count():
                prefix = bytearray(stream.read(1))
                if not prefix:
                    return
                while prefix[-1] & 0x80 and len(prefix) < 10:
                    prefix += stream.read(1)
                status, length, _ = _varint_at(np.frombuffer(bytes(prefix), np.uint8), 0, len(prefix))
                if status:
                    raise DataFormatError(path, f"message {index} at byte {pos}: truncated length prefix")
                length = int(length)
                data = stream.read(length)
                if len(data) < length:
                    raise DataFormatError(path, f"message {index} at byte {pos}: truncated ({length} bytes "
                                                f"announced, {len(data)} left); the recording was cut off: copy it "
                                                "again")
                yield f"message {index} at byte {pos + len(prefix)}", data
                pos += len(prefix) + length


def _records(path: Path) -> Iterator[tuple[str, object]]:
    """The .bfpc `path` read once through, message by message: ('header', BfpcRecording without frames), then
    ('frame', (where, bytes, span)) for each frame message, still to decode, and ('footer', (frames, points,
    returns)) as the device counted them."""
    header = False
    for where, buf in _stream(path):
        with _message_errors(path, where):
            message = _fields(buf, 0, len(buf))
            if not header:
                device = _message(buf, message, 1, "header.device")
                if not device or set(message) - {1, 2}:
                    raise _WireError("the first message is not a point-cloud header")
                header = True
                yield "header", BfpcRecording(
                    path=path, serial_number=_string(buf, device, 2, "header.cube_serial_number")
                    or _string(buf, device, 1, "header.legacy_cube_serial_number"),
                    firmware_version=_string(buf, device, 4, "header.firmware_version"),
                    hardware_variant=HARDWARE_VARIANTS.get(_last(device, 5, int, "header.hardware_variant", 6),
                                                           "UNKNOWN_HARDWARE"),
                    start_time_ns=_last(device, 3, int, "header.start_time_ns", 0))
            elif 1 in message:
                yield "frame", (where, buf, _last(message, 1, tuple, "data.frame"))
            elif 2 in message:
                counter = _message(buf, _message(buf, message, 2, "data.footer"), 1, "footer.stats")
                counter = _message(buf, counter, 1, "stats.counter")
                yield "footer", tuple(_last(counter, number, int, f"counter.{name}")
                                      for number, name in ((1, "frames"), (2, "points"), (3, "returns")))
            else:
                raise _WireError("a data message with neither a frame nor a footer")
    if not header:
        raise DataFormatError(path, "empty recording: no header message")


def read_bfpc(path: str | Path) -> BfpcRecording:
    """Read a Blickfeld .bfpc recording, every frame decoded; raise DataFormatError naming the file on bad input."""
    path = Path(path)
    for kind, value in _records(path):
        if kind == "header":
            recording = value
        elif kind == "frame":
            where, buf, span = value
            with _message_errors(path, where):
                recording.frames.append(_parse_frame(buf, span))
        else:
            recording.footer_frames, recording.footer_points, recording.footer_returns = value
    return recording


def read_pulses(path: str | Path) -> PulseRecording:
    """A .bfpc recording as frames of every pulse (each with its strongest return, if any) and its stored scan
    pattern: what io.formats reads of the format. Every frame is checked here and decoded when loaded, read again
    from the file (io.frames.SequentialReader)."""
    path = Path(path)
    names, starts, counts, stored = [], [], [], None
    for kind, value in _records(path):
        if kind == "frame":
            where, buf, span = value
            with _message_errors(path, where):
                frame, frame_counts = _checked_frame(buf, span)
                counts.append(frame_counts)
                pattern_span = _last(frame, 5, tuple, "frame.scan_pattern")
                if stored is None and pattern_span is not None:
                    stored = BfpcScanPattern.parse(buf, _fields(buf, *pattern_span))
                starts.append(_last(frame, 3, int, "frame.start_time_ns", 0))
            names.append(f"{path.name}#{len(names)}")
    frames = SequentialReader(lambda: _frame_messages(path), lambda index: DataFormatError(
        path, f"frame {index} is gone: the recording changed after it was listed; read it again"))
    pattern = None if stored is None else dict(
        hfov_deg=np.degrees(stored.hfov), vfov_deg=np.degrees(stored.vfov), lines_up=stored.lines_up,
        lines_down=stored.lines_down, angle_spacing_deg=np.degrees(stored.angle_spacing))
    return PulseRecording(names, starts, functools.partial(_pulse_frame, path, names, counts, frames), pattern)


def _frame_messages(path: Path) -> tuple[Iterator[tuple[int, tuple]], Callable[[], None]]:
    """(index, (where, bytes, span)) of the frame messages of `path`, read again from its start; and their close."""
    records = _records(path)
    frames = (value for kind, value in records if kind == "frame")
    return enumerate(frames), records.close


def _pulse_frame(path: Path, names: list[str], counts: list[tuple[int, int]], frames: SequentialReader,
                 index: int) -> PulseFrame:
    """Frame `index` of the listed .bfpc `path` (its names and numbers of pulses and returns) as a PulseFrame: every
    pulse's direction (KITTI axes) and time, and its strongest return."""
    where, buf, span = frames.item(index)
    with _message_errors(path, where):
        frame = _parse_frame(buf, span, counts[index])
    cos_el = np.cos(frame.elevation)
    directions = np.stack([cos_el * np.cos(frame.azimuth), cos_el * np.sin(frame.azimuth),
                           np.sin(frame.elevation)], axis=1)
    strongest = frame.first_returns()
    points = np.full((frame.num_pulses, 4), np.nan, dtype=np.float32)
    points[frame.return_pulse[strongest]] = frame.points[strongest]
    return PulseFrame(names[index], frame.start_time_ns, directions, frame.time_offset, points,
                      len(frame.points) - len(strongest))
