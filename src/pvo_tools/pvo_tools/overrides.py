"""Parameter overrides on the command line (``-p name=value``) and from ROS-style YAML parameter files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pvo_core.config import parse_assignments

from .errors import PvoError


def read_params_file(path: Path, node: str) -> dict[str, Any]:
    """The dotted parameters of ``node`` in a ROS 2 parameter file (``node: ros__parameters: {...}``)."""
    if not path.is_file():
        raise PvoError(f"{path}: parameter file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise PvoError(f"{path}: not valid YAML: {exc}") from None
    section = data.get(node) if isinstance(data, dict) else None
    params = section.get("ros__parameters") if isinstance(section, dict) else None
    if not isinstance(params, dict):
        raise PvoError(f"{path}: expected '{node}: ros__parameters: {{...}}'")
    return dict(params)


def parse_overrides(items: list[str] | None, params_file: Path | None = None, node: str = "") -> dict[str, Any]:
    """Parameters from ``params_file`` (the ``node`` section), then ``name=value`` items (values read as YAML)."""
    values: dict[str, Any] = {}
    if params_file is not None:
        values.update(read_params_file(params_file, node))
    try:
        values.update(parse_assignments(items or []))
    except ValueError as exc:
        raise PvoError(f"parameter {exc}") from None
    return values
