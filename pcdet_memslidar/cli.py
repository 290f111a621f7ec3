"""The `memslidar` command: one subcommand per pipeline stage.

Each subcommand is a module of pcdet_memslidar.commands, which defines `add_arguments(parser)` and
`run(args) -> int`; only the module of the command being run is imported, so `memslidar --help` stays fast, and
only after the process policy is applied (policy.apply_process_policy: before torch loads).
"""
from __future__ import annotations

import argparse
import copy
import errno
import importlib
import sys

from pcdet_memslidar.errors import ConfigError, DataFormatError, OutputError
from pcdet_memslidar.policy import apply_process_policy

# name -> (module of pcdet_memslidar.commands, one-line help), in pipeline order
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("simulate", "simulate a domain (sim | real | industrial) or a site file as a KITTI-layout dataset"),
    "import": ("import_recordings", "real recordings (.bfpc/.pcd/.ply/.npy/.bin/ROS 2 bags) and CVAT 3D cuboids -> "
                                    "dataset"),
    "export-custom": ("export_custom", "a KITTI-layout dataset -> OpenPCDet's custom layout (points/*.npy)"),
    "export-bag": ("export_bag", "a KITTI-layout dataset -> a ROS 2 bag of PointCloud2 messages (sqlite3 or MCAP)"),
    "create-infos": ("create_infos", "info files and gt database of every source a config reads"),
    "train": ("train", "train a SECOND detector (OpenPCDet's tools/train.py flags), then evaluate"),
    "test": ("test", "evaluate checkpoints on the test split (OpenPCDet's tools/test.py flags)"),
    "eval": ("eval", "AP of prediction label folders (3D/BEV IoU 0.5, R40/R11, distance bins)"),
    "reproduce": ("reproduce", "the paper's M1-M4 end to end: data, four models, Table 3, figures, report"),
    "sweep": ("sweep", "the paper's open questions: AP against the sim/real ratio or the real-annotation budget"),
    "site": ("site", "your own site without annotating: check a site file's floor; train a detector on its empty "
                     "recording with simulated people composited in"),
    "detect": ("detect", "a trained detector on recordings: detections, tracks and zone events (no raw points)"),
    "docs": ("docs", "store finished runs' results and render README's and docs/results.md's tables from them"),
}


# errno -> what the user can do about it
OS_ERROR_FIXES = {
    errno.ENOSPC: "free space on that disk or write to another one",
    errno.EDQUOT: "free space within your quota or write to another disk",
    errno.EACCES: "choose a folder you may write to, or change its permissions",
    errno.EPERM: "choose a folder you may write to, or change its permissions",
    errno.EROFS: "the file system is read-only: choose another folder",
    errno.ENOTDIR: "a file stands where a folder is needed: choose another path",
    errno.EISDIR: "a folder stands where a file is needed: choose another path",
    errno.EEXIST: "something already exists there: choose another path",
    errno.ENOENT: "check the path",
}


class HelpFormatter(argparse.HelpFormatter):
    """--help with each option under its own name only: the first long spelling (and short ones); the others are
    accepted aliases, such as OpenPCDet's underscore spellings (--batch_size for --batch-size)."""

    def _format_action_invocation(self, action: argparse.Action) -> str:
        long_names = [name for name in action.option_strings if name.startswith("--")]
        if len(long_names) > 1:
            action = copy.copy(action)
            action.option_strings = [name for name in action.option_strings if name not in long_names[1:]]
        return super()._format_action_invocation(action)


def command_module(name: str):
    """The module of pcdet_memslidar.commands that implements command `name`."""
    return importlib.import_module(f"pcdet_memslidar.commands.{COMMANDS[name][0]}")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser; only `command`'s own arguments are added (its module is imported)."""
    parser = argparse.ArgumentParser(prog="memslidar", description="MEMS-LiDAR person detection, OpenPCDet-compatible.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, summary) in COMMANDS.items():
        sub = commands.add_parser(name, help=summary, description=summary, formatter_class=HelpFormatter)
        if name == command:
            command_module(name).add_arguments(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    apply_process_policy()
    argv = sys.argv[1:] if argv is None else argv
    command = next((word for word in argv if not word.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(command_module(args.command).run(args) or 0)
    except (DataFormatError, ConfigError, OutputError) as error:
        parser.exit(2, f"memslidar {args.command}: error: {error}\n")
    except OSError as error:  # the file system refused: full disk, read-only folder, a file where a folder must be
        parser.exit(2, f"memslidar {args.command}: error: {os_error_message(error)}\n")
    except KeyboardInterrupt:
        parser.exit(130, f"\nmemslidar {args.command}: interrupted; what was written is whole: run the same "
                         f"command again to resume\n")


def os_error_message(error: OSError) -> str:
    """'<path>: <reason>; <fix>' for an error of the file system."""
    fix = OS_ERROR_FIXES.get(error.errno, "check the path and its permissions")
    where = f"{error.filename}: " if error.filename else ""
    return f"{where}{error.strerror or error}; {fix}"


if __name__ == "__main__":
    sys.exit(main())
