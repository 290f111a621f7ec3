"""Our KITTI layout: whole frames written and read back, metadata, and the stable 70/30 split."""
import json

import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout, read_frame, stable_split, write_frame, write_split


def _frame(rng, boxes=3):
    points = rng.normal(size=(100, 4)).astype(np.float32)
    gt = np.column_stack([rng.uniform(1, 30, boxes), rng.uniform(-10, 10, boxes), rng.uniform(0.8, 1.0, boxes),
                          rng.uniform(0.4, 0.8, (boxes, 2)), rng.uniform(1.5, 1.9, boxes),
                          rng.uniform(-np.pi, np.pi, boxes)])
    return points, gt


def test_frame_round_trip(tmp_path):
    layout = KittiLayout(tmp_path / "sim")
    points, boxes = _frame(np.random.default_rng(0))
    metadata = {"seed": np.int64(7), "mount": {"tilt_deg": 16.0, "height": 4.0}, "counts": np.arange(3)}
    write_frame(layout, "000003", points, ["Pedestrian"] * 3, boxes, metadata)
    write_frame(layout, "000001", points[:0], [], np.zeros((0, 7)), {})
    assert layout.frame_ids() == ["000001", "000003"]
    frame = read_frame(layout, "000003")
    np.testing.assert_array_equal(frame["points"], points)
    assert frame["gt_names"].tolist() == ["Pedestrian"] * 3
    assert frame["gt_boxes"].dtype == np.float32
    np.testing.assert_allclose(frame["gt_boxes"][:, :6], boxes[:, :6], atol=1.1e-4)
    assert frame["metadata"] == {"counts": [0, 1, 2], "mount": {"height": 4.0, "tilt_deg": 16.0}, "seed": 7}
    text = layout.metadata("000003").read_text()
    assert text.index('"counts"') < text.index('"mount"') < text.index('"seed"')  # sorted keys
    assert text.index('"height"') < text.index('"tilt_deg"')
    empty = read_frame(layout, "000001")
    assert empty["points"].shape == (0, 4) and empty["gt_boxes"].shape == (0, 7) and len(empty["gt_names"]) == 0
    for path in (layout.velodyne("000003"), layout.label("000003"), layout.calib("000003")):
        assert path.parent.parent == tmp_path / "sim" / "training"
    assert layout.image_set("val") == tmp_path / "sim" / "ImageSets" / "val.txt"


def test_time_offsets_are_written_beside_the_points_and_named_in_the_metadata(tmp_path):
    layout = KittiLayout(tmp_path)
    points, boxes = _frame(np.random.default_rng(2))
    times = np.linspace(0.0, 0.4, len(points), dtype=np.float32)
    write_frame(layout, "000002", points, ["Pedestrian"] * 3, boxes, {}, time_offset=times)
    assert read_frame(layout, "000002")["metadata"] == {"time_offset_file": "training/time_offset/000002.bin"}
    np.testing.assert_array_equal(kitti.read_point_times(layout.time_offset("000002"), len(points)), times)
    with pytest.raises(ValueError, match="frame 000003: 1 time offsets for 3 points"):
        write_frame(layout, "000003", points[:3], [], np.zeros((0, 7)), {}, time_offset=times[:1])
    assert layout.frame_ids() == ["000002"]


def test_frame_errors(tmp_path):
    layout = KittiLayout(tmp_path)
    points, boxes = _frame(np.random.default_rng(1))
    with pytest.raises(ValueError, match="invalid frame id"):
        write_frame(layout, "a/b", points, ["Pedestrian"] * 3, boxes, {})
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        write_frame(layout, "000000", points, ["Pedestrian"] * 3, boxes, {"x": float("nan")})
    assert layout.frame_ids() == []
    write_frame(layout, "000000", points, ["Pedestrian"] * 3, boxes, {})
    layout.calib("000000").unlink()
    with pytest.raises(DataFormatError, match=r"calib/000000\.txt: file not found"):
        read_frame(layout, "000000")


def test_stable_split_is_exact_and_pinned():
    ids = [f"{i:06d}" for i in range(230)]
    train, val = stable_split(ids)
    assert (len(train), len(val)) == (161, 69)
    assert sorted(train + val) == ids and not set(train) & set(val)
    for block in range(23):  # exactly 3 of every 10 consecutive frames
        assert sum(f"{i:06d}" in val for i in range(10 * block, 10 * block + 10)) == 3
    assert val[:6] == ["000001", "000004", "000007", "000010", "000013", "000014"]  # pinned: never changes
    assert stable_split(ids, seed=1)[1][:6] == ["000003", "000008", "000009", "000010", "000013", "000016"]
    assert stable_split(list(reversed(ids))) == (train, val)
    assert stable_split(ids, val_fraction=0.5)[1].__len__() == 115
    with pytest.raises(ValueError, match="multiple of 0.1"):
        stable_split(ids, val_fraction=0.25)


def test_adding_frames_never_moves_existing_ones():
    ids = [f"{i:06d}" for i in range(47)]
    full_val = set(stable_split(ids)[1])
    for count in range(1, 47):
        train, val = stable_split(ids[:count])
        assert set(val) == full_val & set(ids[:count])
        assert set(train) == set(ids[:count]) - full_val


def test_write_split(tmp_path):
    layout = KittiLayout(tmp_path)
    points, boxes = _frame(np.random.default_rng(2), boxes=1)
    for i in range(12):
        write_frame(layout, f"{i:06d}", points, ["Pedestrian"], boxes, {"i": i})
    train, val = write_split(layout)
    assert kitti.read_image_set(layout.image_set("train")) == train and len(train) == 8
    assert kitti.read_image_set(layout.image_set("val")) == val and len(val) == 4
    assert json.loads(layout.metadata("000011").read_text()) == {"i": 11}
