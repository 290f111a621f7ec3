"""`memslidar create-infos --cfg CFG`: info files and gt database of every source the config's splits read
(datasets.infos), then each split's frame and box counts."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.commands.options import add_profile, add_set
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.infos import INFO_FILE, create_domain_infos
from pcdet_memslidar.datasets.mixing import source_split, split_sources
from pcdet_memslidar.runtime.pretrain import split_stages


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cfg", "--cfg_file", dest="cfg_file", required=True,
                        help="experiment config (cfgs/m3.yaml) or dataset config")
    parser.add_argument("--force", action="store_true", help="rebuild infos even when they match the frames")
    add_profile(parser)
    add_set(parser)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.cfg_file, args.set_cfgs, profile=args.profile)
    data_cfg = cfg.DATA_CONFIG if "DATA_CONFIG" in cfg else cfg
    data_path = Path(data_cfg.DATA_PATH)
    print(f"profile {cfg.get('PROFILE', 'paper')}, data {data_path}")
    pretraining, _ = split_stages(cfg) if "DATA_CONFIG" in cfg else (None, cfg)
    splits = [("train", data_cfg), ("val", data_cfg), ("test", data_cfg)]
    if pretraining is not None:  # the sources of a pre-training stage (runtime.pretrain) are read too
        splits = [("pretrain train", pretraining.DATA_CONFIG), ("pretrain val", pretraining.DATA_CONFIG), *splits]
    sources = [(label, stage_cfg, split_sources(stage_cfg, label.split()[-1], data_path))
               for label, stage_cfg in splits]
    infos = {}
    for source in (source for _, _, split_list in sources for source in split_list):
        if source.root not in infos:
            infos[source.root] = create_domain_infos(source, force=args.force)
    for label, stage_cfg, split_list in sources:
        for source in split_list:
            frame_ids = [info["frame_id"] for info in infos[source.root]]
            split = label.split()[-1]
            chosen = set(source_split(source, frame_ids, split, stage_cfg, source.root / INFO_FILE))
            boxes = sum(len(info["annos"]["name"]) for info in infos[source.root] if info["frame_id"] in chosen)
            print(f"{label:>14}  {source.name:<12} {len(chosen):6d} of {len(frame_ids):6d} frames, {boxes:7d} "
                  f"boxes  ({source.root})")
    return 0
