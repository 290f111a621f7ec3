"""Options that several commands take, added the same way everywhere (--profile, --set, --workers, --mount,
--time-unit, --topic),
OpenPCDet's flags of `memslidar train` and `memslidar test`, and the experiment set-up those flags ask for."""
from __future__ import annotations

import argparse
from pathlib import Path

from pcdet_memslidar.config import load_config
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.io import ground
from pcdet_memslidar.io.formats import time_unit_clouds
from pcdet_memslidar.io.pointclouds import TIME_UNITS
from pcdet_memslidar.runtime.common import default_workers
from pcdet_memslidar.runtime.experiment import Process, option_count, output_folder, start_process


def add_profile(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    """--profile NAME: an entry of the config's PROFILES, applied before --set."""
    parser.add_argument("--profile", default=default,
                        help="an entry of the config's PROFILES: smoke (seconds, for tests), quick (a 2-core CPU), "
                             "paper (a GPU: the config as written); same as --set PROFILE NAME (default: "
                             f"{default or 'the config PROFILE, else paper'})")


def add_set(parser: argparse.ArgumentParser) -> None:
    """--set KEY VALUE ...: config overrides after the profile; must come last."""
    parser.add_argument("--set", dest="set_cfgs", default=None, nargs=argparse.REMAINDER,
                        help="config overrides KEY.SUB VALUE ... after the profile (e.g. --set OPTIMIZATION.LR 0.002); "
                             "put it last")


def add_workers(parser: argparse.ArgumentParser) -> None:
    """--workers N: data-loader worker processes (default: runtime.common.default_workers() of this machine)."""
    parser.add_argument("--workers", type=int, default=default_workers(),
                        help="data-loader worker processes per model (default here %(default)s: 0 on a CPU, where "
                             "loading in the training process is fastest; up to 4 with CUDA)")


def add_precision(parser: argparse.ArgumentParser) -> None:
    """--precision fp32|bf16: inference precision of the BEV backbone and the head (models.detector.PRECISIONS)."""
    from pcdet_memslidar.models.detector import PRECISIONS  # here: the other commands need not import the model

    parser.add_argument("--precision", choices=PRECISIONS, default=PRECISIONS[0],
                        help="inference precision of the BEV backbone and head (default %(default)s; bf16 is fast on "
                             "CPUs with AMX or AVX512-BF16 and on GPUs, slow elsewhere; the sparse 3D part, box "
                             "decoding and NMS stay fp32)")


def _mount(text: str) -> Mount:
    try:
        return ground.parse_mount(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_mount_arguments(parser: argparse.ArgumentParser) -> None:
    """--mount H,TILT[,ROLL] or --estimate-ground: how recordings are brought into the ground frame (neither: they
    already are)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--mount", type=_mount, metavar="H,TILT[,ROLL]",
                       help="sensor height [m] and tilt [deg] (> 0 looks down) to remove")
    where.add_argument("--estimate-ground", action="store_true", help="estimate the mount from the ground plane")


def add_time_unit(parser: argparse.ArgumentParser) -> None:
    """--time-unit: the unit of the per-point time field of clouds whose format does not record it
    (io.formats.time_unit_clouds) (args.time_unit_s: seconds per unit or None)."""
    parser.add_argument("--time-unit", dest="time_unit_s", type=_time_unit, default=None, metavar="{s,ms,us,ns}",
                        help=f"unit of the per-point time field of {time_unit_clouds()} clouds, which those formats "
                             "do not (always) record (default: their times are not used, but a ROS 2 bag's integer "
                             "time field is taken as ns and a float32 one as s; .bfpc and KITTI-layout times are "
                             "used)")


def add_topic(parser: argparse.ArgumentParser) -> None:
    """--topic: the point-cloud topic of a ROS 2 bag (args.topic; None: the bag's only PointCloud2 topic)."""
    parser.add_argument("--topic", default=None,
                        help="the sensor_msgs/msg/PointCloud2 topic of a ROS 2 bag (default: its only one; a bag "
                             "with several is refused, listing them)")


def _time_unit(text: str) -> float:
    if text not in TIME_UNITS:
        raise argparse.ArgumentTypeError(f"unknown time unit {text!r}: use one of {', '.join(TIME_UNITS)}")
    return TIME_UNITS[text]


def add_experiment_arguments(parser: argparse.ArgumentParser, runs: str, seeds: int = 1) -> None:
    """The options of commands that train many models (`reproduce`, `sweep`): --seeds (default `seeds`), --out,
    --data-root, --jobs, --workers; `runs` names what --jobs counts."""
    parser.add_argument("--seeds", type=int, default=seeds,
                        help="training seeds 0..K-1; the report gives mean and std (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default output/<command>/...); "
                                                               "finished models in it are reused")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder of the data sources (default: the cfgs' DATA_PATH, data/memslidar)")
    parser.add_argument("--jobs", type=int, default=None,
                        help=f"{runs} trained at once, each in its own process (default on a CPU: five, or one per "
                             f"core if more; 1 on a GPU)")
    add_workers(parser)


def experiment_command(words: list[str], args: argparse.Namespace) -> str:
    """The command line of a `reproduce` or `sweep` call (`words`, then its experiment options and --set), for the
    report."""
    return " ".join([*words, f"--profile {args.profile}", f"--seeds {args.seeds}",
                     *([f"--out {args.out}"] if args.out else []),
                     *([f"--data-root {args.data_root}"] if args.data_root else []),
                     *([f"--jobs {args.jobs}"] if args.jobs else []),
                     *(["--set", *args.set_cfgs] if args.set_cfgs else [])])


def add_openpcdet_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags `memslidar train` and `memslidar test` share, hyphenated; OpenPCDet's tools/train.py and
    tools/test.py spellings (--cfg_file, --batch_size, --output_dir, ...) are accepted as aliases (cli.HelpFormatter
    keeps them out of --help), plus --profile."""
    parser.add_argument("--cfg", "--cfg_file", dest="cfg_file", required=True, help="experiment config (YAML)")
    parser.add_argument("--batch-size", "--batch_size", type=int, default=None,
                        help="frames per batch and process (default OPTIMIZATION.BATCH_SIZE_PER_GPU)")
    add_workers(parser)
    parser.add_argument("--extra-tag", "--extra_tag", default="default", help="output sub-folder name")
    parser.add_argument("--ckpt", default=None, help="checkpoint to start from (train) or evaluate (test)")
    parser.add_argument("--launcher", choices=["none", "pytorch", "slurm"], default="none",
                        help="pytorch: one process per device under torchrun (gloo on CPU, nccl on GPU)")
    parser.add_argument("--tcp-port", "--tcp_port", type=int, default=18888,
                        help="rendezvous port when MASTER_PORT is unset")
    parser.add_argument("--local-rank", "--local_rank", type=int, default=None, help="set by the launcher")
    parser.add_argument("--max-waiting-mins", "--max_waiting_mins", type=int, default=0,
                        help="minutes to wait for a checkpoint")
    parser.add_argument("--start-epoch", "--start_epoch", type=int, default=0, help="first epoch to evaluate")
    parser.add_argument("--save-to-file", "--save_to_file", action="store_true", default=False,
                        help="write KITTI label files")
    parser.add_argument("--out", "--output_dir", dest="output_dir", default=None,
                        help="output root: a run goes to <out>/<config group>/<config name>/<extra tag> (default "
                             "<repo>/output)")
    add_profile(parser)
    add_set(parser)


def setup_experiment(args: argparse.Namespace) -> tuple[object, Process, Path]:
    """(cfg, process, run folder) of OpenPCDet's flags: the config (--cfg, --profile, --set; --batch-size
    replaces OPTIMIZATION.BATCH_SIZE_PER_GPU) with its grid (load_config) and batch size checked before any data is
    read, the process joined to its group (--launcher), and <output root>/<group>/<cfg name>/<extra_tag>."""
    cfg = load_config(args.cfg_file, args.set_cfgs, profile=args.profile)
    cfg.OPTIMIZATION.BATCH_SIZE_PER_GPU = option_count(args.batch_size, "--batch-size", "BATCH_SIZE_PER_GPU", cfg)
    process = start_process(args.launcher, args.tcp_port, args.local_rank)
    return cfg, process, output_folder(cfg, args.output_dir, args.extra_tag)
