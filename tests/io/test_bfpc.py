"""The .bfpc reader on the real Cube 1 recording, on corrupted copies of it and on hand-made recordings whose
frames hold every field the reader reads, left out, or broken (exact values and one-line errors); a recording is
read in memory that does not grow with its length, its frames loaded in any order."""
import gzip
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.bfpc import read_bfpc, read_pulses
from pcdet_memslidar.io.formats import list_frames


@pytest.mark.slow
def test_real_recording_frames_and_pulses(real_bfpc):
    assert len(real_bfpc.frames) == 10
    assert [frame.num_pulses for frame in real_bfpc.frames] == [12312] * 10
    assert real_bfpc.hardware_variant == "CUBE_V0_3"
    assert real_bfpc.serial_number == "msb-0206"
    # footer counters written by the device agree with what was decoded
    assert real_bfpc.footer_frames == 10 and real_bfpc.footer_points == 123120
    assert sum(len(frame.points) for frame in real_bfpc.frames) == real_bfpc.footer_returns == 116412
    assert [frame.frame_id for frame in real_bfpc.frames][:3] == [558025, 558026, 558027]


def test_real_recording_scan_pattern(real_bfpc):
    pattern = real_bfpc.scan_pattern
    assert np.rad2deg(pattern.hfov) == pytest.approx(72.0, abs=1e-4)
    assert np.rad2deg(pattern.vfov) == pytest.approx(30.0, abs=1e-4)
    assert (pattern.lines_up, pattern.lines_down) == (18, 18)
    assert np.rad2deg(pattern.angle_spacing) == pytest.approx(0.21, abs=1e-5)
    assert (pattern.pulse_type, pattern.frame_mode) == ("equi_horizontal_angle", "combine_up_down")
    assert pattern.frame_rate_maximum_hz == pytest.approx(8.185, abs=1e-3)


def test_pulses_without_return_are_a_mask_and_points_are_kitti_axes(real_bfpc):
    frame = real_bfpc.frames[0]
    assert frame.returned.sum() == len(frame.points) == 11646  # 666 pulses got no return
    assert np.isfinite(frame.points).all()
    first = frame.first_returns()
    xyz = frame.points[first, :3].astype(np.float64)
    pulse = frame.return_pulse[first]
    # KITTI axes: the point lies along the pulse's direction (azimuth positive to the left, +y)
    np.testing.assert_allclose(np.arctan2(xyz[:, 1], xyz[:, 0]), frame.azimuth[pulse], atol=1e-5)
    np.testing.assert_allclose(np.arcsin(xyz[:, 2] / np.linalg.norm(xyz, axis=1)), frame.elevation[pulse], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), frame.ranges[first], rtol=1e-5)
    assert frame.points[:, 0].mean() > 3.0  # the scene lies in front (+x)
    assert 0.0 <= frame.time_offset.min() and frame.time_offset.max() == pytest.approx(0.1212, abs=1e-3)


@pytest.fixture(scope="module")
def raw_bytes(real_recording):
    return real_recording.read_bytes()


def test_truncated_file_is_a_gzip_error(tmp_path, raw_bytes):
    path = tmp_path / "cut.bfpc"
    path.write_bytes(raw_bytes[: len(raw_bytes) // 2])
    with pytest.raises(DataFormatError, match="cut.bfpc: corrupt or truncated gzip"):
        read_bfpc(path)


def test_flipped_gzip_header(tmp_path, raw_bytes):
    path = tmp_path / "flipped.bfpc"
    path.write_bytes(bytes([raw_bytes[0] ^ 0xFF]) + raw_bytes[1:])
    with pytest.raises(DataFormatError, match="flipped.bfpc: not a gzip stream"):
        read_bfpc(path)


def test_truncated_message_inside_valid_gzip(tmp_path, real_recording):
    stream = gzip.decompress(real_recording.read_bytes())
    path = tmp_path / "short.bfpc"
    path.write_bytes(gzip.compress(stream[:1000]))
    with pytest.raises(DataFormatError, match=r"short.bfpc: message 1 at byte 27: truncated"):
        read_bfpc(path)


def test_wrong_message_type(tmp_path):
    path = tmp_path / "other.bfpc"
    # one message whose field 1 is a varint, where the header expects a sub-message
    path.write_bytes(gzip.compress(bytes([2, 0x08, 0x05])))
    with pytest.raises(DataFormatError, match="other.bfpc: message 0 at byte 1: field 'header.device' has the wrong"):
        read_bfpc(path)


def test_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="file not found"):
        read_bfpc(tmp_path / "none.bfpc")


def test_gzip_crc_failure_is_reported_as_corrupt_not_as_not_gzip(tmp_path):
    header = message_field(1, message_field(2, b"cube-1"))  # messages that read, then the trailer's CRC
    data = bytearray(gzip.compress(varint(len(header)) + header))
    data[-8] ^= 0xFF  # the CRC-32 in the gzip trailer
    (tmp_path / "crc.bfpc").write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"crc\.bfpc: corrupt or truncated gzip data \(CRC check failed"):
        read_bfpc(tmp_path / "crc.bfpc")
    (tmp_path / "plain.bfpc").write_bytes(b"\x00" * 100)
    with pytest.raises(DataFormatError, match=r"plain\.bfpc: not a gzip stream \(it does not start with the gzip "
                                              r"bytes 1f 8b\)"):
        read_bfpc(tmp_path / "plain.bfpc")


