"""Atomic file and folder writes: write to a temporary name next to the target, then rename.

Temporary names are `.<name>.<pid>.<n>.tmp` (files and folders alike). One left behind by a process that was killed
(kill -9, power loss) is removed by the next write into the same folder, once per folder and process; one whose
process is still alive is never touched.

A folder written by atomic_dir holds OWNER_FILE naming the command that wrote it: a rerun of that command may
replace it, anything else (a user's folder, a file) is refused with an OutputError.
"""
from __future__ import annotations

import contextlib
import itertools
import os
import re
import shutil
from pathlib import Path
from typing import Callable, Iterator, TypeVar

from pcdet_memslidar.errors import OutputError

OWNER_FILE = ".memslidar-output"  # in a folder written by atomic_dir: first line the command that wrote it
_TEMPORARY_NUMBER = itertools.count()
_TEMPORARY = re.compile(r"\..+\.(\d{1,7})\.\d+\.tmp")  # group 1: the pid (Linux pids are < 2**22)
_CLEANED: set[str] = set()  # folders whose leftovers this process has removed
T = TypeVar("T")


def _temporary_names(path: Path) -> Iterator[str]:
    """Endless `.<name>.<pid>.<n>.tmp` beside `path`, n counting up over the whole process."""
    folder, name = os.path.split(path)
    while True:
        yield os.path.join(folder, f".{name}.{os.getpid()}.{next(_TEMPORARY_NUMBER)}.tmp")


def _alive(pid: int) -> bool:
    """Whether process `pid` exists (on this machine)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def remove_leftovers(folder: str | Path) -> None:
    """Delete the temporary files and folders in `folder` whose process is no longer alive (first call per folder
    in this process only: later ones are free)."""
    folder = os.path.abspath(folder)
    if folder in _CLEANED:
        return
    _CLEANED.add(folder)
    try:
        entries = list(os.scandir(folder))
    except OSError:  # missing or unreadable: nothing to clean
        return
    for entry in entries:
        match = _TEMPORARY.fullmatch(entry.name)
        if not match or _alive(int(match.group(1))):
            continue
        if entry.is_dir(follow_symlinks=False):
            shutil.rmtree(entry.path, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(entry.path)


def _create_temporary(path: str | Path, create: Callable[[str], T]) -> tuple[str, T]:
    """(name, create(name)) for the first free temporary name beside `path`, creating missing folders; other
    errors are raised naming `path` rather than the hidden name."""
    remove_leftovers(os.path.dirname(path))
    for tmp in _temporary_names(path):
        try:
            return tmp, create(tmp)
        except FileExistsError:  # left behind by a killed process that had the same pid
            continue
        except FileNotFoundError:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # read-only folder, full disk, ...
            raise OSError(error.errno, error.strerror, str(path)) from None


def _open_temporary(path: str | Path) -> tuple[str, int]:
    """A new temporary file beside `path` with the permissions of any new file (0o666 less the umask): its name
    and a descriptor open for writing."""
    return _create_temporary(path, lambda tmp: os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))


def _make_temporary_dir(path: Path) -> Path:
    """A new empty temporary folder beside `path` (0o777 less the umask)."""
    return Path(_create_temporary(path, os.mkdir)[0])


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it onto `path`, else delete it."""
    tmp, descriptor = _open_temporary(path)
    os.close(descriptor)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes(path: str | Path, data) -> None:
    """Write `data` (bytes or any C-contiguous buffer, e.g. a numpy array) to `path` atomically. An OSError without
    a file name (a full disk fails the write itself) is raised again naming `path`."""
    tmp, descriptor = _open_temporary(path)
    try:
        with open(descriptor, "wb") as file:
            file.write(data)
        os.replace(tmp, path)
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(error, OSError) and error.filename is None:
            raise OSError(error.errno, error.strerror or str(error), str(path)) from error
        raise


def write_text(path: str | Path, text: str) -> None:
    """Write `text` (UTF-8) to `path` atomically."""
    write_bytes(path, text.encode("utf-8"))


def check_output_folder(path: str | Path, owner: str) -> None:
    """Raise OutputError unless `path` is missing, an empty folder, or a folder that `owner` (a command, e.g.
    'memslidar import') wrote with atomic_dir: only those may be replaced."""
    path = Path(path)
    fix = "choose a new folder, or move or delete it yourself"
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise OutputError(f"{path} is a {'symbolic link' if path.is_symlink() else 'file'}, not a folder that "
                          f"{owner} wrote; {fix}")
    if not path.is_dir() or not any(path.iterdir()):
        return
    marker = path / OWNER_FILE
    if not marker.is_file() or marker.read_text(encoding="utf-8", errors="replace").splitlines()[:1] != [owner]:
        raise OutputError(f"{path} holds files that {owner} did not write (it has no {OWNER_FILE} naming it), so "
                          f"it will not replace them; {fix}")


def mark_output(folder: str | Path, owner: str) -> None:
    """Write OWNER_FILE into `folder`: `owner` (a command) wrote it and may replace it (check_output_folder)."""
    write_text(Path(folder) / OWNER_FILE, f"{owner}\nThis folder was written by `{owner}`; running it again replaces "
                                          "the folder whole. Keep your own files elsewhere.\n")


@contextlib.contextmanager
def atomic_dir(path: str | Path, owner: str) -> Iterator[Path]:
    """Yield an empty temporary folder beside `path`; on success it replaces `path` whole, else it is removed.

    `owner` (the command writing, e.g. 'memslidar import') is written to OWNER_FILE in the folder; `path` must pass
    check_output_folder(path, owner) (checked before and at the swap). An OSError about a file in the temporary
    folder is raised again naming the file's place under `path`.
    """
    path = Path(path)
    check_output_folder(path, owner)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _make_temporary_dir(path)
    try:
        yield tmp
        mark_output(tmp, owner)
        check_output_folder(path, owner)
        if path.exists():
            old = _make_temporary_dir(path)
            os.replace(path, old)  # onto the empty folder
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as error:
        if error.filename is None or not Path(error.filename).is_relative_to(tmp):
            raise
        raise OSError(error.errno, error.strerror, str(path / Path(error.filename).relative_to(tmp))) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def scratch_dir(path: str | Path) -> Iterator[Path]:
    """Yield a new empty temporary folder beside `path`, removed afterwards (after a kill: by remove_leftovers), for
    a writer that makes the file `path` with files of its own: rename the finished file onto `path` (os.replace)
    inside the block."""
    tmp = _make_temporary_dir(Path(path))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def refuse_overlap(output: str | Path, inputs, option: str = "the output") -> Path:
    """Return `output` resolved; raise OutputError if it equals or contains one of `inputs` (files or folders),
    since writing it could replace or delete an input."""
    output = Path(output).resolve()
    for source in inputs:
        source = Path(source).resolve()
        if source == output or output in source.parents:
            raise OutputError(f"{option} {output} {'is' if source == output else 'contains'} the input {source}; "
                              f"choose {option} outside every input")
    return output
