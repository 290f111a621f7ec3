"""The .bfpc reader on the real Cube 1 recording and on corrupted copies of it."""
import gzip

import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.bfpc import read_bfpc


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
    data = bytearray(gzip.compress(b"\x00" * 100))
    data[-8] ^= 0xFF  # the CRC-32 in the gzip trailer
    (tmp_path / "crc.bfpc").write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"crc\.bfpc: corrupt or truncated gzip data \(CRC check failed"):
        read_bfpc(tmp_path / "crc.bfpc")
    (tmp_path / "plain.bfpc").write_bytes(b"\x00" * 100)
    with pytest.raises(DataFormatError, match=r"plain\.bfpc: not a gzip stream \(it does not start with the gzip "
                                              r"bytes 1f 8b\)"):
        read_bfpc(tmp_path / "plain.bfpc")
