"""The KITTI raw-derived KLT tracks: shapes, the orientation convention (checked against the tracks
themselves: their reprojection error under the true motion) and bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.errors import DataFormatError
from pvo_core.readers import read_klt_tracks

DRIVES = ("2011_09_30_drive_0020_sync_KLT.mat", "2011_09_30_drive_0027_sync_KLT.mat", "2011_10_03_drive_0042_sync_KLT.mat")


@pytest.mark.parametrize("name", DRIVES)
def test_tracks_reproject_under_the_true_motion_within_a_pixel_or_two(pvo_data: Path, name: str) -> None:
    tracks = read_klt_tracks(pvo_data / "kitti" / "raw-derived" / name)
    assert len(tracks) == 500 and tracks.observations.shape[0] == 500 and tracks.observations.shape[2] == 4
    assert tracks.camera.f == pytest.approx(707.0912) or tracks.camera.f > 700.0
    medians = []
    for k in range(1, 500, 25):
        ref, cur, index = tracks.pair(k)
        assert len(ref) >= 6 and len(index) == len(ref)
        motion = tracks.motion(k)
        moved = tracks.camera.triangulate(ref) @ motion[:3, :3].T + motion[:3, 3]
        medians.append(np.median(np.abs(tracks.camera.project(moved) - cur)[:, :2]))
    assert np.median(medians) < 2.0
    # the vehicle moves forward (camera z) and the specific force holds gravity (~9.8 m/s^2)
    steps = np.array([tracks.motion(k)[:3, 3] for k in range(1, 500)])
    assert np.median(-steps[:, 2]) > 0.1
    assert 8.0 < np.median(np.linalg.norm(tracks.specific_force, axis=1)) < 11.5


def test_a_file_without_the_fields_is_one_clear_error(tmp_path: Path) -> None:
    from scipy.io import savemat

    savemat(tmp_path / "bad.mat", {"t": np.zeros((1, 3))})
    with pytest.raises(DataFormatError, match=r"bad.mat.*missing y_k_j"):
        read_klt_tracks(tmp_path / "bad.mat")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(DataFormatError, match="junk.mat"):
        read_klt_tracks(tmp_path / "junk.mat")
