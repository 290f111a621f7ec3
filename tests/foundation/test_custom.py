"""OpenPCDet custom layout: read/write and the export of our KITTI layout."""
import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io import custom, kitti
from pcdet_memslidar.io.layout import KittiLayout, read_frame, write_frame, write_split


def test_export_custom_round_trip(tmp_path):
    layout = KittiLayout(tmp_path / "kitti")
    rng = np.random.default_rng(0)
    for i in range(5):
        boxes = np.column_stack([rng.uniform(1, 30, i), rng.uniform(-10, 10, i), np.full(i, 0.9),
                                 np.full((i, 2), 0.6), np.full(i, 1.8), rng.uniform(-np.pi, np.pi, i)])
        write_frame(layout, f"{i:06d}", rng.normal(size=(20 + i, 4)), ["Pedestrian"] * i, boxes, {})
    train, val = write_split(layout)
    out = tmp_path / "custom"
    (out / "stale").mkdir(parents=True)  # replaced whole
    assert custom.export_custom(layout.root, out) == 5
    assert sorted(path.name for path in out.iterdir()) == ["ImageSets", "labels", "points"]
    assert kitti.read_image_set(out / "ImageSets/train.txt") == train
    assert kitti.read_image_set(out / "ImageSets/val.txt") == val
    for i in range(5):
        frame = read_frame(layout, f"{i:06d}")
        points = custom.read_custom_points(out / "points" / f"{i:06d}.npy")
        assert points.dtype == np.float32
        np.testing.assert_array_equal(points, frame["points"])
        names, boxes = custom.read_custom_label(out / "labels" / f"{i:06d}.txt")
        assert names.tolist() == frame["gt_names"].tolist()
        np.testing.assert_allclose(boxes, frame["gt_boxes"], atol=1e-4)
    line = (out / "labels/000001.txt").read_text().split()
    assert len(line) == 8 and line[-1] == "Pedestrian"


def test_custom_errors(tmp_path):
    good = "1.0 2.0 0.9 0.6 0.5 1.8 0.1 Pedestrian\n"
    cases = {"cols.txt": ("1 2 3 Pedestrian", "expected 8 columns"),
             "num.txt": ("1 2 x 0.6 0.5 1.8 0.1 Pedestrian", "columns 1-7 must be numbers"),
             "nan.txt": ("1 2 nan 0.6 0.5 1.8 0.1 Pedestrian", "NaN or inf"),
             "neg.txt": ("1 2 0.9 0.6 -0.5 1.8 0.1 Pedestrian", "negative size")}
    for name, (line, message) in cases.items():
        (tmp_path / name).write_text(good + line + "\n")
        with pytest.raises(DataFormatError, match=rf"{name.replace('.', '[.]')}:2: {message}"):
            custom.read_custom_label(tmp_path / name)
    np.save(tmp_path / "p.npy", np.zeros((4, 3), np.float32))
    with pytest.raises(DataFormatError, match=r"p\.npy: expected an \(N, 4\) numeric array"):
        custom.read_custom_points(tmp_path / "p.npy")
    with pytest.raises(DataFormatError, match="no frames"):
        custom.export_custom(tmp_path / "empty", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_export_custom_command(tmp_path, capsys):
    from pcdet_memslidar.cli import main

    layout = KittiLayout(tmp_path / "kitti")
    write_frame(layout, "000000", np.zeros((3, 4)), ["Pedestrian"], np.array([[5, 0, 0.9, 0.6, 0.5, 1.8, 0]]), {})
    assert main(["export-custom", str(layout.root), str(tmp_path / "out")]) == 0
    assert "exported 1 frames" in capsys.readouterr().out
    assert custom.read_custom_label(tmp_path / "out/labels/000000.txt")[0].tolist() == ["Pedestrian"]
