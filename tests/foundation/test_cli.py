"""The `memslidar` entry point turns file-system faults into one line naming the path, the reason and the fix."""
import errno

import pytest

from pcdet_memslidar import cli
from pcdet_memslidar.sim import cli as simulate_cli


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
