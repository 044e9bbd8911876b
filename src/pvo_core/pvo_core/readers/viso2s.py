"""The thesis baseline's stereo VO results: ``kitti/viso2s-vo/baseline/<drive>.mat`` (libviso2, per KITTI drive).

Each file holds the ground truth ``poses_gt`` and the VO ``poses_est`` (4x4xN, T_world,cam of the left
camera) and, for most drives, ``Sigma_21`` (N-1 6x6 covariances of the per-frame motions T_k,k-1, ROS
order [rho; phi] of a left perturbation). Files are named by KITTI raw drive; :data:`SEQUENCE_DRIVES`
maps the odometry sequences 00-10 (03 has no raw drive) to them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError
from ..lie import nearest_rotations

Array = NDArray[np.float64]

SEQUENCE_DRIVES = {
    "00": "2011_10_03_drive_0027",
    "01": "2011_10_03_drive_0042",
    "02": "2011_10_03_drive_0034",
    "04": "2011_09_30_drive_0016",
    "05": "2011_09_30_drive_0018",
    "06": "2011_09_30_drive_0020",
    "07": "2011_09_30_drive_0027",
    "08": "2011_09_30_drive_0028",
    "09": "2011_09_30_drive_0033",
    "10": "2011_09_30_drive_0034",
}


@dataclass(frozen=True)
class Viso2sRun:
    """One drive: ground truth and VO poses (N, 4, 4), VO motion covariances (N-1, 6, 6) or None."""

    drive: str
    ground_truth: Array
    vo_poses: Array
    covariances: Array | None


def viso2s_path(data_dir: str | Path, sequence: str) -> Path:
    """``<data>/kitti/viso2s-vo/baseline/<drive>.mat`` of an odometry sequence ("00".."10", not "03")."""
    if sequence not in SEQUENCE_DRIVES:
        raise ValueError(f"sequence {sequence!r} is not one of {', '.join(SEQUENCE_DRIVES)}")
    return Path(data_dir) / "kitti" / "viso2s-vo" / "baseline" / f"{SEQUENCE_DRIVES[sequence]}.mat"


def read_viso2s(path: str | Path, project_rotations: bool = True) -> Viso2sRun:
    """Read one ``.mat`` file.

    project_rotations: the files' rotations are orthonormal to ~4e-13 only; composed over thousands of
    frames with inverse = transpose (GTSAM) or with a general inverse, the same VO drifts 2.6e-7 m apart.
    True projects them onto SO(3); False keeps the stored numbers (to reproduce published metrics).
    """
    from scipy.io import loadmat

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "no such file (see shared/data/SOURCES.md)")
    try:
        mat = loadmat(str(path))
    except Exception as exc:  # noqa: BLE001 - scipy raises ValueError, OSError, IndexError ... for broken files
        raise DataFormatError(path, f"not a readable MATLAB file: {str(exc) or type(exc).__name__}") from None
    for key in ("poses_gt", "poses_est"):
        if key not in mat or mat[key].ndim != 3 or mat[key].shape[:2] != (4, 4):
            raise DataFormatError(path, f"{key} missing or not 4x4xN")
    gt = np.ascontiguousarray(np.moveaxis(mat["poses_gt"], 2, 0), dtype=float)
    est = np.ascontiguousarray(np.moveaxis(mat["poses_est"], 2, 0), dtype=float)
    if len(gt) != len(est):
        raise DataFormatError(path, f"{len(gt)} ground-truth poses but {len(est)} VO poses")
    covariances = np.asarray(mat["Sigma_21"], dtype=float) if "Sigma_21" in mat else None
    if covariances is not None and covariances.shape != (len(gt) - 1, 6, 6):
        raise DataFormatError(path, f"Sigma_21 has shape {covariances.shape}, expected ({len(gt) - 1}, 6, 6)")
    if project_rotations:
        for poses in (gt, est):
            poses[:, :3, :3] = nearest_rotations(poses[:, :3, :3])
    drive = path.stem
    return Viso2sRun(drive, gt, est, covariances)


def read_viso2s_sequence(data_dir: str | Path, sequence: str, project_rotations: bool = True) -> Viso2sRun:
    """The viso2-s run of an odometry sequence, found through :data:`SEQUENCE_DRIVES`."""
    return read_viso2s(viso2s_path(data_dir, sequence), project_rotations)


FRAME_PERIOD_NS = 100_000_000  # KITTI 10 Hz; the .mat files carry no times
FIRST_STAMP_NS = 1_000_000_000


@dataclass
class KittiSunSequence:
    """One KITTI odometry sequence for the sun experiment: the viso2-s run plus the ground-truth sun.

    ground_truth, vo_poses: T_map,cam (N, 4, 4) with map = the first ground-truth camera frame;
    covariances: (N-1, 6, 6) ROS-order left covariances of the VO motions T_k,k-1 (None for 01, 04);
    sun_camera: (N, 3) unit sun vectors in the camera frame; stamps: (N,) ns at 10 Hz (the files carry none).
    """

    name: str
    drive: str
    ground_truth: Array
    vo_poses: Array
    covariances: Array | None
    sun_camera: Array

    @property
    def stamps(self) -> NDArray[np.int64]:
        return FIRST_STAMP_NS + FRAME_PERIOD_NS * np.arange(len(self.ground_truth), dtype=np.int64)

    @property
    def motions(self) -> Array:
        """VO motions T_k,k-1 (N-1, 4, 4)."""
        from ..metrics import se3_inverse_batch

        return se3_inverse_batch(self.vo_poses[1:]) @ self.vo_poses[:-1]

    def sun_map(self) -> Array:
        """Ground-truth sun direction in the map frame per frame (N, 3): C_map,k s_k."""
        return np.einsum("nij,nj->ni", self.ground_truth[:, :3, :3], self.sun_camera)

    def clipped(self, frames: int) -> KittiSunSequence:
        """The first ``frames`` frames."""
        if frames < 2:
            raise ValueError(f"a clip needs at least 2 frames, got {frames}")
        n = min(frames, len(self.ground_truth))
        covs = None if self.covariances is None else self.covariances[: n - 1]
        return KittiSunSequence(self.name, self.drive, self.ground_truth[:n], self.vo_poses[:n], covs, self.sun_camera[:n])


def read_kitti_sun_sequence(data_dir: str | Path, name: str) -> KittiSunSequence:
    """``kitti/viso2s-vo/baseline/<drive>.mat`` (rotations projected onto SO(3)) and
    ``kitti/sun/kitti_sun_test_<name>.csv`` of an odometry sequence, checked to have the same length."""
    from .kitti import read_kitti_sun_csv

    run = read_viso2s_sequence(data_dir, name)
    sun_path = Path(data_dir) / "kitti" / "sun" / f"kitti_sun_test_{name}.csv"
    sun = read_kitti_sun_csv(sun_path)
    if len(sun) != len(run.ground_truth):
        raise DataFormatError(sun_path, f"{len(sun)} sun vectors for {len(run.ground_truth)} poses of sequence {name}")
    return KittiSunSequence(name, run.drive, run.ground_truth, run.vo_poses, run.covariances, sun)
