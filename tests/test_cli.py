"""The `memslidar` entry point: file-system faults as one line naming the path, the reason and the fix; one module
per command with the shared options taken the same way; progress bars only on a terminal."""
import errno
import io
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