def varint(value: int) -> bytes:
    out = bytearray()
    while True:
        out.append((value & 0x7F) | (0x80 if value >= 0x80 else 0))
        value >>= 7
        if not out[-1] & 0x80:
            return bytes(out)


def int_field(number: int, value: int) -> bytes:
    return varint(number << 3) + varint(value)


def float_field(number: int, value: float) -> bytes:
    return varint(number << 3 | 5) + struct.pack("<f", value)


def message_field(number: int, body: bytes) -> bytes:
    return varint(number << 3 | 2) + varint(len(body)) + body


def echo(xyz=(1.5, 2.0, -0.25), distance=2.5, intensity=None, return_id=None, cartesian=None) -> bytes:
    """A return: cartesian x, y, z (Blickfeld's axes), range, intensity and id where given."""
    body = message_field(2, struct.pack("<3f", *xyz) if cartesian is None else cartesian)
    body += float_field(3, distance) if distance is not None else b""
    body += int_field(4, intensity) if intensity is not None else b""
    return body + (int_field(1, return_id) if return_id is not None else b"")


def recording(tmp_path, *lines: bytes) -> Path:
    """A .bfpc file: a header, then one frame (id 7, start 1000 ns) of the given scan lines."""
    frame = int_field(1, 7) + int_field(3, 1000) + b"".join(message_field(2, line) for line in lines)
    messages = [message_field(1, message_field(2, b"cube-1")), message_field(1, frame)]
    path = tmp_path / "made.bfpc"
    path.write_bytes(gzip.compress(b"".join(varint(len(m)) + m for m in messages)))
    return path


FULL_POINT = (int_field(1, 42) + int_field(3, 250) + int_field(4, 3)
              + message_field(5, float_field(1, 0.5) + float_field(2, -0.25))
              + message_field(2, echo(intensity=9)) + message_field(2, echo((3.0, 4.0, 0.5), 5.0, 2, 1)))


def test_a_made_frame_reads_every_field_and_the_defaults_of_those_left_out(tmp_path):
    bare_point = int_field(3, 500)  # no id, direction or return
    half_point = message_field(5, float_field(1, 1.0)) + message_field(2, echo(distance=None))  # no elevation
    path = recording(tmp_path, int_field(1, 5) + message_field(3, FULL_POINT) + message_field(3, bare_point),
                     message_field(3, half_point))  # the second line has no id
    frame, = read_bfpc(path).frames
    assert (frame.frame_id, frame.start_time_ns) == (7, 1000)
    np.testing.assert_array_equal(frame.time_offset, np.array([250, 500, 0]) * 1e-9)  # [ns] * 1e-9
    np.testing.assert_array_equal(frame.azimuth, [-0.5, np.nan, -1.0])  # KITTI: positive to the left
    np.testing.assert_array_equal(frame.elevation, [-0.25, np.nan, np.nan])
    np.testing.assert_array_equal(frame.scanline, [5, 5, 1])  # a line's index where it has no id
    np.testing.assert_array_equal(frame.point_id, [42, 1, 2])  # a pulse's index where it has no id
    np.testing.assert_array_equal(frame.ambient, [3, 0, 0])
    np.testing.assert_array_equal(frame.returned, [True, False, True])
    np.testing.assert_array_equal(frame.points, np.array([[2.0, -1.5, -0.25, 9.0], [4.0, -3.0, 0.5, 2.0],
                                                          [2.0, -1.5, -0.25, 0.0]], np.float32))  # KITTI axes
    np.testing.assert_array_equal(frame.ranges, np.array([2.5, 5.0, np.nan], np.float32))
    np.testing.assert_array_equal(frame.return_pulse, [0, 0, 2])
    np.testing.assert_array_equal(frame.return_id, [0, 1, 0])  # a return's number where it has no id


