"""The run-result record round-trips through metrics.json; NaN becomes null; a foreign file is one clear error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.results import RunResult


def test_round_trip_with_numpy_values_and_nan(tmp_path: Path) -> None:
    record = RunResult(
        "eval",
        "06",
        figures={"ate_rmse_m": np.float64(0.25), "anees": float("nan"), "frames": np.int64(51)},
        tables={"per_sequence": {"06": {"rot": 1.5e-3}}},
        inputs={"gt": "poses.txt"},
    )
    path = record.write(tmp_path)
    assert path == tmp_path / "metrics.json"
    back = RunResult.read(tmp_path)
    assert back.figures == {"ate_rmse_m": 0.25, "anees": None, "frames": 51}
    assert back.tables["per_sequence"]["06"]["rot"] == 1.5e-3
    assert back.kind == "eval" and back.inputs == {"gt": "poses.txt"}


def test_a_file_that_is_not_a_record_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "metrics.json"
    bad.write_text('{"devkit": 1}')
    with pytest.raises(ValueError, match="not a run-result record"):
        RunResult.read(bad)
    bad.write_text("{")
    with pytest.raises(ValueError, match="not a readable run-result record"):
        RunResult.read(bad)
