"""CVAT 3D-cuboid exports (Sly Point Cloud 1.0, Kitti Raw 1.0), hand-written here, into ground-frame boxes."""
import json
import shutil
import zipfile

import numpy as np
import pytest

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import cvat
from pcdet_memslidar.io.ground import normalise_boxes
from pcdet_memslidar.io.importer import import_dataset
from pcdet_memslidar.io.layout import KittiLayout, read_frame

DEG = np.pi / 180


def write_pcd(path, points):
    """Binary PCD of (N, 4) x, y, z, intensity."""
    path.parent.mkdir(parents=True, exist_ok=True)
    header = (f"VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {len(points)}\n"
              f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(points)}\nDATA binary\n")
    path.write_bytes(header.encode() + np.asarray(points, "<f4").tobytes())


def write_sly(root, frames, dataset="ds0"):
    """frames: {name: (points (N, 4), [(class, position xyz, rotation xyz, dimensions xyz), ...] or None)}, in the
    dataset folder `dataset`."""
    classes = sorted({c[0] for _, cuboids in frames.values() for c in cuboids or []})
    (root / dataset).mkdir(parents=True, exist_ok=True)
    (root / "meta.json").write_text(json.dumps({"classes": [{"title": c, "shape": "cuboid_3d"} for c in classes],
                                                "tags": [], "projectType": "point_clouds"}))
    (root / "key_id_map.json").write_text(json.dumps({"tags": {}, "objects": {}, "figures": {}, "videos": {}}))
    for name, (points, cuboids) in frames.items():
        write_pcd(root / dataset / "pointcloud" / f"{name}.pcd", points)
        if cuboids is None:
            continue
        axes = lambda v: dict(zip("xyz", map(float, v)))  # noqa: E731
        ann = {"description": "", "key": name, "tags": [],
               "objects": [{"key": f"o{i}", "classTitle": c[0], "tags": []} for i, c in enumerate(cuboids)],
               "figures": [{"key": f"f{i}", "objectKey": f"o{i}", "geometryType": "cuboid_3d",
                            "geometry": {"position": axes(c[1]), "rotation": axes(c[2]), "dimensions": axes(c[3])}}
                           for i, c in enumerate(cuboids)]}
        (root / dataset / "ann").mkdir(exist_ok=True)
        (root / dataset / "ann" / f"{name}.pcd.json").write_text(json.dumps(ann))


def write_kitti_raw(root, names, tracklets):
    """names: frame names in index order; tracklets: [(class, h, w, l, first_frame, [(tx, ty, tz, rz), ...])]."""
    for name in names:
        write_pcd(root / "velodyne_points" / "data" / f"{name}.pcd", np.ones((3, 4)))
    (root / "frame_list.txt").write_text("".join(f"{i} {name}\n" for i, name in enumerate(names)))
    items = []
    for label, h, w, l, first, poses in tracklets:
        pose_xml = "".join(f"<item><tx>{tx}</tx><ty>{ty}</ty><tz>{tz}</tz><rx>0</rx><ry>0</ry><rz>{rz}</rz>"
                           "<state>2</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf>"
                           "<truncation>0</truncation><amt_occlusion>-1</amt_occlusion></item>"
                           for tx, ty, tz, rz in poses)
        items.append(f"<item><objectType>{label}</objectType><h>{h}</h><w>{w}</w><l>{l}</l>"
                     f"<first_frame>{first}</first_frame><poses><count>{len(poses)}</count>"
                     f"<item_version>2</item_version>{pose_xml}</poses><finished>1</finished></item>")
    (root / "tracklet_labels.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<!DOCTYPE boost_serialization>\n'
        '<boost_serialization version="9" signature="serialization::archive"><tracklets class_id="0" '
        f'tracking_level="0" version="0"><count>{len(items)}</count><item_version>1</item_version>{"".join(items)}'
        "</tracklets></boost_serialization>")


