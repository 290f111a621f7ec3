"""tools/train.py and tools/test.py end to end on synthetic frames: output layout, checkpoints, resume, AP line."""
import json
import struct

import pytest
import yaml
from tensorboardX.proto import event_pb2
from torch.utils.data import DataLoader

from pcdet_memslidar import cli
from pcdet_memslidar.datasets.synthetic import SyntheticPersonDataset
from pcdet_memslidar.models import build_network
from pcdet_memslidar.runtime import predict as predict_module
from pcdet_memslidar.runtime import train as train_module
from pcdet_memslidar.runtime.checkpoint import checkpoint_state, save_checkpoint


@pytest.fixture
def experiment(tmp_path, monkeypatch, small_model_cfg, small_range, person_voxel):
    def synthetic_dataloader(dataset_cfg, class_names, batch_size, dist, workers=4, training=True, **kwargs):
        dataset = SyntheticPersonDataset(small_range, person_voxel, num_frames=4, seed=0 if training else 50)
        return dataset, DataLoader(dataset, batch_size=batch_size, collate_fn=dataset.collate_batch), None

    monkeypatch.setattr(train_module, "build_dataloader", synthetic_dataloader)
    monkeypatch.setattr(predict_module, "build_dataloader", synthetic_dataloader)
    cfg_dir = tmp_path / "cfgs" / "people"
    cfg_dir.mkdir(parents=True)
    config = {"CLASS_NAMES": ["Pedestrian"], "DATA_CONFIG": {
                  "DATA_SPLIT": {"train": "train", "test": "val"}, "POINT_CLOUD_RANGE": list(small_range),
                  "DATA_PROCESSOR": [{"NAME": "transform_points_to_voxels", "VOXEL_SIZE": list(person_voxel)}]},
              "MODEL": small_model_cfg(),
              "OPTIMIZATION": {"BATCH_SIZE_PER_GPU": 2, "NUM_EPOCHS": 2, "OPTIMIZER": "adam_onecycle", "LR": 0.003,
                               "WEIGHT_DECAY": 0.01, "MOMS": [0.95, 0.85], "PCT_START": 0.4, "DIV_FACTOR": 10,
                               "GRAD_NORM_CLIP": 10}}
    cfg_file = cfg_dir / "tiny.yaml"
    cfg_file.write_text(yaml.safe_dump(_plain(config)))
    return cfg_file, tmp_path / "output"


def _plain(value):
    """EasyDicts (also inside lists) -> plain dicts and lists that yaml can write."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def tensorboard_scalars(folder) -> dict[str, dict[int, float]]:
    """{tag: {step: value}} of the tensorboard event files in folder (TFRecord: length, crc, event, crc)."""
    scalars = {}
    for path in folder.iterdir():
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            length = struct.unpack("<Q", data[offset:offset + 8])[0]
            event = event_pb2.Event.FromString(data[offset + 12:offset + 12 + length])
            offset += 16 + length
            for value in event.summary.value:
                scalars.setdefault(value.tag, {})[event.step] = value.simple_value
    return scalars


@pytest.mark.slow
def test_train_then_test_then_resume(experiment, capsys):
    cfg_file, output = experiment
    common = ["--cfg", str(cfg_file), "--output_dir", str(output), "--workers", "0", "--extra_tag", "run"]
    assert cli.main(["train", *common, "--fix_random_seed", "--use_tqdm_to_record"]) == 0
    run_dir = output / "people" / "tiny" / "run"
    assert sorted(p.name for p in (run_dir / "ckpt").iterdir()) == ["checkpoint_epoch_1.pth", "checkpoint_epoch_2.pth"]
    assert len(list(run_dir.glob("log_train_*.txt"))) == 1
    scalars = tensorboard_scalars(run_dir / "tensorboard")
    assert sorted(scalars["val/AP3D_R40"]) == sorted(scalars["train/epoch_loss"]) == [1, 2]  # every epoch
    assert all(0 <= value <= 1 for value in scalars["val/AP3D_R40"].values())
    log = next(run_dir.glob("log_train_*.txt")).read_text()
    assert "epoch 1 val: AP@IoU0.5  3D R40 " in log and "epoch 2 val: " in log
    assert (run_dir / "eval" / "eval_with_train" / "epoch_2" / "val" / "result.pkl").is_file()

    capsys.readouterr()
    assert cli.main(["test", *common, "--ckpt", str(run_dir / "ckpt" / "checkpoint_epoch_2.pth"), "--diagnose"]) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if line.startswith("AP@IoU0.5  3D R40 "))
    assert "BEV R40" in line
    result_dir = run_dir / "eval" / "epoch_2" / "val"
    assert (result_dir / "result.pkl").is_file()
    diagnosis = json.loads((result_dir / "diagnosis.json").read_text())
    assert list(diagnosis["part_ablation"]) == ["as predicted", "centre x, y", "z, height", "length, width", "heading",
                                                "all but the centre"]
    assert f"{diagnosis['part_ablation']['as predicted']['AP3D_R40']:.4f}" == line.split()[3]  # the AP printed above
    assert "part replaced" in out and "Predicted against labelled boxes" in out

    assert cli.main(["train", *common, "--epochs", "3", "--use_tqdm_to_record"]) == 0  # resumes from epoch 2
    log = sorted(run_dir.glob("log_train_*.txt"))[-1].read_text()
    assert "resuming from" in log and "checkpoint_epoch_2.pth" in log
    assert (run_dir / "ckpt" / "checkpoint_epoch_3.pth").is_file()


def test_test_refuses_a_checkpoint_trained_on_another_grid(experiment, capsys, small_model_cfg, person_voxel):
    cfg_file, output = experiment
    other_grid = SyntheticPersonDataset([2.56, -5.12, -0.5, 12.8, 5.12, 3.5], person_voxel, num_frames=1)
    model = build_network(small_model_cfg(), 1, other_grid)
    model.profile = "quick"
    ckpt = save_checkpoint(checkpoint_state(model, epoch=1), output / "quick_grid.pth")
    with pytest.raises(SystemExit) as exited:
        cli.main(["test", "--cfg", str(cfg_file), "--output_dir", str(output), "--workers", "0", "--ckpt", str(ckpt)])
    assert exited.value.code == 2
    assert (f"memslidar test: error: {ckpt}: was trained on profile 'quick', POINT_CLOUD_RANGE [2.56, -5.12, -0.5, "
            f"12.8, 5.12, 3.5], VOXEL_SIZE [0.08, 0.08, 0.1], but this config has profile 'paper', POINT_CLOUD_RANGE "
            f"[0.0, -5.12, -0.5, 10.24, 5.12, 3.5]") in capsys.readouterr().err


def test_cfg_alias_and_openpcdet_flags_parse():
    parser = cli.build_parser("train")
    args = parser.parse_args(["train", "--cfg", "x.yaml", "--launcher", "pytorch", "--tcp_port", "1", "--sync_bn",
                              "--num_epochs_to_eval", "2", "--set", "PROFILE", "smoke"])
    assert args.cfg_file == "x.yaml" and args.set_cfgs == ["PROFILE", "smoke"] and args.launcher == "pytorch"
    args = cli.build_parser("test").parse_args(["test", "--cfg_file", "y.yaml", "--eval_all", "--infer_time"])
    assert args.cfg_file == "y.yaml" and args.eval_all
