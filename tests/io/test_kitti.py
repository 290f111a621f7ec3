"""KITTI files: points, labels, calib, ImageSets; label <-> LiDAR boxes; malformed input; atomic writes."""

import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io import kitti
from pcdet_memslidar.utils import atomic

LINE = "Pedestrian 0.00 0 -1.37 600.00 150.00 650.00 250.00 1.80 0.50 0.60 -2.00 0.00 10.00 -1.57"


def _write(path, text):
    path.write_text(text)
    return path


def _random_boxes(rng, count):
    headings = np.concatenate([[np.pi, -np.pi, np.pi - 1e-9, -np.pi + 1e-9, 0.0, np.pi / 2, -np.pi / 2],
                               rng.uniform(-np.pi, np.pi, count - 7)])
    return np.column_stack([rng.uniform(0.5, 40, count), rng.uniform(-20, 20, count), rng.uniform(0.3, 1.5, count),
                            rng.uniform(0.2, 1.2, (count, 2)), rng.uniform(0.5, 2.0, count), headings])


def _same_heading(a, b, atol):
    return np.allclose(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))), 0, atol=atol)


def test_points_round_trip_and_malformed_files(tmp_path):
    points = np.random.default_rng(0).normal(size=(37, 4)).astype(np.float32)
    kitti.write_points(tmp_path / "a.bin", points)
    assert (tmp_path / "a.bin").stat().st_size == 37 * 16
    np.testing.assert_array_equal(kitti.read_points(tmp_path / "a.bin"), points)
    assert kitti.read_points(_write(tmp_path / "empty.bin", "")).shape == (0, 4)
    (tmp_path / "short.bin").write_bytes(points.tobytes()[:-4])
    with pytest.raises(DataFormatError, match=r"short\.bin: size 588 bytes is not a multiple of 16"):
        kitti.read_points(tmp_path / "short.bin")
    bad = points.copy()
    bad[5, 2] = np.nan
    (tmp_path / "nan.bin").write_bytes(bad.tobytes())
    with pytest.raises(DataFormatError, match=r"nan\.bin: 1 point\(s\) with NaN or inf, first at point index 5"):
        kitti.read_points(tmp_path / "nan.bin")
    with pytest.raises(DataFormatError, match=r"out\.bin: points must have shape \(N, 4\)"):
        kitti.write_points(tmp_path / "out.bin", points[:, :3])
    with pytest.raises(DataFormatError, match=r"missing\.bin: point file not found"):
        kitti.read_points(tmp_path / "missing.bin")
    assert not (tmp_path / "out.bin").exists()


@pytest.mark.parametrize("line, message", [
    (LINE.rsplit(" ", 1)[0], "expected 15 columns .* got 14"),
    (LINE + " 0.9 7", "expected 15 columns .* got 17"),
    (LINE.replace("1.80", "tall"), "non-numeric value 'tall'"),
    (LINE.replace("-2.00", "nan"), "NaN or inf"),
    (LINE.replace("10.00", "inf"), "NaN or inf"),
    (LINE.replace("0.50", "-0.50"), "negative size"),
    (LINE.replace(" 0 -1.37", " 0.5 -1.37"), "occluded must be an integer"),
])
def test_malformed_label_line_names_file_and_line(tmp_path, line, message):
    path = _write(tmp_path / "000007.txt", f"{LINE}\n\n{line}\n")
    with pytest.raises(DataFormatError, match=rf"000007\.txt:3: {message}") as error:
        kitti.read_label(path)
    assert error.value.line == 3 and error.value.path == path


def test_a_byte_order_mark_does_not_rename_the_first_object(tmp_path):
    path = tmp_path / "bom.txt"
    path.write_bytes(f"{LINE}\n{LINE}\n".encode("utf-8-sig"))  # as Windows Notepad saves "UTF-8 with BOM"
    assert kitti.read_label(path).name.tolist() == ["Pedestrian", "Pedestrian"]
    ids = tmp_path / "train.txt"
    ids.write_bytes("000001\n000002\n".encode("utf-8-sig"))
    assert kitti.read_image_set(ids) == ["000001", "000002"]


