"""Readers of the simulator's sidecar files (``imu.csv``, ``gps.csv``, times relative to the first frame) and of
the pseudo-sensors' prediction files (Sun-BCNN's ``pred.csv``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pvo_core.errors import DataFormatError

Array = NDArray[np.float64]


def _read_csv(path: Path, header: str, columns: int) -> Array:
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "file not found")
    lines = path.read_text().splitlines()
    if not lines or lines[0].strip() != header:
        raise DataFormatError(path, f"expected the header {header!r}", 1)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.split(",")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise DataFormatError(path, "non-numeric value", number) from None
        if len(values) != columns or not np.all(np.isfinite(values)):
            raise DataFormatError(path, f"expected {columns} finite numbers", number)
        rows.append(values)
    if not rows:
        raise DataFormatError(path, "no data")
    data = np.asarray(rows)
    if np.any(np.diff(data[:, 0]) <= 0):
        raise DataFormatError(path, "times must increase")
    return data


def read_imu_csv(path: Path) -> Array:
    """(N, 7): t [s from the first frame], angular rate (rad/s), specific force (m/s²), camera frame."""
    return _read_csv(path, "t,wx,wy,wz,fx,fy,fz", 7)


def imu_at_stamps(rows: Array, stamps: Array, tolerance: float = 0.05) -> Array:
    """The IMU reading nearest each stamp, (N, 6) [wx, wy, wz, fx, fy, fz], from ``read_imu_csv`` rows (M, 7)
    whose times share the stamps' origin (s); a stamp farther than ``tolerance`` s from every reading is an error."""
    times = rows[:, 0]
    index = np.clip(np.searchsorted(times, stamps), 1, len(times) - 1) if len(times) > 1 else np.zeros(len(stamps), int)
    if len(times) > 1:
        index = np.where(np.abs(times[index - 1] - stamps) <= np.abs(times[index] - stamps), index - 1, index)
    far = np.abs(times[index] - stamps) > tolerance
    if np.any(far):
        k = int(np.flatnonzero(far)[0])
        raise ValueError(f"no IMU reading within {tolerance} s of the frame at {stamps[k]:.3f} s")
    return rows[index, 1:7]


def read_gps_csv(path: Path) -> Array:
    """(N, 4): t [s from the first frame], latitude, longitude (deg), altitude (m)."""
    return _read_csv(path, "t,latitude,longitude,altitude", 4)


SUN_PREDICTIONS_HEADER = "frame,sx,sy,sz,zenith,azimuth,c_zz,c_za,c_az,c_aa"


def read_sun_predictions_csv(path: Path) -> Array:
    """(N, 10) rows of a Sun-BCNN prediction file: frame, the unit sun vector in the camera optical frame,
    zenith and azimuth (rad), and the 2x2 covariance over (zenith, azimuth) row-major (rad²)."""
    rows = _read_csv(Path(path), SUN_PREDICTIONS_HEADER, 10)
    norms = np.linalg.norm(rows[:, 1:4], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise DataFormatError(path, f"sun vector of frame {int(rows[bad[0], 0])} is not unit length", int(bad[0]) + 2)
    return rows


ROTATION_PREDICTIONS_HEADER = "frame_prev,frame,qw,qx,qy,qz,c00,c01,c02,c10,c11,c12,c20,c21,c22"


def read_rotation_predictions_csv(path: Path) -> Array:
    """(N, 15) rows of a HydraNet prediction file: the earlier and the later frame, the unit quaternion
    (w, x, y, z) of C_later,earlier and its 3x3 covariance (rad², left tangent space) row-major."""
    rows = _read_csv(Path(path), ROTATION_PREDICTIONS_HEADER, 15)
    norms = np.linalg.norm(rows[:, 2:6], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise DataFormatError(path, f"quaternion of frame {int(rows[bad[0], 1])} is not unit length", int(bad[0]) + 2)
    covariances = rows[:, 6:].reshape(-1, 3, 3)
    symmetric = np.abs(covariances - covariances.transpose(0, 2, 1)).max(axis=(1, 2)) <= 1e-9 + 1e-6 * np.abs(covariances).max(
        axis=(1, 2)
    )
    positive = np.all(np.linalg.eigvalsh(0.5 * (covariances + covariances.transpose(0, 2, 1))) > 0.0, axis=1)
    bad = np.flatnonzero(~(symmetric & positive))
    if bad.size:
        raise DataFormatError(
            path, f"covariance of frame {int(rows[bad[0], 1])} is not symmetric positive definite", int(bad[0]) + 2
        )
    return rows