# Hand derivation of the rotated box (Sly export annotated in the raw, tilted sensor frame):
#   mount: height 4 m, tilt 30 deg: sensor -> ground R = Ry(30 deg) = [[c, 0, s], [0, 1, 0], [-s, 0, c]],
#   c = cos 30 = 0.8660254, s = 0.5, then + (0, 0, 4).
#   cuboid: position (5, 0, -1), rotation (x 0, y -30 deg, z 30 deg), dimensions (0.6, 0.4, 1.8).
#   box -> sensor (three.js 'XYZ'): Rx(0) Ry(-30) Rz(30), so box -> ground = Ry(30) Ry(-30) Rz(30) = Rz(30):
#   upright, heading 30 deg = 0.5235988 rad.
#   centre: Ry(30) (5, 0, -1) = (5c - s, 0, -5s - c) = (3.8301270, 0, -3.3660254); + 4 m -> z = 0.6339746.
#   sizes stay (0.6, 0.4, 1.8) along the box's own x, y, z = dx, dy, dz.
ROTATED_CUBOID = ("Person", (5.0, 0.0, -1.0), (0.0, -30 * DEG, 30 * DEG), (0.6, 0.4, 1.8))
ROTATED_EXPECTED = [3.8301270, 0.0, 0.6339746, 0.6, 0.4, 1.8, 0.5235988]
MOUNT = Mount(4.0, 30.0)


def test_sly_rotated_box_in_a_tilted_frame(tmp_path):
    write_sly(tmp_path, {"frame_2": (np.ones((3, 4)), [ROTATED_CUBOID]), "frame_10": (np.ones((3, 4)), None)})
    frames = cvat.read_sly_export(tmp_path)
    assert [f.name for f in frames] == ["ds0/frame_2", "ds0/frame_10"] and frames[1].labels == []
    boxes, levelling = normalise_boxes(frames[0].centers, frames[0].rotations, frames[0].sizes, MOUNT)
    np.testing.assert_allclose(boxes, [ROTATED_EXPECTED], atol=1e-6)
    np.testing.assert_allclose(levelling, [0.0], atol=1e-6)


def test_kitti_raw_sizes_and_centre_conventions(tmp_path):
    # one cuboid of size x 0.6, y 0.4, z 1.8: CVAT writes it as w = 0.6 (x), h = 0.4 (y), l = 1.8 (z) at its centre;
    # a devkit-style file writes l = 0.6 (x), w = 0.4 (y), h = 1.8 (z) at its bottom centre (z 0 -> centre 0.9).
    write_kitti_raw(tmp_path / "cvat", ["a", "b", "c"], [("person", 0.4, 0.6, 1.8, 2, [(4.0, -1.0, 0.9, -2.0)])])
    write_kitti_raw(tmp_path / "kitti", ["a"], [("Pedestrian", 1.8, 0.4, 0.6, 0, [(4.0, -1.0, 0.0, -2.0)])])
    frames = cvat.read_kitti_raw_export(tmp_path / "cvat")
    assert [(f.name, len(f.labels)) for f in frames] == [("a", 0), ("b", 0), ("c", 1)]
    devkit = cvat.read_kitti_raw_export(tmp_path / "kitti", convention="kitti")[0]
    expected = [[4.0, -1.0, 0.9, 0.6, 0.4, 1.8, -2.0]]
    for frame in (frames[2], devkit):
        boxes, _ = normalise_boxes(frame.centers, frame.rotations, frame.sizes, Mount(0.0, 0.0))
        np.testing.assert_allclose(boxes, expected, atol=1e-9)


def test_class_names_map_to_pedestrian_and_unknown_names_fail_or_are_counted(tmp_path):
    box = ((1, 0, 0), (0, 0, 0), (0.5, 0.5, 1.7))
    write_sly(tmp_path, {"f": (np.ones((3, 4)), [(name, *box) for name in ("person", "Pedestrian", "PERSON",
                                                                           "forklift", "Forklift", "dog")])})
    frames = cvat.read_sly_export(tmp_path)
    with pytest.raises(DataFormatError, match=r"'Forklift' \(1\), 'dog' \(1\), 'forklift' \(1\).*--skip-unknown"):
        cvat.person_mask(frames, skip_unknown=False, source=tmp_path)
    masks, unknown = cvat.person_mask(frames, skip_unknown=True, source=tmp_path)
    assert masks[0].tolist() == [True, True, True, False, False, False] and sum(unknown.values()) == 3


