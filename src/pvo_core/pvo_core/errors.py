"""Exceptions with messages that name the file (and line) that is wrong."""

from __future__ import annotations

from pathlib import Path


class DataFormatError(ValueError):
    """A dataset file is missing, unreadable or malformed. ``str()`` is one line naming it."""

    def __init__(self, path: str | Path, message: str, line: int | None = None) -> None:
        self.path = Path(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        super().__init__(f"{where}: {message}")
