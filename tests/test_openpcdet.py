"""OpenPCDet's stock train.py and test.py paths, proven with a minimal fake `pcdet` package and the launcher: our
dataset and configs, its HOOK call, checkpoints refused on another grid, numpy scalars under weights_only."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from pcdet_memslidar.config import load_config

CFGS = Path(__file__).resolve().parents[1] / "cfgs"

FAKE_PCDET = {
    "pcdet/__init__.py": "",
    # stock OpenPCDet: YAML read as is (bases not resolved relative to files), --set via literal_eval
    "pcdet/config.py": """
        from ast import literal_eval
        import yaml
        from easydict import EasyDict
        cfg = EasyDict()

        def cfg_from_yaml_file(cfg_file, config):
            with open(cfg_file) as f:
                config.update(EasyDict(yaml.safe_load(f)))
            return config

        def cfg_from_list(cfg_list, config):
            for key, text in zip(cfg_list[0::2], cfg_list[1::2]):
                *parents, leaf = key.split('.')
                node = config
                for part in parents:
                    node = node[part]
                assert leaf in node, f'NotFoundKey: {key}'
                try:
                    node[leaf] = literal_eval(text)
                except (ValueError, SyntaxError):
                    node[leaf] = text
    """,
    "pcdet/datasets/dataset.py": """
        import torch.utils.data as torch_data

        class DatasetTemplate(torch_data.Dataset):
            def __init__(self, *args, **kwargs):
                raise RuntimeError('the fake OpenPCDet template must not be constructed')
    """,
    "pcdet/datasets/__init__.py": """
        from torch.utils.data import DataLoader
        from .dataset import DatasetTemplate
        __all__ = {'DatasetTemplate': DatasetTemplate}

        def build_dataloader(dataset_cfg, class_names, batch_size, dist, root_path=None, workers=4, seed=None,
                             logger=None, training=True, merge_all_iters_to_one_epoch=False, total_epochs=0):
            dataset = __all__[dataset_cfg.DATASET](dataset_cfg=dataset_cfg, class_names=class_names,
                                                   root_path=root_path, training=training, logger=logger)
            return dataset, DataLoader(dataset, batch_size=batch_size, num_workers=workers, shuffle=training,
                                       collate_fn=dataset.collate_batch), None
    """,
    "pcdet/models/__init__.py": "",
    "pcdet/models/detectors/__init__.py": "",
    # stock loading: torch.load with its default (weights_only=True from torch 2.6), the half that fits is loaded
    "pcdet/models/detectors/detector3d_template.py": """
        import torch

        class Detector3DTemplate(torch.nn.Module):
            def __init__(self, model_cfg, num_class, dataset):
                super().__init__()
                self.dataset = dataset

            def load_params_from_file(self, filename, logger=None, to_cpu=False, pre_trained_path=None):
                return torch.load(filename, map_location='cpu')['epoch']

            def load_params_with_optimizer(self, filename, to_cpu=False, optimizer=None, logger=None):
                return torch.load(filename, map_location='cpu')['it'], 0
    """,
    # the shape of OpenPCDet's tools/test.py: parse, cfg, the test loader, build the model, load --ckpt
    "tools/test.py": """
        import argparse, json
        from pcdet.config import cfg, cfg_from_list, cfg_from_yaml_file
        from pcdet.datasets import build_dataloader
        from pcdet.models.detectors.detector3d_template import Detector3DTemplate

        parser = argparse.ArgumentParser()
        parser.add_argument('--cfg_file')
        parser.add_argument('--ckpt')
        parser.add_argument('--set', dest='set_cfgs', default=None, nargs=argparse.REMAINDER)
        args = parser.parse_args()
        cfg_from_yaml_file(args.cfg_file, cfg)
        if args.set_cfgs is not None:
            cfg_from_list(args.set_cfgs, cfg)
        dataset, loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False, workers=0,
                                              training=False)
        model = Detector3DTemplate(cfg.MODEL, len(cfg.CLASS_NAMES), dataset)
        print(json.dumps({'epoch': model.load_params_from_file(filename=args.ckpt, logger=None, to_cpu=True)}))
    """,
    # OpenPCDet's tools/train_utils: train_model saves checkpoint_state(...) of every epoch (name looked up at call)
    "tools/train_utils/__init__.py": "",
    "tools/train_utils/train_utils.py": """
        import torch

        def checkpoint_state(model=None, optimizer=None, epoch=None, it=None):
            return {'epoch': epoch, 'it': it, 'model_state': model.state_dict(), 'optimizer_state': None,
                    'version': 'pcdet+fake'}

        def save_checkpoint(state, filename='checkpoint'):
            torch.save(state, f'{filename}.pth')

        def train_model(model, ckpt_save_dir, total_epochs):
            for epoch in range(1, total_epochs + 1):
                save_checkpoint(checkpoint_state(model, None, epoch, 7 * epoch),
                                filename=f'{ckpt_save_dir}/checkpoint_epoch_{epoch}')
    """,
    # the shape of OpenPCDet's tools/train.py: parse, load cfg, --set, build the loader, load_data_to_gpu,
    # train_utils' disable_augmentation_hook before the last epoch, train_model (writes ./checkpoint_epoch_1.pth)
    "tools/train.py": """
        import argparse, json
        import numpy as np
        import torch
        from pcdet.config import cfg, cfg_from_list, cfg_from_yaml_file
        from pcdet.datasets import DatasetTemplate, build_dataloader
        from pcdet.models.detectors.detector3d_template import Detector3DTemplate
        from train_utils.train_utils import train_model

        parser = argparse.ArgumentParser()
        parser.add_argument('--cfg_file')
        parser.add_argument('--set', dest='set_cfgs', default=None, nargs=argparse.REMAINDER)
        args = parser.parse_args()
        cfg_from_yaml_file(args.cfg_file, cfg)
        if args.set_cfgs is not None:
            cfg_from_list(args.set_cfgs, cfg)
        dataset, loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False, workers=0)
        batch = next(iter(loader))
        hook = cfg.get('HOOK', {}).get('DisableAugmentationHook')
        if hook is not None:  # OpenPCDet's hook: the config's list replaced, then the augmentor rebuilt
            cfg.DATA_CONFIG.DATA_AUGMENTOR.DISABLE_AUG_LIST = hook.DISABLE_AUG_LIST
            dataset.data_augmentor.disable_augmentation(cfg.DATA_CONFIG.DATA_AUGMENTOR)
        for key, value in batch.items():  # OpenPCDet's load_data_to_gpu, on the CPU
            if isinstance(value, np.ndarray) and key not in ('frame_id', 'metadata', 'calib'):
                batch[key] = torch.from_numpy(value).float()
        print(json.dumps({'class': type(dataset).__name__, 'is_pcdet_template': isinstance(dataset, DatasetTemplate),
                          'profile': cfg.PROFILE, 'total': cfg.DATA_CONFIG.MIX.TOTAL,
                          'epochs': cfg.OPTIMIZATION.NUM_EPOCHS, 'frames': len(dataset),
                          'gt_boxes': list(batch['gt_boxes'].shape),
                          'augmentations': dataset.data_augmentor.names}))
        train_model(Detector3DTemplate(cfg.MODEL, len(cfg.CLASS_NAMES), dataset), '.', 1)
    """,
}


def _fake_openpcdet(tmp_path) -> dict:
    """The fake `pcdet` and its tools/ under tmp_path; returns the environment that imports it."""
    for name, text in FAKE_PCDET.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(textwrap.dedent(text))
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
            "OMP_NUM_THREADS": "1"}


def _launch(tmp_path, env, script: str, *arguments: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "pcdet_memslidar.openpcdet", str(tmp_path / "tools" / script), *arguments]
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.slow
@pytest.mark.parametrize("experiment", ["m3.yaml", "centerpoint/m3.yaml"])
def test_stock_train_script_runs_on_memslidar_through_the_launcher(tmp_path, memslidar_data, experiment):
    env = _fake_openpcdet(tmp_path)
    config = tmp_path / "m3_hook.yaml"  # OpenPCDet's HOOK block, as its TransFusion and DSVT configs write it
    config.write_text(yaml.safe_dump({"_BASE_CONFIG_": str(CFGS / experiment), "HOOK": {"DisableAugmentationHook": {
        "DISABLE_AUG_LIST": ["gt_sampling"], "NUM_LAST_EPOCHS": 1}}}))
    done = _launch(tmp_path, env, "train.py", "--cfg_file", str(config), "--set", "OPTIMIZATION.NUM_EPOCHS", "3",
                   "PROFILE", "smoke", "DATA_CONFIG.DATA_PATH", str(memslidar_data))
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["class"] == "MEMSLidarDataset" and report["is_pcdet_template"]
    assert (report["profile"], report["total"], report["epochs"], report["frames"]) == ("smoke", 20, 3, 14)
    assert report["gt_boxes"][0] == 2 and report["gt_boxes"][2] == 8
    configured = [step.NAME for step in load_config(CFGS / "m3.yaml").DATA_CONFIG.DATA_AUGMENTOR.AUG_CONFIG_LIST]
    assert "gt_sampling" in configured and report["augmentations"] == [n for n in configured if n != "gt_sampling"]


@pytest.mark.slow
def test_stock_test_script_refuses_a_checkpoint_of_another_grid_and_loads_one_of_its_own(tmp_path, memslidar_data):
    """A quick-grid checkpoint under the paper grid would load half-way in OpenPCDet and evaluate anyway: the
    launcher refuses it in one line; with its profile it loads, numpy scalars in its optimizer state included."""
    env = _fake_openpcdet(tmp_path)
    smoke = load_config(CFGS / "m3.yaml", profile="smoke").DATA_CONFIG
    voxel = next(step.VOXEL_SIZE for step in smoke.DATA_PROCESSOR if step.NAME == "transform_points_to_voxels")
    checkpoint = tmp_path / "checkpoint_epoch_2.pth"
    torch.save({"epoch": 2, "it": 20, "model_state": {"w": torch.zeros(1)}, "version": "pcdet_memslidar+test",
                "optimizer_state": {"param_groups": [{"lr": np.float64(0.002)}]},  # OpenPCDet's one-cycle writes these
                "memslidar": {"profile": "smoke", "point_cloud_range": list(smoke.POINT_CLOUD_RANGE),
                              "voxel_size": list(voxel)}}, checkpoint)
    arguments = ["--cfg_file", str(CFGS / "m3.yaml"), "--ckpt", str(checkpoint), "--set", "DATA_CONFIG.DATA_PATH",
                 str(memslidar_data)]
    refused = _launch(tmp_path, env, "test.py", *arguments)
    assert refused.returncode == 2 and refused.stdout == ""
    assert refused.stderr.startswith(f"error: {checkpoint}: was trained on profile 'smoke', POINT_CLOUD_RANGE ")
    assert refused.stderr.count("\n") == 1 and "(--set PROFILE smoke)" in refused.stderr
    loaded = _launch(tmp_path, env, "test.py", *arguments, "PROFILE", "smoke")
    assert loaded.returncode == 0, loaded.stderr[-3000:]
    assert json.loads(loaded.stdout.strip().splitlines()[-1]) == {"epoch": 2}


@pytest.mark.slow
def test_a_checkpoint_openpcdets_training_writes_is_refused_on_another_grid(tmp_path, memslidar_data):
    """OpenPCDet's own training (through the launcher) records the grid and profile in its checkpoints, so its
    test.py refuses them under another profile instead of loading half of the weights."""
    env = _fake_openpcdet(tmp_path)
    data = ["DATA_CONFIG.DATA_PATH", str(memslidar_data)]
    trained = _launch(tmp_path, env, "train.py", "--cfg_file", str(CFGS / "m3.yaml"), "--set", "PROFILE", "smoke",
                      *data)
    assert trained.returncode == 0, trained.stderr[-3000:]
    checkpoint = tmp_path / "checkpoint_epoch_1.pth"
    record = torch.load(checkpoint, map_location="cpu")["memslidar"]
    assert record["profile"] == "smoke" and len(record["point_cloud_range"]) == 6 and len(record["voxel_size"]) == 3
    arguments = ["--cfg_file", str(CFGS / "m3.yaml"), "--ckpt", str(checkpoint), "--set", *data]
    refused = _launch(tmp_path, env, "test.py", *arguments)
    assert refused.returncode == 2 and "was trained on profile 'smoke'" in refused.stderr
    assert refused.stderr.count("\n") == 1 and "(--set PROFILE smoke)" in refused.stderr
    loaded = _launch(tmp_path, env, "test.py", *arguments, "PROFILE", "smoke")
    assert loaded.returncode == 0 and json.loads(loaded.stdout.strip().splitlines()[-1]) == {"epoch": 1}


def test_launcher_without_script_prints_usage(tmp_path):
    done = subprocess.run([sys.executable, "-m", "pcdet_memslidar.openpcdet"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and "usage: python -m pcdet_memslidar.openpcdet" in done.stdout