def test_bad_exports_raise_naming_the_file(tmp_path):
    write_sly(tmp_path / "size", {"f": (np.ones((3, 4)), [("person", (1, 0, 0), (0, 0, 0), (0.5, 0.0, 1.7))])})
    with pytest.raises(DataFormatError, match=r"f\.pcd\.json: figure f0: non-positive box size"):
        cvat.read_sly_export(tmp_path / "size")
    write_sly(tmp_path / "orphan", {"f": (np.ones((3, 4)), [ROTATED_CUBOID])})
    (tmp_path / "orphan" / "ds0" / "pointcloud" / "f.pcd").unlink()
    with pytest.raises(DataFormatError, match="frame-list mismatch"):
        cvat.read_sly_export(tmp_path / "orphan")
    write_kitti_raw(tmp_path / "raw", ["a"], [("person", 1.8, 0.5, 0.5, 1, [(4, 0, 0, 0)])])
    with pytest.raises(DataFormatError, match="frame-list mismatch: tracklet 0 .* frame 1"):
        cvat.read_kitti_raw_export(tmp_path / "raw")
    (tmp_path / "raw" / "tracklet_labels.xml").write_text("<boost_serialization><tracklets><item>")
    with pytest.raises(DataFormatError, match="malformed XML"):
        cvat.read_kitti_raw_export(tmp_path / "raw")


def test_import_of_a_zipped_sly_export_writes_ground_frame_labels(tmp_path):
    # 20 points inside the rotated person box and 3 floor points, all given in the tilted sensor frame
    rng = np.random.default_rng(0)
    inside = np.array(ROTATED_EXPECTED[:3]) + rng.uniform(-0.15, 0.15, (20, 3))
    floor = np.array([[3.0, 2.0, 0.0], [6.0, -2.0, 0.0], [30.0, 30.0, 0.0]])  # the last one out of range
    points = np.column_stack([MOUNT.ground_to_sensor(np.vstack([inside, floor])), np.full(23, 50.0)])
    points = np.vstack([points, [[0, 0, 0, 0], [np.nan, np.nan, np.nan, 0]]])  # pulses without return
    small = ("person", MOUNT.ground_to_sensor([[6.0, -2.0, 0.9]])[0], (0, -30 * DEG, 0), (0.5, 0.5, 1.8))
    write_sly(tmp_path / "export", {"000": (points, [ROTATED_CUBOID, small]), "001": (points[:5], [])})
    shutil.make_archive(str(tmp_path / "export"), "zip", tmp_path / "export")
    assert zipfile.is_zipfile(tmp_path / "export.zip")

    report = import_dataset("cvat-sly", tmp_path / "export.zip", tmp_path / "real", mount=MOUNT)
    assert (report["frames"], report["boxes"], report["boxes_under_min_points"]) == (2, 2, 1)
    counts = report["frames_without_labels"], report["dropped_invalid_points"], report["points_out_of_range"]
    assert counts == (1, 2, 1)
    frame = read_frame(KittiLayout(tmp_path / "real"), "000000")
    np.testing.assert_allclose(frame["gt_boxes"][0], ROTATED_EXPECTED, atol=2e-4)
    np.testing.assert_allclose(frame["gt_boxes"][1], [6.0, -2.0, 0.9, 0.5, 0.5, 1.8, 0.0], atol=2e-4)
    assert list(frame["gt_names"]) == ["Pedestrian", "Pedestrian"]
    assert frame["metadata"]["num_points_in_gt"] == [20, 1]
    np.testing.assert_allclose(frame["points"][:20, :3], inside, atol=1e-5)
    assert json.loads((tmp_path / "real" / "import_report.json").read_text())["boxes"] == 2


