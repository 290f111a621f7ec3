"""Point-cloud readers: PCD (3 encodings) and PLY written by Open3D (an independent writer), NPY, BIN, bad files."""
import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.formats import read_point_cloud
from pcdet_memslidar.io.pointclouds import LoadedCloud
from pcdet_memslidar.utils.open3d import import_open3d


@pytest.fixture(scope="module")
def cloud():
    """(50, 3) xyz, (50,) intensity 0..511, (50,) time [s]; points 0 and 1 invalid (NaN, all zero)."""
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-10, 10, (50, 3)).astype(np.float32)
    xyz[0] = np.nan
    xyz[1] = 0.0
    return xyz, rng.integers(0, 512, 50).astype(np.float32), rng.uniform(0, 0.12, 50).astype(np.float32)


def _write_open3d(path, cloud, **kwargs):
    o3d = import_open3d()
    xyz, intensity, time = cloud
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(xyz)
    pc.point.intensity = o3d.core.Tensor(intensity[:, None])
    pc.point.time = o3d.core.Tensor(time[:, None])
    assert o3d.t.io.write_point_cloud(str(path), pc, **kwargs)


@pytest.mark.parametrize("name, kwargs", [
    ("ascii.pcd", dict(write_ascii=True)), ("binary.pcd", dict(write_ascii=False, compressed=False)),
    ("compressed.pcd", dict(write_ascii=False, compressed=True)), ("binary.ply", dict(write_ascii=False)),
    ("ascii.ply", dict(write_ascii=True))])
def test_open3d_files_read_back_with_intensity_time_and_counted_invalid_points(tmp_path, cloud, name, kwargs):
    _write_open3d(tmp_path / name, cloud, **kwargs)
    if name == "compressed.pcd":
        assert b"DATA binary_compressed" in (tmp_path / name).read_bytes()[:400]
    loaded = read_point_cloud(tmp_path / name)
    xyz, intensity, time = cloud
    assert loaded.dropped == 2 and loaded.has_intensity
    assert loaded.points.shape == (48, 4) and loaded.points.dtype == np.float32
    np.testing.assert_allclose(loaded.points[:, :3], xyz[2:], atol=1e-4)
    np.testing.assert_allclose(loaded.points[:, 3], intensity[2:], atol=1e-3)
    np.testing.assert_allclose(loaded.time, time[2:], atol=1e-6)


def test_hand_written_pcd_with_uint_intensity_and_padding(tmp_path):
    (tmp_path / "a.pcd").write_text(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z _ intensity\nSIZE 4 4 4 1 2\nTYPE F F F U U\nCOUNT 1 1 1 1 1\n"
        "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n"
        "1.5 -2 3 0 300\nnan nan nan 0 0\n0 0 0 0 7\n")
    loaded = read_point_cloud(tmp_path / "a.pcd")
    np.testing.assert_array_equal(loaded.points, [[1.5, -2.0, 3.0, 300.0]])
    assert loaded.dropped == 2 and loaded.time is None


@pytest.mark.parametrize("name, kwargs, message", [
    ("a.pcd", dict(write_ascii=True), "truncated"), ("b.pcd", dict(write_ascii=False, compressed=False), "truncated"),
    ("c.pcd", dict(write_ascii=False, compressed=True), "truncated"), ("d.ply", dict(write_ascii=False), "truncated")])
def test_truncated_files_raise_naming_the_file(tmp_path, cloud, name, kwargs, message):
    _write_open3d(tmp_path / name, cloud, **kwargs)
    data = (tmp_path / name).read_bytes()
    (tmp_path / name).write_bytes(data[:-200])
    with pytest.raises(DataFormatError, match=message) as error:
        read_point_cloud(tmp_path / name)
    assert name in str(error.value)


