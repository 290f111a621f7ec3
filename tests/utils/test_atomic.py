"""Atomic writes: the guards against replacing an input or what a command did not write, errors that name the
target, and the removal of what killed processes left behind."""
import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pcdet_memslidar.errors import OutputError
from pcdet_memslidar.utils.atomic import OWNER_FILE, atomic_dir, refuse_overlap, write_bytes


def test_refuse_overlap_names_output_input_and_fix(tmp_path):
    source = tmp_path / "data" / "rec.bfpc"
    assert refuse_overlap(tmp_path / "out", [source]) == (tmp_path / "out").resolve()
    assert refuse_overlap(source.parent / "sub", [source.parent]) == (source.parent / "sub").resolve()  # inside: ok
    with pytest.raises(OutputError, match=r"--out .*data contains the input .*rec\.bfpc; choose --out outside"):
        refuse_overlap(tmp_path / "data", [source], "--out")
    with pytest.raises(OutputError, match=r"OUT .*data is the input .*data; choose OUT outside"):
        refuse_overlap(tmp_path / "data" / ".", [tmp_path / "data"], "OUT")


def dead_pid() -> int:
    """The pid of a process that has ended."""
    child = subprocess.Popen(["true"])
    child.wait()
    return child.pid


def test_atomic_dir_replaces_only_its_own_output(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out, "memslidar import") as tmp:
        (tmp / "a.txt").write_text("first")
    assert (out / OWNER_FILE).read_text().splitlines()[0] == "memslidar import"
    with atomic_dir(out, "memslidar import") as tmp:  # a rerun replaces its own output whole
        (tmp / "b.txt").write_text("second")
    assert sorted(p.name for p in out.iterdir()) == [OWNER_FILE, "b.txt"]
    with pytest.raises(OutputError, match=rf"{out} holds files that memslidar export-custom did not write .*"
                                          "choose a new folder, or move or delete it yourself"):
        with atomic_dir(out, "memslidar export-custom"):
            pass
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    (tmp_path / "file").write_text("mine")
    (tmp_path / "link").symlink_to(out)
    for path, what in ((user, "holds files that memslidar import did not write"), (tmp_path / "file", "is a file"),
                       (tmp_path / "link", "is a symbolic link")):
        with pytest.raises(OutputError, match=what):
            with atomic_dir(path, "memslidar import"):
                raise AssertionError("refused before the work starts")
    assert (user / "notes.txt").read_text() == "mine" and (tmp_path / "file").read_text() == "mine"
    (tmp_path / "empty").mkdir()
    with atomic_dir(tmp_path / "empty", "memslidar import") as tmp:  # an empty folder loses nothing
        (tmp / "c.txt").write_text("third")
    assert (tmp_path / "empty" / "c.txt").read_text() == "third"
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_a_read_only_folder_names_the_target_not_the_hidden_temporary(tmp_path, monkeypatch):
    def refuse(name, *args):
        raise PermissionError(errno.EACCES, "Permission denied", name)

    monkeypatch.setattr(os, "open", refuse)  # a read-only folder: creating the temporary file fails
    with pytest.raises(PermissionError) as error:
        write_bytes(tmp_path / "a.bin", b"1")
    assert error.value.filename == str(tmp_path / "a.bin")


def test_a_full_disk_names_the_file_under_the_target_not_the_hidden_temporary(tmp_path, full_disk):
    with pytest.raises(OSError, match="No space left") as error, atomic_dir(tmp_path / "out", "test") as tmp:
        write_bytes(tmp / "points" / "000000.bin", b"1")
    assert error.value.errno == errno.ENOSPC and error.value.filename == str(tmp_path / "out/points/000000.bin")
    assert not list(tmp_path.iterdir())


def test_leftovers_of_dead_processes_are_removed_on_the_next_write(tmp_path):
    dead, live = dead_pid(), os.getpid()
    (tmp_path / f".checkpoint_epoch_1.pth.{dead}.0.tmp").write_bytes(b"")  # training killed while saving
    (tmp_path / f".real.{dead}.3.tmp" / "training").mkdir(parents=True)  # import killed while writing
    (tmp_path / f".other.pth.{live}.0.tmp").write_bytes(b"")  # a live process's: kept
    (tmp_path / ".notes.tmp").write_bytes(b"")  # not a temporary name: kept
    write_bytes(tmp_path / "a.bin", b"1")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".notes.tmp", f".other.pth.{live}.0.tmp", "a.bin"]


def test_killed_atomic_dir_leaves_a_folder_that_the_next_one_removes(tmp_path):
    code = ("import sys, time; from pcdet_memslidar.utils.atomic import atomic_dir\n"
            "with atomic_dir(sys.argv[1], 'memslidar import') as tmp:\n"
            "    (tmp / 'half.bin').write_bytes(b'1'); print(tmp, flush=True); time.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "real")], stdout=subprocess.PIPE, text=True,
                             cwd=Path(__file__).resolve().parents[2])
    leftover = Path(child.stdout.readline().strip())
    child.kill()  # kill -9
    child.wait()
    assert leftover.name == f".real.{child.pid}.0.tmp" and (leftover / "half.bin").is_file()
    with atomic_dir(tmp_path / "real", "memslidar import") as tmp:
        (tmp / "whole.bin").write_bytes(b"2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["real"]


def test_checkpoint_save_removes_a_killed_saves_empty_temporary(tmp_path):
    from pcdet_memslidar.runtime.checkpoint import save_checkpoint

    leftover = tmp_path / f".checkpoint_epoch_1.pth.{dead_pid()}.0.tmp"
    leftover.write_bytes(b"")
    save_checkpoint({"epoch": 2}, tmp_path / "checkpoint_epoch_2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint_epoch_2.pth"]


def test_create_infos_rebuilds_its_own_gt_database(tmp_path):
    import numpy as np

    from pcdet_memslidar.datasets.infos import DATABASE_DIR, create_domain_infos
    from pcdet_memslidar.datasets.mixing import Source
    from pcdet_memslidar.io.layout import KittiLayout, write_frame

    points = np.array([[5.0, 0.0, 0.9, 1.0], [20.0, 3.0, 0.5, 1.0]])
    write_frame(KittiLayout(tmp_path), "000000", points, ["Pedestrian"], np.array([[5, 0, 0.9, 0.6, 0.6, 1.8, 0]]), {})
    for _ in range(2):  # the rerun (--force) replaces the database it wrote
        assert len(create_domain_infos(Source("real", tmp_path, None), force=True)) == 1
    assert sorted(p.name for p in (tmp_path / DATABASE_DIR).iterdir()) == [OWNER_FILE, "000000_Pedestrian_0.bin"]
    (tmp_path / DATABASE_DIR / OWNER_FILE).unlink()  # as an older version wrote it: object files only, no marker
    assert len(create_domain_infos(Source("real", tmp_path, None), force=True)) == 1  # adopted and replaced
    (tmp_path / DATABASE_DIR / OWNER_FILE).unlink()
    (tmp_path / DATABASE_DIR / "notes.txt").write_text("mine")  # now a folder create-infos did not write
    with pytest.raises(OutputError, match=rf"{DATABASE_DIR} holds files that memslidar create-infos did not write"):
        create_domain_infos(Source("real", tmp_path, None), force=True)
    assert sorted(p.name for p in (tmp_path / DATABASE_DIR).iterdir()) == ["000000_Pedestrian_0.bin", "notes.txt"]
    assert (tmp_path / "memslidar_infos.pkl").is_file()  # the refused rebuild left the info file in place
