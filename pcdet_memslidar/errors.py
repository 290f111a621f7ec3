"""Errors that tell the user which file (and line) is wrong and how to fix it."""
from __future__ import annotations

from pathlib import Path


class DataFormatError(ValueError):
    """A data file is missing or malformed; the message names the file, the line and the fix."""

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        where = f"{path}" if line is None else f"{path}:{line}"
        super().__init__(f"{where}: {message}")
        self.path, self.line = Path(path), line


class ConfigError(ValueError):
    """A config is inconsistent (unknown key, grid that does not fit the network, missing base file, ...)."""


class OutputError(ValueError):
    """An output path would overwrite or delete something the command did not create (an input, a user's file)."""
