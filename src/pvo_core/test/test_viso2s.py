"""The viso2-s results reader and the KITTI sun sequences of the thesis experiment (real data)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.errors import DataFormatError
from pvo_core.readers import SEQUENCE_DRIVES, read_kitti_sun_sequence, read_viso2s, read_viso2s_sequence


def test_all_sequences_are_mapped() -> None:
    assert list(SEQUENCE_DRIVES) == ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"]


def test_sequences_load_and_sun_vectors_agree_with_the_ground_truth(pvo_data: Path) -> None:
    seq = read_kitti_sun_sequence(pvo_data, "04")
    assert seq.covariances is None and len(seq.stamps) == 271
    seq = read_kitti_sun_sequence(pvo_data, "07")
    assert seq.covariances is not None and seq.covariances.shape == (len(seq.stamps) - 1, 6, 6)
    # The map-frame sun direction from ground truth barely moves over the drive: the camera-frame
    # vectors and the poses are in the same frame.
    s_map = seq.sun_map()
    spread = np.degrees(np.arccos(np.clip(s_map @ s_map[0], -1.0, 1.0)))
    assert spread.max() < 2.0
    clip = seq.clipped(20)
    assert len(clip.stamps) == 20 and clip.covariances is not None and clip.covariances.shape == (19, 6, 6)
    with pytest.raises(ValueError, match="not one of"):
        read_kitti_sun_sequence(pvo_data, "03")


def test_rotations_are_projected_onto_so3_only_when_asked(pvo_data: Path) -> None:
    raw = read_viso2s_sequence(pvo_data, "06", project_rotations=False)
    projected = read_viso2s_sequence(pvo_data, "06")
    r = projected.vo_poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-15)
    assert 0.0 < np.max(np.abs(raw.vo_poses - projected.vo_poses)) < 1e-11


def test_a_missing_or_foreign_file_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="no such file"):
        read_viso2s(tmp_path / "2011_09_30_drive_0020.mat")
    bad = tmp_path / "bad.mat"
    bad.write_bytes(b"not a mat file at all")
    with pytest.raises(DataFormatError, match=r"bad\.mat: not a readable MATLAB file"):
        read_viso2s(bad)
    from scipy.io import savemat

    savemat(tmp_path / "short.mat", {"poses_gt": np.zeros((4, 4, 3)), "poses_est": np.zeros((4, 4, 2))})
    with pytest.raises(DataFormatError, match="3 ground-truth poses but 2 VO poses"):
        read_viso2s(tmp_path / "short.mat")
