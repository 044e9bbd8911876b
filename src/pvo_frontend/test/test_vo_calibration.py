"""The VO calibration record (`pvo_frontend.vo_calibration`): written and read back, malformed entries named, and a
graph's VO told apart from the one a record measured."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from pvo_frontend.vo import VOConfig, from_flat
from pvo_frontend.vo_calibration import (
    differing_settings,
    read_vo_calibration,
    recorded_settings,
    resolve_calibration,
    write_vo_calibration,
)

SCALE = [1.25, 0.25, 1.15, 0.13, 0.37, 0.19]


def test_a_record_keeps_the_files_other_fields_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "vo.yaml"
    path.write_text("description: my rig\n")
    write_vo_calibration(path, {"covariance_scale": SCALE, "vo_settings": recorded_settings(VOConfig())})
    document = yaml.safe_load(path.read_text())
    assert document["description"] == "my rig"
    calibration = read_vo_calibration(path)
    assert calibration is not None and calibration.covariance_scale == tuple(SCALE) and calibration.source == path
    # a bad entry is refused and the good one stays
    with pytest.raises(ValueError, match=r"vo\.yaml: vo_calibration.covariance_scale must be 6 positive numbers"):
        write_vo_calibration(path, {"covariance_scale": [1.0, float("nan"), 1.0, 1.0, 1.0, 1.0]})
    assert read_vo_calibration(path).covariance_scale == tuple(SCALE)  # type: ignore[union-attr]


def test_reading_names_the_file_and_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="missing.yaml: not a readable VO calibration"):
        read_vo_calibration(tmp_path / "missing.yaml")
    path = tmp_path / "vo.yaml"
    path.write_text("description: none yet\n")
    assert read_vo_calibration(path) is None
    path.write_text(yaml.safe_dump({"vo_calibration": {"covariance_scale": SCALE, "vo_settings": [1, 2]}}))
    with pytest.raises(ValueError, match="vo_settings must be a mapping"):
        read_vo_calibration(path)


def test_the_graphs_vo_is_compared_setting_by_setting(tmp_path: Path) -> None:
    path = tmp_path / "vo.yaml"
    recorded = recorded_settings(from_flat({"ransac.inlier_threshold": 16.0}))
    assert "probe.model" not in recorded
    # YAML reads 16 where the VO holds 16.0, tuples come back as lists: neither is a difference
    write_vo_calibration(path, {"covariance_scale": SCALE, "vo_settings": {**recorded, "ransac.inlier_threshold": 16}})
    calibration = read_vo_calibration(path)
    assert calibration is not None
    assert differing_settings(calibration, {"ransac.inlier_threshold": 16.0, "probe.model": "anything"}) == {}
    assert differing_settings(calibration, {}) == {"ransac.inlier_threshold": (16, 4.0)}
    with pytest.raises(ValueError):
        differing_settings(calibration, {"ransac.nonsense": 1})
    # a record that predates recorded settings compares with nothing
    write_vo_calibration(path, {"covariance_scale": SCALE})
    assert differing_settings(read_vo_calibration(path), {"ransac.inlier_threshold": 16.0}) == {}  # type: ignore[arg-type]


def test_the_shipped_record_is_of_the_default_vo() -> None:
    calibration = read_vo_calibration(resolve_calibration("default_vo"))
    assert calibration is not None and len(calibration.covariance_scale) == 6
    assert differing_settings(calibration, {}) == {}
