"""MEMSLidarDataset on generated data: create-infos, Table 2 counts (smoke), batches, replacement, errors."""
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets import MEMSLidarDataset, build_dataloader
from pcdet_memslidar.datasets.infos import DBINFO_FILE, INFO_FILE, create_domain_infos
from pcdet_memslidar.datasets.mixing import Source
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.geometry.boxes import points_in_boxes_mask
from pcdet_memslidar.io import kitti
from pcdet_memslidar.io.layout import KittiLayout, write_frame
from pcdet_memslidar.utils.atomic import write_bytes

CFGS = Path(__file__).resolve().parents[2] / "cfgs"


def _cfg(name, data_path, *sets):
    return load_config(CFGS / f"{name}.yaml", ["PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(data_path), *sets])


def test_create_infos_writes_infos_and_a_centred_gt_database(memslidar_data):
    for name, frames in (("sim", 12), ("real", 12), ("industrial", 4)):
        stored = pickle.loads((memslidar_data / name / INFO_FILE).read_bytes())
        assert [info["frame_id"] for info in stored["infos"]] == [f"{i:06d}" for i in range(frames)]
    real = pickle.loads((memslidar_data / "real" / INFO_FILE).read_bytes())["infos"]
    assert len(real[2]["annos"]["name"]) == 0
    db = pickle.loads((memslidar_data / "real" / DBINFO_FILE).read_bytes())
    assert list(db) == ["Pedestrian"]
    assert len(db["Pedestrian"]) == sum(len(info["annos"]["name"]) for info in real)
    entry = db["Pedestrian"][0]
    points = np.fromfile(memslidar_data / "real" / entry["path"], dtype=np.float32).reshape(-1, 4)
    assert len(points) == entry["num_points_in_gt"] > 0
    centred_box = np.concatenate([[0.0, 0.0, 0.0], entry["box3d_lidar"][3:]])
    assert points_in_boxes_mask(points, centred_box[None]).all()


def test_m3_training_set_matches_table2_smoke_counts_and_batches_are_well_formed(memslidar_data):
    cfg = _cfg("m3", memslidar_data)
    dataset, loader, sampler = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False,
                                                workers=0, seed=0, training=True)
    assert sampler is None
    assert dataset.source_counts() == {"sim": 7, "real": 7}  # smoke M3: 10 / 10 before the 70 / 30 split
    val = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False, root_path=None)
    assert val.split == "test" and val.source_counts() == {"industrial": 4}
    cfg.DATA_CONFIG.DATA_SPLIT.test = "val"
    assert MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False).source_counts() == {"sim": 3, "real": 3}

    grid = dataset.grid_size
    seen_sources = []
    for batch in loader:
        b = batch["batch_size"]
        assert batch["points"].dtype == np.float32 and batch["points"].shape[1] == 5
        assert batch["voxels"].dtype == np.float32 and batch["voxels"].shape[1:] == (5, 4)
        assert batch["voxel_coords"].dtype == np.int32 and batch["voxel_num_points"].dtype == np.int32
        assert batch["gt_boxes"].dtype == np.float32 and batch["gt_boxes"].shape[0] == b
        assert batch["gt_boxes"].shape[2] == 8
        real = np.abs(batch["gt_boxes"]).sum(axis=2) > 0
        assert (batch["gt_boxes"][real][:, 7] == 1).all() and real.any(axis=1).all()
        assert (np.abs(batch["gt_boxes"][real][:, 6]) <= np.float32(np.pi / 4)).all()  # fold_box_headings
        assert set(np.unique(batch["voxel_coords"][:, 0])) == set(range(b))
        coords = batch["voxel_coords"][:, 1:]
        assert (coords >= 0).all() and (coords < grid[::-1]).all()
        # every voxel's first point lies in the cell its (z, y, x) coords name
        first = batch["voxels"][:, 0, :3]
        cell = np.floor((first - dataset.point_cloud_range[:3]) / dataset.voxel_size).astype(np.int64)
        np.testing.assert_array_equal(np.clip(cell, 0, grid - 1)[:, ::-1], coords)
        assert batch["voxel_num_points"].sum() <= len(batch["points"])
        seen_sources += [meta["source"] for meta in batch["metadata"]]
        assert [f.split("/")[0] for f in batch["frame_id"]] == [meta["source"] for meta in batch["metadata"]]
    assert sorted(seen_sources) == ["real"] * 7 + ["sim"] * 7