def test_a_flipped_bit_in_lzf_literals_is_refused_as_a_point_beyond_any_lidar_range(tmp_path):
    """LZF carries no checksum: a flipped bit in a literal run decodes without error to another value. One in a
    float's exponent puts the point out of any LiDAR's range, and the reader refuses the file."""
    import lzf

    xyz = np.random.default_rng(3).uniform([2, -5, -1], [20, 5, 2], (20, 3)).astype("<f4")
    xyz[:, 2] = -1.5  # a floor: LZF compresses this column (it returns None for a body it cannot shrink)
    raw = xyz.T.tobytes()  # binary_compressed: column-major
    compressed = bytearray(lzf.compress(raw))
    header = (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 20\nHEIGHT 1\nPOINTS 20\n"
              b"DATA binary_compressed\n" + np.array([len(compressed), len(raw)], "<u4").tobytes())
    path = tmp_path / "flipped.pcd"
    path.write_bytes(header + bytes(compressed))
    np.testing.assert_array_equal(read_point_cloud(path).points[:, :3], xyz)
    at = bytes(compressed).find(xyz[7, 0].tobytes())
    assert at > 0 and not compressed[at + 3] & 0x08  # x of point 7 is a literal; exponent bit 4 is clear
    compressed[at + 3] ^= 0x08  # exponent + 16: x times 65536
    path.write_bytes(header + bytes(compressed))
    far = [round(float(xyz[7, 0]) * 65536, 1), round(float(xyz[7, 1]), 1), round(float(xyz[7, 2]), 1)]
    with pytest.raises(DataFormatError) as error:
        read_point_cloud(path)
    assert str(error.value) == (f"{path}: 1 point(s) lie beyond 1000 m, the first is point 7 (counting from 0) at "
                                f"{far} m: no LiDAR return is that far, so the file is damaged (copy it again from "
                                "the recorder) or not in metres (convert it)")


def test_corrupt_lzf_and_bad_ascii_row(tmp_path, cloud):
    _write_open3d(tmp_path / "c.pcd", cloud, write_ascii=False, compressed=True)
    data = bytearray((tmp_path / "c.pcd").read_bytes())
    start = data.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n") + 8
    data[start:start + 40] = b"\xff" * 40  # LZF back-references far before the start of the output
    (tmp_path / "c.pcd").write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match="corrupt"):
        read_point_cloud(tmp_path / "c.pcd")
    (tmp_path / "e.pcd").write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 2\nDATA ascii\n1 2 3\n1 two 3\n")
    with pytest.raises(DataFormatError, match=r"e\.pcd:7: bad row"):
        read_point_cloud(tmp_path / "e.pcd")


def test_npy_and_bin(tmp_path):
    np.save(tmp_path / "a.npy", np.array([[1, 2, 3, 4, 0.5], [0, 0, 0, 9, 0.6]], dtype=np.float64))
    loaded = read_point_cloud(tmp_path / "a.npy")
    np.testing.assert_array_equal(loaded.points, [[1, 2, 3, 4]])
    np.testing.assert_array_equal(loaded.time, [0.5])
    assert loaded.dropped == 1
    structured = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("reflectivity", "u2")])
    structured[0] = (1, 2, 3, 40)
    structured[1] = (4, 5, 6, 50)
    np.save(tmp_path / "s.npy", structured)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "s.npy").points[:, 3], [40, 50])
    np.array([0, 0, 0, 3, 4, 5, 6, 7], dtype="<f4").tofile(tmp_path / "k.bin")
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "k.bin").points, [[4, 5, 6, 7]])  # row 0 is all zero
    (tmp_path / "t.bin").write_bytes(b"\0" * 20)
    with pytest.raises(DataFormatError, match="multiple of 16"):
        read_point_cloud(tmp_path / "t.bin")
    with pytest.raises(DataFormatError, match="shape"):
        np.save(tmp_path / "b.npy", np.zeros((3, 7)))
        read_point_cloud(tmp_path / "b.npy")


@pytest.mark.parametrize("counts, message", [
    ("WIDTH 3\nHEIGHT 1\nPOINTS 2", r"p\.pcd:4: PCD header: POINTS 2 differs from WIDTH x HEIGHT = 3 x 1 = 3"),
    ("WIDTH -3\nHEIGHT 1\nPOINTS 3", r"p\.pcd:2: PCD header: WIDTH '-3' must be one integer >= 0"),
    ("POINTS -1", r"p\.pcd:2: PCD header: POINTS '-1' must be one integer >= 0"),
    ("POINTS 3\nCOUNT 1 1 -1", r"p\.pcd:3: PCD header: COUNT 1 1 -1 must be >= 1")])