def test_score_column_on_some_lines_only(tmp_path):
    path = _write(tmp_path / "p.txt", f"{LINE} 0.9\n{LINE}\n")
    with pytest.raises(DataFormatError, match=r"p\.txt:2: score column present on some lines only"):
        kitti.read_label(path)


def test_label_file_round_trip_keeps_long_names_and_scores(tmp_path):
    path = _write(tmp_path / "gt.txt", f"{LINE}\nDontCare -1 -1 -10 1.0 2.0 3.0 4.0 -1 -1 -1 -1000 -1000 -1000 -10\n")
    label = kitti.read_label(path)
    assert label.name.tolist() == ["Pedestrian", "DontCare"] and label.score is None
    np.testing.assert_allclose(label.dimensions[0], [0.60, 1.80, 0.50])  # l h w
    np.testing.assert_allclose(label.location[0], [-2.0, 0.0, 10.0])
    np.testing.assert_allclose(label.bbox[1], [1, 2, 3, 4])
    label.name = np.array(["AVeryLongPersonClassName", "DontCare"])
    label.score = np.array([0.123456, 0.5])
    kitti.write_label(tmp_path / "pred.txt", label)
    back = kitti.read_label(tmp_path / "pred.txt")
    assert back.name.tolist() == ["AVeryLongPersonClassName", "DontCare"]
    np.testing.assert_allclose(back.score, [0.123456, 0.5])
    for field in ("truncated", "occluded", "alpha", "bbox", "dimensions", "location", "rotation_y"):
        np.testing.assert_allclose(getattr(back, field), getattr(label, field), atol=1e-9)
    assert len(kitti.read_label(_write(tmp_path / "none.txt", ""))) == 0


def test_known_box_to_label_values():
    # a person 10 m ahead, 2 m left, standing on the ground, facing +x
    label = kitti.label_from_boxes(["Pedestrian"], np.array([[10.0, 2.0, 0.9, 0.6, 0.5, 1.8, 0.0]]),
                                   Calibration.virtual(), scores=[0.7])
    np.testing.assert_allclose(label.location, [[-2.0, 0.0, 10.0]], atol=1e-12)  # bottom centre, camera frame
    np.testing.assert_allclose(label.dimensions, [[0.6, 1.8, 0.5]])
    np.testing.assert_allclose(label.rotation_y, [-np.pi / 2])
    np.testing.assert_allclose(label.alpha, [-np.pi / 2 + np.arctan2(2.0, 10.0)])
    np.testing.assert_allclose(label.score, [0.7])
    # projected 2D box: focal 721.5377, centre (609.5593, 172.854); the box's near face is at depth 9.7
    x1, y1, x2, y2 = label.bbox[0]
    assert x1 == pytest.approx(609.5593 + 721.5377 * -2.25 / 9.7)
    assert x2 == pytest.approx(609.5593 + 721.5377 * -1.75 / 10.3)
    assert y1 == pytest.approx(172.854 - 721.5377 * 1.8 / 9.7) and y2 == pytest.approx(172.854)


def test_label_box_round_trip_with_headings_near_pi(tmp_path):
    rng = np.random.default_rng(1)
    boxes = _random_boxes(rng, 200)
    calib = Calibration.virtual()
    label = kitti.label_from_boxes(["Pedestrian"] * len(boxes), boxes, calib)
    back = kitti.boxes_from_label(label, calib)
    np.testing.assert_allclose(back[:, :6], boxes[:, :6], atol=1e-9)
    assert _same_heading(back[:, 6], boxes[:, 6], 1e-9)
    assert (back[:, 6] >= -np.pi).all() and (back[:, 6] < np.pi).all()
    assert (label.rotation_y >= -np.pi).all() and (label.rotation_y < np.pi).all()
    kitti.write_label(tmp_path / "l.txt", label)  # through the file: 4 decimals
    from_file = kitti.boxes_from_label(kitti.read_label(tmp_path / "l.txt"), calib)
    np.testing.assert_allclose(from_file[:, :6], boxes[:, :6], atol=1.1e-4)  # z: bottom + h / 2, both rounded
    assert _same_heading(from_file[:, 6], boxes[:, 6], 6e-5)


