"""OpenPCDet custom layout: read/write and the export of our KITTI layout."""
import errno
import hashlib
import os
import re

import numpy as np
import pytest

from pcdet_memslidar.cli import main
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io import custom, kitti
from pcdet_memslidar.io.layout import KittiLayout, read_frame, write_frame, write_split
from pcdet_memslidar.utils.atomic import OWNER_FILE


def test_export_custom_round_trip(tmp_path):
    layout = KittiLayout(tmp_path / "kitti")
    rng = np.random.default_rng(0)
    for i in range(5):
        boxes = np.column_stack([rng.uniform(1, 30, i), rng.uniform(-10, 10, i), np.full(i, 0.9),
                                 np.full((i, 2), 0.6), np.full(i, 1.8), rng.uniform(-np.pi, np.pi, i)])
        write_frame(layout, f"{i:06d}", rng.normal(size=(20 + i, 4)), ["Pedestrian"] * i, boxes, {})
    train, val = write_split(layout)
    out = tmp_path / "custom"
    assert custom.export_custom(layout.root, out) == 5
    assert sorted(path.name for path in out.iterdir()) == [OWNER_FILE, "ImageSets", "labels", "points"]
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
    layout = KittiLayout(tmp_path / "kitti")
    write_frame(layout, "000000", np.zeros((3, 4)), ["Pedestrian"], np.array([[5, 0, 0.9, 0.6, 0.5, 1.8, 0]]), {})
    assert main(["export-custom", "--src", str(layout.root), "--out", str(tmp_path / "out")]) == 0
    assert "exported 1 frames" in capsys.readouterr().out
    assert custom.read_custom_label(tmp_path / "out/labels/000000.txt")[0].tolist() == ["Pedestrian"]


def _tree(root):
    """{relative path: sha256} of every file under `root`."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in root.rglob("*") if p.is_file()}


def _export_error(capsys, *args) -> str:
    """stderr of `memslidar export-custom ARGS`, which must exit 2 without a traceback."""
    with pytest.raises(SystemExit) as exit_:
        main(["export-custom", "--src", str(args[0]), "--out", str(args[1])])
    assert exit_.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("memslidar export-custom: error: ") and "Traceback" not in error
    return error


def test_export_custom_never_replaces_an_input_or_what_it_did_not_write(tmp_path, capsys):
    layout = KittiLayout(tmp_path / "data" / "kitti")
    write_frame(layout, "000000", np.ones((3, 4)), ["Pedestrian"], np.array([[5, 0, 0.9, 0.6, 0.5, 1.8, 0]]), {})
    source = _tree(layout.root)
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    (tmp_path / "file").write_text("mine")
    for out, message in ((layout.root, rf"--out {layout.root} is the input {layout.root}; choose --out outside"),
                         (tmp_path / "data", "--out .*data contains the input .*kitti"),
                         (user, f"{user} holds files that memslidar export-custom did not write .*choose a new folder"),
                         (tmp_path / "file", f"{tmp_path / 'file'} is a file")):
        assert re.search(message, _export_error(capsys, layout.root, out))
    assert _tree(layout.root) == source and list(user.iterdir()) == [user / "notes.txt"]
    assert (user / "notes.txt").read_text() == (tmp_path / "file").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "file", "user"]  # no temporary left behind

    out = tmp_path / "custom"
    assert custom.export_custom(layout.root, out) == 1
    write_frame(layout, "000001", np.ones((4, 4)), [], np.zeros((0, 7)), {})
    assert custom.export_custom(layout.root, out) == 2  # a rerun replaces its own earlier export
    assert sorted(p.name for p in (out / "points").iterdir()) == ["000000.npy", "000001.npy"]


def test_export_custom_into_a_read_only_folder_is_a_clear_error(tmp_path, capsys, monkeypatch):
    layout = KittiLayout(tmp_path / "kitti")
    write_frame(layout, "000000", np.ones((3, 4)), [], np.zeros((0, 7)), {})
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    real_mkdir = os.mkdir

    def mkdir(path, mode=0o777):  # root ignores permissions: refuse as a read-only folder would
        if str(path).startswith(str(read_only)):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        real_mkdir(path, mode)

    monkeypatch.setattr(os, "mkdir", mkdir)
    error = _export_error(capsys, layout.root, read_only / "custom")
    assert f"{read_only / 'custom'}: Permission denied; choose a folder you may write to" in error
    assert not list(read_only.iterdir())