@pytest.mark.parametrize("point, error", [
    (int_field(1, 1) + float_field(3, 1.0), "field 'point.start_offset_ns' has the wrong wire type"),
    (message_field(5, varint(1 << 3 | 1) + struct.pack("<d", 0.5)),
     "field 'direction.azimuth' holds 8 bytes where a float32 has 4"),
    (message_field(5, int_field(2, 3)), "field 'direction.elevation' has the wrong wire type"),
    (int_field(5, 1), "field 'point.direction' has the wrong wire type"),
    (int_field(2, 1), "field 'point.returns' has the wrong wire type"),
    (message_field(2, echo(cartesian=struct.pack("<2f", 1.0, 2.0))), "a return without its 3 cartesian coordinates"),
    (message_field(2, float_field(3, 1.0)), "a return without its 3 cartesian coordinates"),
    (message_field(2, echo(intensity=None) + float_field(4, 1.0)), "field 'return.intensity' has the wrong wire type"),
    (varint(6 << 3 | 3), "unsupported wire type 3 for field 6"),
    (varint(1 << 3) + b"\xff" * 9 + b"\x02", "varint longer than 64 bits"),
    (varint(1 << 3) + b"\xff", "message ends inside a varint (truncated)"),
    (message_field(5, b"") + varint(2 << 3 | 2) + varint(50), "field runs past the end of its message"),
], ids=["offset as float", "azimuth as float64", "elevation as varint", "direction as varint", "return as varint",
        "2 coordinates", "no coordinates", "intensity as float", "wire type 3", "65-bit varint", "cut varint",
        "field past its message"])
def test_a_broken_field_of_a_point_is_refused_naming_the_message(tmp_path, point, error):
    path = recording(tmp_path, int_field(1, 5) + message_field(3, FULL_POINT) + message_field(3, point))
    with pytest.raises(DataFormatError, match=re.escape(f"{path}: message 1 at byte ") + r"\d+: " + re.escape(error)):
        read_bfpc(path)


def recording_of(tmp_path, real_recording, frames: list[int]) -> Path:
    """The real recording's header, its frames `frames` (indices, in this order, repeats allowed) and its footer."""
    stream, messages, pos = gzip.decompress(real_recording.read_bytes()), [], 0
    while pos < len(stream):
        start = pos
        while stream[pos] & 0x80:
            pos += 1
        length = sum((byte & 0x7F) << 7 * k for k, byte in enumerate(stream[start:pos + 1]))
        pos += 1 + length
        messages.append(stream[start:pos])
    path = tmp_path / f"{len(frames)}_frames.bfpc"
    body = [messages[0], *(messages[1 + index] for index in frames), messages[-1]]
    path.write_bytes(gzip.compress(b"".join(body), compresslevel=1))
    return path


@pytest.mark.slow
def test_a_recording_is_read_in_memory_that_does_not_grow_with_its_length(tmp_path, real_recording, peak_bytes):
    short, long = (recording_of(tmp_path, real_recording, list(range(10)) * times) for times in (1, 4))
    assert len(list_frames("bfpc", long)) == 40
    peaks = peak_bytes("bfpc", short), peak_bytes("bfpc", long)
    assert peaks[1] < 1.5 * peaks[0], peaks


def test_frames_load_the_same_in_any_order_and_a_changed_recording_is_named(tmp_path, real_bfpc, real_recording):
    pulses = read_pulses(real_recording)
    assert pulses.names[:2] == ["cube1_sample_2020.bfpc#0", "cube1_sample_2020.bfpc#1"]
    assert pulses.start_times_ns == [frame.start_time_ns for frame in real_bfpc.frames]
    for index in (7, 2, 2, 9):  # back to the start, and the same frame twice
        frame, whole = pulses.load(index), real_bfpc.frames[index]
        strongest = whole.first_returns()
        np.testing.assert_array_equal(frame.time_offset, whole.time_offset)
        np.testing.assert_array_equal(frame.points[whole.return_pulse[strongest]], whole.points[strongest])
    changed = recording_of(tmp_path, real_recording, list(range(10)))
    listed = read_pulses(changed)
    (tmp_path / "again").mkdir()
    again = recording_of(tmp_path / "again", real_recording, [1, 0, 2])  # other frames (11,652 returns, not 11,646)
    changed.write_bytes(again.read_bytes())  # recorded again after the listing
    with pytest.raises(DataFormatError, match=re.escape(f"{changed}: message 1 at byte ") + r"\d+: " + re.escape(
            "the frame holds other pulses than when it was listed: the recording changed; read it again")):
        listed.load(0)
    with pytest.raises(DataFormatError, match=re.escape(f"{changed}: frame 9 is gone: the recording changed after it "
                                                        "was listed; read it again")):
        listed.load(9)