def test_balanced_batches_hold_both_sources(memslidar_data):
    cfg = _cfg("m3", memslidar_data, "DATA_CONFIG.MIX.BALANCE_BATCHES", "True")
    dataset, loader, sampler = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False,
                                                workers=0, seed=0)
    assert len(loader) == len(sampler) == 7
    for batch in loader:
        assert sorted(meta["source"] for meta in batch["metadata"]) == ["real", "sim"]


def test_training_frame_without_boxes_is_replaced(memslidar_data):
    cfg = _cfg("m1", memslidar_data, "DATA_CONFIG.MIX.TOTAL", "12",
               "DATA_CONFIG.DATA_AUGMENTOR.DISABLE_AUG_LIST", "gt_sampling")  # gt_sampling would fill the frame
    dataset = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    dataset.reseed(0)
    empty = next(i for i, info in enumerate(dataset.infos) if len(info["annos"]["name"]) == 0)
    assert dataset.infos[empty]["frame_id"] == "000002"
    sample = dataset[empty]
    assert sample["frame_id"] != "real/000002" and len(sample["gt_boxes"]) > 0
    test = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)
    cfg.DATA_CONFIG.DATA_SPLIT.test = "train"
    kept = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)
    assert kept[empty]["frame_id"] == "real/000002" and kept[empty]["gt_boxes"].shape == (0, 8)
    assert len(test) == 4


def test_dataset_without_any_box_is_a_clear_error(memslidar_data):
    cfg = _cfg("m1", memslidar_data, "DATA_CONFIG.MIX.TOTAL", "12")
    with pytest.raises(DataFormatError, match="no box of the classes \\['Cyclist'\\]"):
        MEMSLidarDataset(cfg.DATA_CONFIG, ["Cyclist"], training=True)


def test_too_few_frames_and_missing_infos_say_which_command_makes_them(memslidar_data, tmp_path):
    cfg = _cfg("m1", memslidar_data)  # smoke M1 needs 20 real frames, the data has 12
    with pytest.raises(DataFormatError) as error:
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    assert "has 12 frames but the mix needs 20" in str(error.value)
    assert f"memslidar simulate --domain real --frames 20 --out {memslidar_data / 'real'}" in str(error.value)
    cfg = _cfg("m3", tmp_path)
    with pytest.raises(DataFormatError, match="memslidar simulate --domain sim --frames 10 --out"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    industrial = tmp_path / "industrial"
    with pytest.raises(DataFormatError, match=f"memslidar simulate --domain industrial --out {industrial} --seed 0`"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)
    copy = tmp_path / "sim" / "training" / "velodyne"
    copy.mkdir(parents=True)
    (copy / "000000.bin").write_bytes((memslidar_data / "sim" / "training" / "velodyne" / "000000.bin").read_bytes())
    with pytest.raises(DataFormatError, match="memslidar create-infos --cfg"):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)


@pytest.mark.filterwarnings("ignore:no ground-truth")  # the tiny test split has no person in some distance bins
def test_predictions_keep_long_class_names_and_are_evaluated(memslidar_data, tmp_path):
    cfg = _cfg("m3", memslidar_data)
    dataset = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)
    gt = dataset.gt_annos()
    batch = {"frame_id": np.array([anno["frame_id"] for anno in gt])}
    preds = [{"pred_boxes": torch.from_numpy(anno["boxes_lidar"]), "pred_scores": torch.full((len(anno["name"]),), 0.9),
              "pred_labels": torch.ones(len(anno["name"]), dtype=torch.long)} for anno in gt]
    long_names = ["PedestrianWithAVeryLongName"]
    annos = dataset.generate_prediction_dicts(batch, preds, long_names, output_path=tmp_path)
    assert annos[0]["name"].tolist() == ["PedestrianWithAVeryLongName"] * len(gt[0]["name"])
    label = kitti.read_label(tmp_path / "industrial" / "000000.txt")
    assert label.name.tolist() == long_names * len(gt[0]["name"]) and np.allclose(label.score, 0.9)

    annos = dataset.generate_prediction_dicts(batch, preds, cfg.CLASS_NAMES)
    text, scalars = dataset.evaluation(annos[::-1], cfg.CLASS_NAMES)
    assert scalars["AP3D_R40"] == pytest.approx(1.0) and scalars["APBEV_R11"] == pytest.approx(1.0)
    assert scalars["num_gt"] == sum(len(anno["name"]) for anno in gt)
    assert "AP3D_R40" in text and all(isinstance(value, float) for value in scalars.values())
    _, scalars = dataset.evaluation(annos[:1], cfg.CLASS_NAMES)  # frames without detections count as misses
    assert scalars["AP3D_R40"] < 1.0