def test_calib_round_trip_and_errors(tmp_path):
    calib = Calibration(P2=np.arange(12.0).reshape(3, 4) + 0.1234567891, R0=np.eye(3) * 1.5,
                        V2C=np.arange(12.0).reshape(3, 4) / 7)
    kitti.write_calib(tmp_path / "c.txt", calib)
    back = kitti.read_calib(tmp_path / "c.txt")
    for name in ("P2", "R0", "V2C"):
        np.testing.assert_allclose(getattr(back, name), getattr(calib, name), rtol=1e-12)
    lines = (tmp_path / "c.txt").read_text().splitlines()
    assert [line.split(":")[0] for line in lines] == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam",
                                                      "Tr_imu_to_velo"]
    with pytest.raises(DataFormatError, match=r"c1\.txt:5: R0_rect: expected 9 numbers, got 8"):
        kitti.read_calib(_write(tmp_path / "c1.txt", "\n".join(lines[:4] + [lines[4].rsplit(" ", 1)[0]])))
    with pytest.raises(DataFormatError, match=r"c2\.txt: missing Tr_velo_to_cam"):
        kitti.read_calib(_write(tmp_path / "c2.txt", "\n".join(lines[:5])))
    with pytest.raises(DataFormatError, match=r"c3\.txt:1: P2: non-numeric"):
        kitti.read_calib(_write(tmp_path / "c3.txt", "P2: 1 2 x"))
    with pytest.raises(DataFormatError, match=r"c4\.txt:1: expected 'KEY: numbers'"):
        kitti.read_calib(_write(tmp_path / "c4.txt", "P9: 1 2"))


def test_image_sets(tmp_path):
    kitti.write_image_set(tmp_path / "ImageSets/train.txt", ["000002", "000000", "000010"])
    assert kitti.read_image_set(tmp_path / "ImageSets/train.txt") == ["000002", "000000", "000010"]
    with pytest.raises(DataFormatError, match=r"dup\.txt:3: frame id 000001 repeats line 1"):
        kitti.read_image_set(_write(tmp_path / "dup.txt", "000001\n000002\n000001\n"))
    with pytest.raises(DataFormatError, match=r"sp\.txt:1: expected one frame id per line"):
        kitti.read_image_set(_write(tmp_path / "sp.txt", "000001 000002\n"))
    with pytest.raises(DataFormatError, match="frame ids repeat"):
        kitti.write_image_set(tmp_path / "x.txt", ["1", "1"])


def test_failed_write_leaves_no_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "000001.bin"
    kitti.write_points(target, np.ones((2, 4), np.float32))
    original = target.read_bytes()

    class Crashing:  # a file that dies half-way through writing the temporary file
        def __init__(self, handle):
            self.handle = handle

        def __enter__(self):
            return self

        def __exit__(self, *error):
            self.handle.close()

        def write(self, data):
            data = memoryview(data).cast("B")
            self.handle.write(data[: len(data) // 2])
            raise OSError("disk full")

    monkeypatch.setattr(atomic, "open", lambda *args, **kwargs: Crashing(open(*args, **kwargs)), raising=False)
    with pytest.raises(OSError, match="disk full"):
        kitti.write_points(target, np.zeros((50, 4), np.float32))
    with pytest.raises(OSError, match="disk full"):
        kitti.write_points(tmp_path / "000002.bin", np.zeros((50, 4), np.float32))
    monkeypatch.undo()
    assert target.read_bytes() == original  # the old file is untouched
    assert sorted(path.name for path in tmp_path.iterdir()) == ["000001.bin"]
    label = kitti.label_from_boxes(["Pedestrian"], np.array([[1, 2, 3, 1, 1, 1, 0.0]]), Calibration.virtual())
    label.location[0, 0] = np.inf
    with pytest.raises(DataFormatError, match=r"bad\.txt: object 0 \(Pedestrian\): NaN or inf"):
        kitti.write_label(tmp_path / "bad.txt", label)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["000001.bin"]
