"""OpenPCDet's stock train.py path, proven with a minimal fake `pcdet` package and the launcher."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

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
    # the shape of OpenPCDet's tools/train.py: parse, load cfg, --set, build the loader, load_data_to_gpu
    "tools/train.py": """
        import argparse, json
        import numpy as np
        import torch
        from pcdet.config import cfg, cfg_from_list, cfg_from_yaml_file
        from pcdet.datasets import DatasetTemplate, build_dataloader

        parser = argparse.ArgumentParser()
        parser.add_argument('--cfg_file')
        parser.add_argument('--set', dest='set_cfgs', default=None, nargs=argparse.REMAINDER)
        args = parser.parse_args()
        cfg_from_yaml_file(args.cfg_file, cfg)
        if args.set_cfgs is not None:
            cfg_from_list(args.set_cfgs, cfg)
        dataset, loader, _ = build_dataloader(cfg.DATA_CONFIG, cfg.CLASS_NAMES, batch_size=2, dist=False, workers=0)
        batch = next(iter(loader))
        for key, value in batch.items():  # OpenPCDet's load_data_to_gpu, on the CPU
            if isinstance(value, np.ndarray) and key not in ('frame_id', 'metadata', 'calib'):
                batch[key] = torch.from_numpy(value).float()
        print(json.dumps({'class': type(dataset).__name__, 'is_pcdet_template': isinstance(dataset, DatasetTemplate),
                          'profile': cfg.PROFILE, 'total': cfg.DATA_CONFIG.MIX.TOTAL,
                          'epochs': cfg.OPTIMIZATION.NUM_EPOCHS, 'frames': len(dataset),
                          'gt_boxes': list(batch['gt_boxes'].shape)}))
    """,
}


def test_stock_train_script_runs_on_memslidar_through_the_launcher(tmp_path, memslidar_data):
    for name, text in FAKE_PCDET.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(textwrap.dedent(text))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "pcdet_memslidar.openpcdet", str(tmp_path / "tools" / "train.py"),
               "--cfg_file", str(CFGS / "m3.yaml"),
               "--set", "OPTIMIZATION.NUM_EPOCHS", "3", "PROFILE", "smoke",
               "DATA_CONFIG.DATA_PATH", str(memslidar_data)]
    done = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["class"] == "MEMSLidarDataset" and report["is_pcdet_template"]
    assert (report["profile"], report["total"], report["epochs"], report["frames"]) == ("smoke", 20, 3, 14)
    assert report["gt_boxes"][0] == 2 and report["gt_boxes"][2] == 8


def test_launcher_without_script_prints_usage(tmp_path):
    done = subprocess.run([sys.executable, "-m", "pcdet_memslidar.openpcdet"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and "usage: python -m pcdet_memslidar.openpcdet" in done.stdout
