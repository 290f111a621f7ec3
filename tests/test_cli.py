"""The `memslidar` entry point: file-system faults as one line naming the path, the reason and the fix; one module
per command with the shared options taken the same way; progress bars only on a terminal."""
import argparse
import errno
import io
import re
import sys
from pathlib import Path

import pytest
import torch

from pcdet_memslidar import cli
from pcdet_memslidar.commands import simulate as simulate_cli
from pcdet_memslidar.runtime.common import default_workers
from pcdet_memslidar.utils.cores import available_cores
from pcdet_memslidar.utils.progress import progress_bar


def _run(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    return exit_info.value.code, capsys.readouterr().err


def test_output_that_is_a_file_gives_one_line(tmp_path, capsys):
    (tmp_path / "out").write_text("a file, not a folder")
    code, err = _run(["simulate", "--domain", "real", "--frames", "1", "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and "Traceback" not in err
    assert err.startswith(f"memslidar simulate: error: {tmp_path / 'out'}")
    assert err.rstrip().endswith("a file stands where a folder is needed: choose another path")
    assert (tmp_path / "out").read_text() == "a file, not a folder"


@pytest.mark.parametrize("number, fix", [
    (errno.ENOSPC, "free space on that disk or write to another one"),
    (errno.EROFS, "the file system is read-only: choose another folder"),
    (errno.EACCES, "choose a folder you may write to, or change its permissions"),
])
def test_full_disk_and_read_only_folders_name_path_and_fix(monkeypatch, capsys, number, fix):
    def fail(args):
        raise OSError(number, "refused", "/data/out/000001.bin")

    monkeypatch.setattr(simulate_cli, "run", fail)
    code, err = _run(["simulate", "--domain", "real"], capsys)
    assert (code, err) == (2, f"memslidar simulate: error: /data/out/000001.bin: refused; {fix}\n")


def test_command_code_lives_in_the_commands_package_only():
    package = Path(cli.__file__).parent
    for name in cli.COMMANDS:
        module = cli.command_module(name)
        assert module.__name__.startswith("pcdet_memslidar.commands.") and callable(module.add_arguments)
        assert callable(module.run)
    parsing = [str(path.relative_to(package)) for path in package.rglob("*.py")
               if "argparse" in path.read_text() and path.parent.name != "commands" and path.name != "cli.py"]
    assert parsing == []  # library modules take plain arguments


@pytest.mark.parametrize("command, required", [
    ("create-infos", ["--cfg", "c.yaml"]), ("train", ["--cfg", "c.yaml"]), ("test", ["--cfg", "c.yaml"]),
    ("reproduce", []), ("sweep", ["ratio"]),
])
def test_shared_options_are_taken_the_same_way(command, required):
    args = cli.build_parser(command).parse_args([command, *required, "--profile", "smoke", "--set", "A.B", "1"])
    assert (args.profile, args.set_cfgs) == ("smoke", ["A.B", "1"])
    if command != "create-infos":
        assert args.workers == default_workers() == (min(4, available_cores()) if torch.cuda.is_available() else 0)


def test_the_reproduction_trains_three_seeds_unless_told():
    """Table 3 states seed means by default (a single training's AP moves with its seed and CPU); a sweep's points
    are single runs unless told."""
    assert cli.build_parser("reproduce").parse_args(["reproduce"]).seeds == 3
    assert cli.build_parser("reproduce").parse_args(["reproduce", "--seeds", "1"]).seeds == 1
    assert cli.build_parser("sweep").parse_args(["sweep", "ratio"]).seeds == 1


def _command_parser(name: str) -> argparse.ArgumentParser:
    parser = cli.build_parser(name)
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    return commands.choices[name]


WRITERS = ("simulate", "import", "export-custom", "export-bag", "train", "test", "reproduce", "sweep", "site", "detect")


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_one_flag_style_with_openpcdet_spellings_as_hidden_aliases(name):
    """Every option's own name is hyphenated (--batch-size); OpenPCDet's underscore spellings are aliases that --help
    leaves out; every command that writes takes its output folder as --out."""
    parser = _command_parser(name)
    options = [action for action in parser._actions if action.option_strings]
    own = [next(flag for flag in action.option_strings if flag.startswith("--")) for action in options]
    assert [flag for flag in own if "_" in flag] == []
    assert re.findall(r"--[a-z0-9]+_[a-z0-9_]*", parser.format_help()) == []
    assert ("--out" in parser._option_string_actions) == (name in WRITERS)


def test_openpcdet_spellings_parse_as_ours():
    ours = _command_parser("train").parse_args(["--cfg", "c.yaml", "--batch-size", "4", "--extra-tag", "t", "--out",
                                                "o", "--fix-random-seed", "--ckpt-save-interval", "2"])
    openpcdet = _command_parser("train").parse_args(["--cfg_file", "c.yaml", "--batch_size", "4", "--extra_tag", "t",
                                                     "--output_dir", "o", "--fix_random_seed",
                                                     "--ckpt_save_interval", "2", "--wo_gpu_stat"])
    assert vars(ours) == {**vars(openpcdet), "wo_gpu_stat": False}
    assert (openpcdet.cfg_file, openpcdet.batch_size, openpcdet.output_dir) == ("c.yaml", 4, "o")


def test_progress_bars_are_drawn_on_a_terminal_only(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    assert progress_bar(range(3)).disable  # pytest's captured stderr is no terminal: no carriage-return lines
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert not progress_bar(range(3)).disable and progress_bar(range(3), enabled=False).disable
    monkeypatch.setenv("TQDM_DISABLE", "1")  # what reproduce sets for its worker processes
    assert progress_bar(range(3)).disable