def test_sly_frames_of_two_datasets_with_one_name_stay_apart(tmp_path):
    box = ((1, 0, 0), (0, 0, 0), (0.5, 0.5, 1.7))
    write_sly(tmp_path, {"f1": (np.ones((3, 4)), [("person", *box)])}, dataset="ds0")
    write_sly(tmp_path, {"f1": (np.full((4, 4), 2.0), [("person", *box), ("person", *box)])}, dataset="ds1")
    frames = cvat.read_sly_export(tmp_path)
    assert [(f.name, f.cloud_path.parent.parent.name, len(f.labels)) for f in frames] == [("ds0/f1", "ds0", 1),
                                                                                          ("ds1/f1", "ds1", 2)]


def test_sly_annotation_that_is_a_json_list(tmp_path):
    write_sly(tmp_path, {"f": (np.ones((3, 4)), [])})
    (tmp_path / "ds0" / "ann" / "f.pcd.json").write_text("[]")
    with pytest.raises(DataFormatError, match=r"f\.pcd\.json: not a Sly point-cloud annotation \(TypeError: the file "
                                              r"holds a JSON list, not an object with 'objects' and 'figures'\)"):
        cvat.read_sly_export(tmp_path)


def test_zip_with_a_bad_crc_names_the_archive(tmp_path):
    write_sly(tmp_path / "export", {"f": (np.ones((3, 4)), [])})
    with zipfile.ZipFile(tmp_path / "export.zip", "w", zipfile.ZIP_STORED) as archive:
        for path in sorted((tmp_path / "export").rglob("*")):
            archive.write(path, path.relative_to(tmp_path / "export"))
    data = bytearray((tmp_path / "export.zip").read_bytes())
    start = data.index(b"DATA binary\n") + len(b"DATA binary\n")
    data[start] ^= 0xFF  # one byte of the stored point cloud
    (tmp_path / "export.zip").write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"export\.zip: corrupt zip archive \(Bad CRC-32 for file"):
        import_dataset("cvat-sly", tmp_path / "export.zip", tmp_path / "real")
    assert not (tmp_path / "real").exists()


@pytest.mark.parametrize("listing, message", [
    ("0 a\n1 b\n2 a\n", r"frame_list\.txt:3: name 'a' is listed again \(first on line 1\)"),
    ("0 a\n0 b\n", r"frame_list\.txt:2: frame index 0 is listed again \(first on line 1\)")])
def test_kitti_raw_frame_list_with_a_repeated_name_or_index(tmp_path, listing, message):
    write_kitti_raw(tmp_path, ["a", "b"], [])
    (tmp_path / "frame_list.txt").write_text(listing)
    with pytest.raises(DataFormatError, match=message):
        cvat.read_kitti_raw_export(tmp_path)


def test_a_kitti_raw_frame_list_that_is_not_utf8_is_named(tmp_path):
    write_kitti_raw(tmp_path, ["a", "b"], [])
    (tmp_path / "frame_list.txt").write_bytes("0 a\n1 b\u00e4\n".encode("latin-1"))
    with pytest.raises(DataFormatError, match=r"frame_list\.txt: not a UTF-8 text file"):
        cvat.read_kitti_raw_export(tmp_path)


@pytest.mark.parametrize("first", ["1.7", "-1", "x"])
def test_kitti_raw_first_frame_must_be_a_frame_index(tmp_path, first):
    write_kitti_raw(tmp_path, ["a", "b", "c"], [("person", 0.4, 0.6, 1.8, first, [(4.0, -1.0, 0.9, 0.0)])])
    with pytest.raises(DataFormatError, match=rf"tracklet_labels\.xml: tracklet 0: <first_frame> '{first}' must be a "
                                              r"frame index \(an integer >= 0\)"):
        cvat.read_kitti_raw_export(tmp_path)
