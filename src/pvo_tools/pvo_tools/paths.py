"""Where the command finds the real data and the repository, wherever it runs."""

from __future__ import annotations

import os
from pathlib import Path

from .errors import PvoError

REPOSITORY_MARKER = "colcon.meta"  # at the root of a pvo checkout


def repository_root() -> Path | None:
    """The pvo checkout this command was built from (its install/ lies inside it), else the one the working
    directory is in; None when neither is a checkout."""
    for start in (Path(__file__).resolve(), Path.cwd().resolve()):
        for directory in (start, *start.parents):
            if (directory / REPOSITORY_MARKER).is_file() and (directory / "src" / "pvo_tools").is_dir():
                return directory
    return None


def default_data_directory() -> Path:
    """``$PVO_DATA_DIR``, else ``../shared/data`` next to the repository root."""
    if os.environ.get("PVO_DATA_DIR"):
        return Path(os.environ["PVO_DATA_DIR"])
    root = repository_root()
    if root is None:
        raise PvoError("no data directory: set PVO_DATA_DIR or --data (not inside a pvo checkout)")
    return root.parent / "shared" / "data"


def data_directory(explicit: Path | None = None, need: str = "kitti") -> Path:
    """``--data``, else :func:`default_data_directory`, checked to hold ``need/``."""
    path = explicit if explicit is not None else default_data_directory()
    if not (path / need).is_dir():
        raise PvoError(f"data directory {path} has no {need}/ folder (set --data or PVO_DATA_DIR)")
    return path
