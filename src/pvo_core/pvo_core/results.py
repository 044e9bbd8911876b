"""The run-result record: what every evaluation, experiment and the demo writes as ``metrics.json``.

One shape for every run so that runs can be compared by a script: ``kind`` (``eval``,
``experiment/sun-sim``, ``demo`` ...), ``name`` (what was run), ``figures`` (the headline numbers, flat,
named with their unit), ``tables`` (named row -> column -> number tables, e.g. per sequence or per
estimator), ``inputs`` (files and settings that produced it) and ``notes`` (definitions in words).
Non-finite numbers are written as ``null``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

SCHEMA = "pvo.run-result/1"


@dataclass
class RunResult:
    kind: str
    name: str
    figures: dict[str, Any] = field(default_factory=dict)
    tables: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    schema: str = SCHEMA

    def to_json(self) -> str:
        return json.dumps(_finite(asdict(self)), indent=2, sort_keys=False) + "\n"

    def write(self, path: str | Path) -> Path:
        """Write the record (``path`` a file, or a directory to hold ``metrics.json``); returns the file."""
        path = Path(path)
        if path.is_dir() or not path.suffix:
            path = path / "metrics.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json())
        return path

    @classmethod
    def read(cls, path: str | Path) -> RunResult:
        """Read a record; ``ValueError`` naming the file when it is not one."""
        path = Path(path)
        if path.is_dir():
            path = path / "metrics.json"
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: not a readable run-result record: {exc}") from None
        if not isinstance(data, dict) or data.get("schema") != SCHEMA:
            raise ValueError(f"{path}: not a run-result record (schema {SCHEMA!r} expected)")
        return cls(**{k: data[k] for k in ("kind", "name", "figures", "tables", "inputs", "notes", "schema") if k in data})


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy scalars
        return _finite(value.item())
    if hasattr(value, "tolist"):
        return _finite(value.tolist())
    return value