def test_pcd_point_counts_must_agree_and_be_non_negative(tmp_path, counts, message):
    (tmp_path / "p.pcd").write_text(f"FIELDS x y z\n{counts}\nSIZE 4 4 4\nTYPE F F F\nDATA ascii\n"
                                    "1 2 3\n4 5 6\n7 8 9\n")
    with pytest.raises(DataFormatError, match=message):
        read_point_cloud(tmp_path / "p.pcd")


def test_nan_intensity_or_time_of_a_valid_point_names_the_file(tmp_path):
    np.save(tmp_path / "i.npy", np.array([[1, 2, 3, 4], [1, 2, 3, np.nan], [np.nan, 0, 0, np.nan]]))
    with pytest.raises(DataFormatError, match=r"i\.npy: 1 point\(s\) with valid x, y, z have a NaN or infinite "
                                              r"'intensity', the first is point 1"):
        read_point_cloud(tmp_path / "i.npy")
    np.save(tmp_path / "t.npy", np.array([[1, 2, 3, 4, 0.1], [1, 2, 3, 4, np.inf]]))
    with pytest.raises(DataFormatError, match=r"t\.npy: 1 point\(s\) .* infinite 'time', the first is point 1"):
        read_point_cloud(tmp_path / "t.npy")


@pytest.mark.parametrize("count", ["-3", "many"])
def test_a_ply_element_count_that_is_no_whole_number_is_refused_naming_its_line(tmp_path, count):
    (tmp_path / "v.ply").write_text(f"ply\nformat ascii 1.0\nelement vertex {count}\nproperty float x\n"
                                    "property float y\nproperty float z\nend_header\n1 2 3\n")
    with pytest.raises(DataFormatError) as error:
        read_point_cloud(tmp_path / "v.ply")
    assert str(error.value) == (f"{tmp_path / 'v.ply'}:3: element 'vertex' has count '{count}': a PLY element count "
                                f"is a whole number >= 0")


@pytest.mark.parametrize("array", [np.ones((2, 4), dtype=bool), np.array([["1", "2", "3"]])])
def test_an_npy_array_of_no_numbers_is_refused(tmp_path, array):
    np.save(tmp_path / "n.npy", array)
    with pytest.raises(DataFormatError, match=r"n\.npy: array of (bool|<U1) values; a point cloud holds numbers"):
        read_point_cloud(tmp_path / "n.npy")


def test_a_gzip_recording_named_bin_is_named_as_such(tmp_path):
    (tmp_path / "r.bin").write_bytes(b"\x1f\x8b" + bytes(30))
    with pytest.raises(DataFormatError, match=r"r\.bin: a gzip stream, not float32 points: a Blickfeld recording"):
        read_point_cloud(tmp_path / "r.bin")


@pytest.mark.parametrize("time, unit, expected", [
    ([5.0, 5.25, 5.125], 1.0, [0.0, 0.25, 0.125]),  # seconds (a .bfpc)
    ([2e9, 2.25e9, 2.125e9], 1e-9, [0.0, 0.25, 0.125]),  # nanoseconds
    ([], 1.0, []),
    ([5.0, 5.25, 5.125], None, None),  # a time field of unknown unit
    (None, 1.0, None),
])
def test_time_offsets_are_seconds_from_the_first_point_where_the_unit_is_known(time, unit, expected):
    points = np.zeros((0 if time is None else len(time), 4), np.float32)
    cloud = LoadedCloud(points, None if time is None else np.array(time), 0, False, time_unit_s=unit)
    offsets = cloud.time_offsets()
    if expected is None:
        assert offsets is None
    else:
        assert offsets.dtype == np.float32 and offsets.tolist() == expected


@pytest.mark.parametrize("unit, expected", [(1e-3, [0.0, 0.05, 0.1]), (1e-9, [0.0, 5e-8, 1e-7])])
def test_a_time_unit_gives_a_pcd_its_time_offsets(tmp_path, unit, expected):
    (tmp_path / "t.pcd").write_text("FIELDS x y z timestamp\nSIZE 4 4 4 8\nTYPE F F F F\nPOINTS 4\nDATA ascii\n"
                                    "1 2 3 1000\n1 2 3 1050\n0 0 0 7\n1 2 3 1100\n")  # the zero point is dropped
    assert read_point_cloud(tmp_path / "t.pcd").time_offsets() is None  # no unit: the times are not used
    offsets = read_point_cloud(tmp_path / "t.pcd", time_unit_s=unit).time_offsets()
    np.testing.assert_array_equal(offsets, np.array(expected, np.float32))


