"""Stereo KLT tracks with IMU rates and ground truth derived from KITTI raw drives (``kitti/raw-derived/*.mat``,
the aer1513 project's files: frames 0-499 of 2011_09_30_drive_0020 = odometry 06, 0027 = 07, 2011_10_03_0042 = 01).

Fields: ``t`` (1, N) UNIX times of the frames; ``y_k_j`` (4, N, J) stereo observations [u_L, v_L, u_R, v_R] px of
landmark j at frame k, -1 where unobserved; ``w_vk_vk_i`` and ``v_vk_vk_i`` (3, M) angular and linear velocity of
the vehicle (IMU) frame in that frame; ``r_i_vk_i`` (3, M) vehicle positions in the inertial frame and
``theta_vk_i`` (3, M) axis-angle vectors of the vehicle orientations, M >= N (the whole drive); intrinsics ``fu fv
cu cv b``; the camera's pose in the vehicle frame ``C_c_v`` (3, 3) and ``rho_v_c_v`` (3, 1).

The orientation convention is C_vk_i = exp(-theta^) (the rotation taking inertial coordinates to the vehicle
frame is the inverse of the axis-angle rotation): with it the tracks' reprojection errors under the true motion
are a pixel or two (checked by a test), with exp(+theta^) tens of pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..camera import StereoCamera
from ..errors import DataFormatError
from ..lie import make_transform, so3_exp

Array = NDArray[np.float64]

FIELDS = ("t", "y_k_j", "w_vk_vk_i", "v_vk_vk_i", "r_i_vk_i", "theta_vk_i", "fu", "fv", "cu", "cv", "b", "C_c_v", "rho_v_c_v")


@dataclass
class KLTTracks:
    """A raw-derived drive: times (N,) s, observations (N, J, 4) [u_L, v_L, u_R, v_R] px (NaN unobserved), the
    stereo camera, camera poses T_world,cam (N, 4, 4), the vehicle's angular rate and velocity (N, 3) in its own
    frame (rad/s, m/s) and its specific force (N, 3) m/s²: the world acceleration from the velocities (central
    differences) minus gravity (-9.81 m/s² along the world z axis), in the vehicle frame."""

    path: Path
    times: Array
    observations: Array
    camera: StereoCamera
    poses: Array
    angular_rate: Array
    velocity: Array
    specific_force: Array

    def __len__(self) -> int:
        return len(self.times)

    def pair(self, k: int) -> tuple[Array, Array, NDArray[np.int64]]:
        """Observations [u, v, d] (M, 3) at frames k - 1 and k of the landmarks seen in both (left and right,
        positive disparity), and their indices (M,)."""
        ref, cur = self.observations[k - 1], self.observations[k]
        seen = np.all(np.isfinite(ref), axis=1) & np.all(np.isfinite(cur), axis=1)
        seen &= (ref[:, 0] - ref[:, 2] > 0.0) & (cur[:, 0] - cur[:, 2] > 0.0)
        index = np.flatnonzero(seen)

        def uvd(o: Array) -> Array:
            return np.column_stack([o[index, 0], o[index, 1], o[index, 0] - o[index, 2]])

        return uvd(ref), uvd(cur), index.astype(np.int64)

    def motion(self, k: int) -> Array:
        """True T_cur,ref of camera frames k - 1 -> k."""
        return np.linalg.inv(self.poses[k]) @ self.poses[k - 1]


def read_klt_tracks(path: Path) -> KLTTracks:
    """Read one ``*_KLT.mat``; a missing field or inconsistent shapes is one :class:`DataFormatError`."""
    from scipy.io import loadmat

    path = Path(path)
    try:
        data = loadmat(str(path))
    except Exception as exc:  # noqa: BLE001 - scipy raises anything from IndexError to MatReadError on junk
        raise DataFormatError(path, f"not a readable .mat file ({type(exc).__name__}: {exc})") from None
    missing = [name for name in FIELDS if name not in data]
    if missing:
        raise DataFormatError(path, f"missing {', '.join(missing)}")
    times = np.asarray(data["t"], dtype=float).reshape(-1)
    tracks = np.asarray(data["y_k_j"], dtype=float)
    n = len(times)
    if tracks.ndim != 3 or tracks.shape[0] != 4 or tracks.shape[1] != n:
        raise DataFormatError(path, f"y_k_j must be (4, {n}, J), got {tracks.shape}")
    for name in ("r_i_vk_i", "theta_vk_i", "w_vk_vk_i", "v_vk_vk_i"):
        if data[name].shape[0] != 3 or data[name].shape[1] < n:
            raise DataFormatError(path, f"{name} must be (3, >= {n}), got {data[name].shape}")
    observations = np.transpose(tracks, (1, 2, 0)).copy()
    observations[observations < 0.0] = np.nan
    scalar = {name: float(np.asarray(data[name]).reshape(-1)[0]) for name in ("fu", "fv", "cu", "cv", "b")}
    camera = StereoCamera(f=scalar["fu"], cu=scalar["cu"], cv=scalar["cv"], baseline=scalar["b"])
    c_c_v = np.asarray(data["C_c_v"], dtype=float)
    rho_v_c_v = np.asarray(data["rho_v_c_v"], dtype=float).reshape(3)
    t_c_v = make_transform(c_c_v, -c_c_v @ rho_v_c_v)  # vehicle coordinates -> camera
    poses = np.empty((n, 4, 4))
    c_v_i = np.empty((n, 3, 3))
    for k in range(n):
        c_v_i[k] = so3_exp(-np.asarray(data["theta_vk_i"][:, k], dtype=float))
        t_v_i = make_transform(c_v_i[k], -c_v_i[k] @ np.asarray(data["r_i_vk_i"][:, k], dtype=float))
        poses[k] = np.linalg.inv(t_c_v @ t_v_i)  # T_world,cam
    angular = np.asarray(data["w_vk_vk_i"][:, :n], dtype=float).T
    velocity = np.asarray(data["v_vk_vk_i"][:, :n], dtype=float).T
    world_velocity = np.einsum("nji,nj->ni", c_v_i, velocity)  # C_i_v v
    acceleration = np.gradient(world_velocity, times, axis=0) if n > 1 else np.zeros((n, 3))
    gravity = np.array([0.0, 0.0, -9.81])
    specific_force = np.einsum("nij,nj->ni", c_v_i, acceleration - gravity)
    return KLTTracks(path, times, observations, camera, poses, angular, velocity, specific_force)
