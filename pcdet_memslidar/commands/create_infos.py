"""`memslidar create-infos --cfg CFG`: info files and gt database of every source the config's splits read
(datasets.infos), then each split's frame and box counts."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.commands.options import add_profile, add_set
from pcdet_memslidar.config import load_config
from pcdet_memslidar.datasets.infos import INFO_FILE, create_domain_infos
from pcdet_memslidar.datasets.mixing import source_split, split_sources


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
    sources = {split: split_sources(data_cfg, split, data_path) for split in ("train", "val", "test")}
    infos = {}
    for source in (source for split_list in sources.values() for source in split_list):
        if source.root not in infos:
            infos[source.root] = create_domain_infos(source, force=args.force)
    for split, split_list in sources.items():
        for source in split_list:
            frame_ids = [info["frame_id"] for info in infos[source.root]]
            chosen = set(source_split(source, frame_ids, split, data_cfg, source.root / INFO_FILE))
            boxes = sum(len(info["annos"]["name"]) for info in infos[source.root] if info["frame_id"] in chosen)
            print(f"{split:>5}  {source.name:<12} {len(chosen):6d} of {len(frame_ids):6d} frames, {boxes:7d} boxes  "
                  f"({source.root})")
    return 0
