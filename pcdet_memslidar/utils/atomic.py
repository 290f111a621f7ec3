"""Atomic file and folder writes: write to a temporary name next to the target, then rename."""
from __future__ import annotations

import contextlib
import itertools
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from pcdet_memslidar.errors import OutputError

_UMASK = os.umask(0o022)
os.umask(_UMASK)
_TEMPORARY_NUMBER = itertools.count()


def _open_temporary(path: Path) -> tuple[str, int]:
    """Create a new temporary file `.<name>.<pid>.<n>.tmp` beside `path` (creating missing folders), with the
    permissions of any new file (0o666 less the umask); returns its path and a descriptor open for writing."""
    while True:
        tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{os.getpid()}.{next(_TEMPORARY_NUMBER)}.tmp")
        try:
            return tmp, os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # left behind by a killed process that had the same pid
            continue
        except FileNotFoundError:
            Path(path).parent.mkdir(parents=True, exist_ok=True)


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
    """Write `data` (bytes or any C-contiguous buffer, e.g. a numpy array) to `path` atomically."""
    tmp, descriptor = _open_temporary(path)
    try:
        with open(descriptor, "wb") as file:
            file.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text(path: str | Path, text: str) -> None:
    """Write `text` (UTF-8) to `path` atomically."""
    write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield an empty temporary folder beside `path`; on success it replaces `path` whole, else it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_UMASK)
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
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
