"""Where the command looks for data: --data, else $PVO_DATA_DIR, else ../shared/data beside the repository root,
wherever it runs; overrides parse from files and the command line with clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest
from pvo_tools.errors import PvoError
from pvo_tools.overrides import parse_overrides
from pvo_tools.paths import data_directory, default_data_directory, repository_root

ROOT = Path(__file__).resolve().parents[3]


def test_the_default_is_beside_the_repository_root_from_any_directory(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv("PVO_DATA_DIR", raising=False)
    monkeypatch.chdir(tmp_path)
    assert repository_root() == ROOT
    assert default_data_directory() == ROOT.parent / "shared" / "data"
    monkeypatch.setenv("PVO_DATA_DIR", str(tmp_path))
    assert default_data_directory() == tmp_path
    with pytest.raises(PvoError, match=f"data directory {tmp_path} has no kitti/ folder"):
        data_directory()
    (tmp_path / "kitti").mkdir()
    assert data_directory() == tmp_path


def test_overrides_from_a_params_file_take_the_named_nodes_section(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text(
        "stereo_vo:\n  ros__parameters:\n    solver.loss: huber\nfusion:\n  ros__parameters:\n    window.lag: 5.0\n"
    )
    assert parse_overrides(["ransac.seed=3"], params, node="stereo_vo") == {"solver.loss": "huber", "ransac.seed": 3}
    assert parse_overrides(None, params, node="fusion") == {"window.lag": 5.0}
    with pytest.raises(PvoError, match="expected 'simulated_sun: ros__parameters"):
        parse_overrides(None, params, node="simulated_sun")
    with pytest.raises(PvoError, match="must be NAME=VALUE"):
        parse_overrides(["solver.loss"])
