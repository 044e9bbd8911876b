"""The rectified stereo camera model of thesis eqs. 3.1-3.3 and B.17-B.19.

A point ``p = [x, y, z]`` (metres) in the left camera optical frame (x right, y down, z forward)
is observed as ``y = [u, v, d]`` (pixels): left-image coordinates and disparity ``d = u_l - u_r``::

    u = f x / z + cu,   v = f y / z + cv,   d = f b / z

and triangulated back by ``p = (b / d) [u - cu, v - cv, f]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class StereoCamera:
    """An ideal fronto-parallel (rectified) stereo pair.

    Attributes:
        f: focal length (px), the same for both axes after rectification.
        cu, cv: principal point (px).
        baseline: distance between the optical centres (m), > 0.
        width, height: image size (px); 0 when unknown.
    """

    f: float
    cu: float
    cv: float
    baseline: float
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        for name in ("f", "cu", "cv", "baseline"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"stereo camera {name} is not finite")
        if self.f <= 0.0:
            raise ValueError(f"stereo camera focal length must be positive, got {self.f}")
        if self.baseline <= 0.0:
            raise ValueError(f"stereo camera baseline must be positive, got {self.baseline} m")

    @classmethod
    def from_projection_matrices(cls, p_left: ArrayLike, p_right: ArrayLike, width: int = 0, height: int = 0) -> StereoCamera:
        """Build from the 3x4 rectified projection matrices (KITTI ``P0``/``P1``, ROS ``P``).

        The right matrix carries ``P[0, 3] = -f * baseline``.
        """
        pl = np.asarray(p_left, dtype=float).reshape(3, 4)
        pr = np.asarray(p_right, dtype=float).reshape(3, 4)
        f = pl[0, 0]
        if f <= 0.0:
            raise ValueError(f"projection matrix has non-positive focal length {f}")
        baseline = -(pr[0, 3] - pl[0, 3]) / f
        return cls(f=f, cu=pl[0, 2], cv=pl[1, 2], baseline=baseline, width=width, height=height)

    @classmethod
    def from_camera_infos(cls, left: Any, right: Any) -> StereoCamera:
        """The rectified stereo model from two ``sensor_msgs/CameraInfo``-shaped messages (``width``,
        ``height``, ``p``; rclpy or rosbags); ``ValueError`` naming the problem."""
        if (left.width, left.height) != (right.width, right.height):
            raise ValueError(f"left camera_info is {left.width}x{left.height} but right is {right.width}x{right.height}")
        p_left = np.asarray(left.p, dtype=float).reshape(3, 4)
        p_right = np.asarray(right.p, dtype=float).reshape(3, 4)
        if not (np.all(np.isfinite(p_left)) and np.all(np.isfinite(p_right))):
            raise ValueError("projection matrix P contains NaN")
        if p_left[0, 0] <= 0.0:
            raise ValueError("left camera_info P has no focal length (P[0] = 0): is the camera calibrated?")
        if p_right[0, 3] >= 0.0:
            raise ValueError(f"right camera_info P[3] = {p_right[0, 3]} must be -fx * baseline < 0 for a rectified stereo pair")
        return cls.from_projection_matrices(p_left, p_right, int(left.width), int(left.height))

    def projection_matrices(self) -> tuple[Array, Array]:
        """The rectified 3x4 ``P`` of the left and right camera (ROS camera_info; right ``P[0, 3] = -f * baseline``)."""
        left = np.array([[self.f, 0.0, self.cu, 0.0], [0.0, self.f, self.cv, 0.0], [0.0, 0.0, 1.0, 0.0]])
        right = left.copy()
        right[0, 3] = -self.f * self.baseline
        return left, right

    @property
    def matrix(self) -> Array:
        """The 3x4 matrix M of eq. 3.1 with ``y = M [x, y, z, 1]^T / z``."""
        f, b = self.f, self.baseline
        return np.array([[f, 0.0, self.cu, 0.0], [0.0, f, self.cv, 0.0], [0.0, 0.0, 0.0, f * b]])

    def project(self, points: ArrayLike) -> Array:
        """``[u, v, d]`` of points (3,) or (N, 3) in the left camera frame; z must be positive."""
        p = np.asarray(points, dtype=float)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        inv_z = 1.0 / z
        return np.stack(
            [self.f * x * inv_z + self.cu, self.f * y * inv_z + self.cv, self.f * self.baseline * inv_z],
            axis=-1,
        )

    def triangulate(self, observations: ArrayLike) -> Array:
        """Points (3,) or (N, 3) from ``[u, v, d]`` observations; d must be positive."""
        y = np.asarray(observations, dtype=float)
        u, v, d = y[..., 0], y[..., 1], y[..., 2]
        scale = self.baseline / d
        return np.stack([scale * (u - self.cu), scale * (v - self.cv), scale * self.f], axis=-1)

    def project_jacobian(self, points: ArrayLike) -> Array:
        """d[u, v, d]/d[x, y, z]: (3, 3) for one point or (N, 3, 3) for a batch (eq. B.18)."""
        p = np.asarray(points, dtype=float)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        f, fb = self.f, self.f * self.baseline
        inv_z = 1.0 / z
        inv_z2 = inv_z * inv_z
        jac = np.zeros((*p.shape[:-1], 3, 3))
        jac[..., 0, 0] = f * inv_z
        jac[..., 0, 2] = -f * x * inv_z2
        jac[..., 1, 1] = f * inv_z
        jac[..., 1, 2] = -f * y * inv_z2
        jac[..., 2, 2] = -fb * inv_z2
        return jac

    def triangulate_jacobian(self, observations: ArrayLike) -> Array:
        """d[x, y, z]/d[u, v, d]: (3, 3) or (N, 3, 3), used to propagate pixel noise to points."""
        y = np.asarray(observations, dtype=float)
        u, v, d = y[..., 0], y[..., 1], y[..., 2]
        b = self.baseline
        jac = np.zeros((*y.shape[:-1], 3, 3))
        jac[..., 0, 0] = b / d
        jac[..., 0, 2] = -b * (u - self.cu) / d**2
        jac[..., 1, 1] = b / d
        jac[..., 1, 2] = -b * (v - self.cv) / d**2
        jac[..., 2, 2] = -b * self.f / d**2
        return jac
