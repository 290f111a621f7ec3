"""The `memslidar` command: one subcommand per pipeline stage.

Each subcommand lives in the module of its stage, which defines `add_arguments(parser)` and `run(args) -> int`;
only the module of the command being run is imported, so `memslidar --help` stays fast.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module, one-line help), in pipeline order
COMMANDS: dict[str, tuple[str, str]] = {
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser; only `command`'s own arguments are added (its module is imported)."""
    parser = argparse.ArgumentParser(prog="memslidar", description="MEMS-LiDAR person detection, OpenPCDet-compatible.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, summary) in COMMANDS.items():
        sub = commands.add_parser(name, help=summary, description=summary)
        if name == command:
            importlib.import_module(module).add_arguments(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((word for word in argv if not word.startswith("-")), None)
    args = build_parser(command if command in COMMANDS else None).parse_args(argv)
    return int(importlib.import_module(COMMANDS[args.command][0]).run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