def test_a_time_unit_is_refused_for_a_cloud_without_times_or_with_a_span_no_frame_has(tmp_path):
    np.save(tmp_path / "x.npy", np.array([[1, 2, 3, 4]], np.float32))
    with pytest.raises(DataFormatError) as error:
        read_point_cloud(tmp_path / "x.npy", time_unit_s=1e-6)
    assert str(error.value) == (f"{tmp_path / 'x.npy'}: a time unit was given (--time-unit) but the file has no time "
                                "field (one of time, time_offset, timestamp, t, offset_time; it has x, y, z, "
                                "intensity): drop --time-unit")
    np.save(tmp_path / "t.npy", np.array([[1, 2, 3, 4, 0], [1, 2, 3, 4, 100_001]], np.float64))  # 0.1 s in us
    assert read_point_cloud(tmp_path / "t.npy", time_unit_s=1e-6).time_offsets().tolist() == [0.0, np.float32(0.100001)]
    with pytest.raises(DataFormatError) as error:
        read_point_cloud(tmp_path / "t.npy", time_unit_s=1e-3)  # the same times read as milliseconds: 100 s
    assert str(error.value) == (f"{tmp_path / 't.npy'}: its points' 'time' spans 100 s in unit ms, more than a "
                                "frame's 10 s: the recorder writes a smaller unit (try --time-unit us or ns)")
    np.save(tmp_path / "t.npy", np.array([[1, 2, 3, 4, 0], [1, 2, 3, 4, 2e10]], np.float64))
    with pytest.raises(DataFormatError, match=r"spans 20 s in unit ns, .*: these are no times within one frame"):
        read_point_cloud(tmp_path / "t.npy", time_unit_s=1e-9)


def test_int16_coordinates_at_their_most_negative_are_refused_as_beyond_any_lidar_range(tmp_path):
    points = np.zeros(3, [("x", "<i2"), ("y", "<i2"), ("z", "<i2")])
    points[1] = (1, 2, 3)
    points[2] = (4, -32768, 5)  # abs() of it wraps to itself in int16
    np.save(tmp_path / "i.npy", points)
    with pytest.raises(DataFormatError) as error:
        read_point_cloud(tmp_path / "i.npy")
    assert str(error.value).startswith(f"{tmp_path / 'i.npy'}: 1 point(s) lie beyond 1000 m, the first is point 2 "
                                       "(counting from 0) at [4.0, -32768.0, 5.0] m:")


def test_columns_of_mixed_types_become_float32_points_with_invalid_ones_dropped_and_counted(tmp_path):
    points = np.zeros(5, [("x", "<f8"), ("y", "<i4"), ("z", "<f4"), ("reflectivity", "<u2"), ("t", "<u4")])
    points["x"] = [0.1, np.nan, 0.0, 999.9999999, -1e-46]  # -1e-46 is a nonzero float64 that rounds to -0 in float32
    points["y"] = [2, 3, 0, -1000, 0]
    points["z"] = [3.5, 1.0, 0.0, 0.25, 0.0]
    points["reflectivity"] = [7, 8, 9, 65535, 1]
    points["t"] = [10, 20, 30, 40, 50]
    np.save(tmp_path / "m.npy", points)
    cloud = read_point_cloud(tmp_path / "m.npy")
    assert cloud.points.dtype == np.float32 and cloud.dropped == 2  # the NaN point and the all-zero point
    expected = [[np.float32(0.1), 2.0, 3.5, 7.0], [1000.0, -1000.0, 0.25, 65535.0], [-0.0, 0.0, 0.0, 1.0]]
    assert cloud.points.tolist() == expected and np.signbit(cloud.points[2, 0])  # kept: valid in the file's float64
    assert cloud.time.dtype == np.float64 and cloud.time.tolist() == [10.0, 40.0, 50.0] and cloud.has_intensity
