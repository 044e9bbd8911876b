"""Trajectories and their file formats (KITTI odometry poses, TUM).

A :class:`Trajectory` holds ``poses`` (N, 4, 4): ``T_w_c``, the camera-to-world transform of each
frame (KITTI's ``poses/XX.txt`` convention: the pose of the left camera in the first camera's
frame), and ``stamps`` (N,) in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import DataFormatError
from .lie import is_rotation, quaternion_to_rotation, rotation_to_quaternion

Array = NDArray[np.float64]


@dataclass
class Trajectory:
    """Poses ``T_w_c`` (N, 4, 4) with stamps (N,) in seconds."""

    poses: Array
    stamps: Array

    def __post_init__(self) -> None:
        self.poses = np.asarray(self.poses, dtype=float).reshape(-1, 4, 4)
        self.stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
        if len(self.poses) != len(self.stamps):
            raise ValueError(f"{len(self.poses)} poses but {len(self.stamps)} stamps")

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def positions(self) -> Array:
        """Camera centres in the world frame, (N, 3) metres."""
        return self.poses[:, :3, 3]

    def path_length(self) -> float:
        """Total distance travelled (m)."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def summary(self) -> dict[str, float]:
        """Frames, duration (s), path length (m), mean speed (m/s), extent (m) and net displacement."""
        n = len(self)
        duration = float(self.stamps[-1] - self.stamps[0]) if n > 1 else 0.0
        length = self.path_length()
        pos = self.positions if n else np.zeros((0, 3))
        extent = (pos.max(axis=0) - pos.min(axis=0)) if n else np.zeros(3)
        net = float(np.linalg.norm(pos[-1] - pos[0])) if n else 0.0
        return {
            "frames": float(n),
            "duration_s": duration,
            "path_length_m": length,
            "mean_speed_mps": length / duration if duration > 0 else 0.0,
            "extent_x_m": float(extent[0]),
            "extent_y_m": float(extent[1]),
            "extent_z_m": float(extent[2]),
            "net_displacement_m": net,
        }


def _read_rows(path: Path, columns: int | tuple[int, ...], what: str) -> Array:
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, f"{what} file not found")
    rows: list[list[float]] = []
    with path.open() as handle:
        for number, line in enumerate(handle, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            parts = text.replace(",", " ").split()
            accepted = (columns,) if isinstance(columns, int) else columns
            if len(parts) not in accepted or (rows and len(parts) != len(rows[0])):
                expected = " or ".join(str(c) for c in accepted)
                raise DataFormatError(path, f"expected {expected} numbers per {what} line, got {len(parts)}", number)
            try:
                values = [float(p) for p in parts]
            except ValueError:
                raise DataFormatError(path, f"non-numeric value in {what} line: {text[:60]!r}", number) from None
            if not all(np.isfinite(values)):
                raise DataFormatError(path, f"NaN or infinite value in {what} line", number)
            rows.append(values)
    if not rows:
        raise DataFormatError(path, f"{what} file holds no data")
    return np.asarray(rows)


def read_kitti_poses(path: str | Path) -> Array:
    """Poses (N, 4, 4) from a KITTI pose file: 12 numbers per line, row-major 3x4 ``T_w_c``."""
    return _poses_from_rows(Path(path), _read_rows(Path(path), 12, "KITTI pose"))


def read_kitti_poses_indexed(path: str | Path) -> tuple[NDArray[np.int64], Array]:
    """Frame numbers (N,) and poses (N, 4, 4) from a KITTI pose file with or without a leading frame
    number per line (13 or 12 numbers; the KITTI evaluation toolbox accepts both)."""
    rows = _read_rows(Path(path), (12, 13), "KITTI pose")
    if rows.shape[1] == 12:
        return np.arange(len(rows), dtype=np.int64), _poses_from_rows(Path(path), rows)
    frames = rows[:, 0]
    if np.any(frames != np.round(frames)) or np.any(np.diff(frames) <= 0):
        raise DataFormatError(path, "frame numbers in the first column must be increasing integers")
    return frames.astype(np.int64), _poses_from_rows(Path(path), rows[:, 1:])


def _poses_from_rows(path: Path, rows: Array) -> Array:
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    for i, pose in enumerate(poses):
        if not is_rotation(pose[:3, :3], tol=1e-3):
            raise DataFormatError(path, "rotation part is not a rotation matrix", i + 1)
    return poses


def write_kitti_poses(path: str | Path, poses: Array) -> None:
    """Write poses (N, 4, 4) as a KITTI pose file."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
    np.savetxt(Path(path), poses[:, :3, :].reshape(-1, 12), fmt="%.9e")


def read_tum_trajectory(path: str | Path) -> Trajectory:
    """A TUM file: ``stamp x y z qx qy qz qw`` per line."""
    rows = _read_rows(Path(path), 8, "TUM trajectory")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    for i, row in enumerate(rows):
        qx, qy, qz, qw = row[4:]
        poses[i, :3, :3] = quaternion_to_rotation([qw, qx, qy, qz])
        poses[i, :3, 3] = row[1:4]
    return Trajectory(poses=poses, stamps=rows[:, 0])


def write_tum_trajectory(path: str | Path, trajectory: Trajectory) -> None:
    """Write a TUM file (quaternion with w >= 0)."""
    rows = []
    for stamp, pose in zip(trajectory.stamps, trajectory.poses, strict=True):
        w, x, y, z = rotation_to_quaternion(pose[:3, :3])
        rows.append([stamp, *pose[:3, 3], x, y, z, w])
    np.savetxt(Path(path), np.asarray(rows).reshape(-1, 8), fmt="%.9f")


def read_estimate_with_ground_truth(
    gt_path: str | Path, est_path: str | Path, gt_start: int = 0
) -> tuple[Array, Array, NDArray[np.int64]]:
    """Ground truth (full), estimate, and the estimate's ground-truth frame numbers.

    An estimate with frame numbers (13 columns) is placed by them; otherwise its k-th pose is frame
    ``gt_start + k``.
    """
    gt = read_kitti_poses(gt_path)
    frames, est = read_kitti_poses_indexed(est_path)
    if est.shape[0] and np.array_equal(frames, np.arange(len(frames))):
        frames = frames + gt_start
    if frames.max() >= len(gt):
        raise ValueError(f"{est_path}: the estimate reaches frame {int(frames.max())} but {gt_path} has only {len(gt)} poses")
    if len(frames) < 2:
        raise ValueError(f"{est_path}: need at least 2 poses to evaluate")
    return gt, est, frames