def test_loader_workers_draw_new_augmentations_every_epoch(memslidar_data):
    """Any loader (OpenPCDet's seeds only np.random): workers must not replay the parent's generator each epoch."""
    cfg = _cfg("m3", memslidar_data)
    dataset = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=True)
    torch.manual_seed(0)
    loader = torch.utils.data.DataLoader(dataset, batch_size=1, num_workers=2, collate_fn=dataset.collate_batch)
    epochs = [{batch["frame_id"][0]: batch["points"][:, 1:4].sum() for batch in loader} for _ in range(2)]
    assert epochs[0].keys() == epochs[1].keys() and len(epochs[0]) == 14
    assert all(epochs[0][frame] != epochs[1][frame] for frame in epochs[0])


def test_a_class_name_in_another_case_is_an_error_not_background(tmp_path, make_people_frame, intensity_bands):
    layout = KittiLayout(tmp_path / "industrial")
    rng = np.random.default_rng(0)
    for index, names in enumerate((["Pedestrian"], ["Pedestrian", "pedestrian"])):
        points, boxes = make_people_frame(rng, len(names), intensity_bands["industrial"])
        write_frame(layout, f"{index:06d}", points, names, boxes, {})
    create_domain_infos(Source("industrial", layout.root, None))
    cfg = _cfg("m3", tmp_path)
    with pytest.raises(DataFormatError, match=re.escape(f"{layout.label('000001')}:2: class 'pedestrian' is not "
                                                        f"'Pedestrian' (class names are case-sensitive), so its "
                                                        f"objects would not count; rename it to Pedestrian")):
        MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)


def test_test_frames_carry_their_points_times_through_masking_and_batching(tmp_path, make_people_frame,
                                                                          intensity_bands):
    layout = KittiLayout(tmp_path / "industrial")
    rng = np.random.default_rng(0)
    for index in range(3):
        points, boxes = make_people_frame(rng, 2, intensity_bands["industrial"])
        points[0, 0] = 100.0  # outside POINT_CLOUD_RANGE: masked out
        write_frame(layout, f"{index:06d}", points, ["Pedestrian"] * 2, boxes, {})
        if index < 2:  # frame 2 keeps no times
            write_bytes(layout.time_offset(f"{index:06d}"), points[:, 0].astype("<f4"))  # time = x, to check order
    create_domain_infos(Source("industrial", layout.root, None))
    cfg = _cfg("m3", tmp_path)
    test = MEMSLidarDataset(cfg.DATA_CONFIG, cfg.CLASS_NAMES, training=False)
    samples = [test[index] for index in range(3)]
    for sample in samples[:2]:
        assert sample["point_times"].tolist() == sample["points"][:, 0].tolist()  # the points' own, in range
    assert "point_times" not in samples[2]
    batch = test.collate_batch(samples[:2])
    assert batch["point_times"].tolist() == batch["points"][:, 1].tolist()
    assert "point_times" not in test.collate_batch(samples)  # not every frame has them: none
    write_bytes(layout.time_offset("000001"), np.zeros(3, dtype="<f4"))
    with pytest.raises(DataFormatError, match=re.escape(f"{layout.time_offset('000001')}: 3 time offsets for")):
        test[1]
