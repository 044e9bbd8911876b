"""Covariance conversion between ROS messages and GTSAM's Pose3.

ROS (``PoseWithCovariance.covariance``, ``pvo_msgs/RelativePose``): row-major 6x6 in the order
``(x, y, z, rotX, rotY, rotZ)`` = ``[rho; phi]``, of a LEFT perturbation ``T = exp(xi^) T_hat``.

GTSAM (``Pose3`` noise models, marginals): order ``[omega; v]`` (rotation first), of a RIGHT
perturbation ``T = T_hat Exp(xi_r)``. The two perturbations are related by the adjoint:
``xi = Ad(T_hat) xi_r``, so ``Sigma_r = Ad(T_hat)^-1 Sigma Ad(T_hat)^-T``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .lie import se3_adjoint, se3_inverse

Array = NDArray[np.float64]

#: Permutation between [rho; phi] and [phi; rho] (its own inverse).
SWAP_BLOCKS = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])


def _as_6x6(covariance: ArrayLike) -> Array:
    cov = np.asarray(covariance, dtype=float)
    if cov.size != 36:
        raise ValueError(f"a pose covariance needs 36 numbers, got {cov.size}")
    return cov.reshape(6, 6)


def ros_to_gtsam_covariance(covariance: ArrayLike, pose: ArrayLike | None = None) -> Array:
    """GTSAM Pose3 covariance (6x6, [omega; v], right perturbation) from a ROS one.

    Args:
        covariance: 36 numbers or 6x6, ROS order, left perturbation.
        pose: the 4x4 estimate the perturbation acts on. ``None`` skips the perturbation-side
            change (only correct when the pose is the identity).
    """
    cov = _as_6x6(covariance)
    if pose is not None:
        ad_inv = se3_adjoint(se3_inverse(pose))
        cov = ad_inv @ cov @ ad_inv.T
    return SWAP_BLOCKS @ cov @ SWAP_BLOCKS.T


def gtsam_to_ros_covariance(covariance: ArrayLike, pose: ArrayLike | None = None) -> Array:
    """Inverse of :func:`ros_to_gtsam_covariance`: a 6x6 ROS-order, left-perturbation covariance."""
    cov = SWAP_BLOCKS @ _as_6x6(covariance) @ SWAP_BLOCKS.T
    if pose is not None:
        ad = se3_adjoint(pose)
        cov = ad @ cov @ ad.T
    return cov


def is_positive_definite(covariance: ArrayLike) -> bool:
    """True when the matrix is finite, symmetric (to 1e-9 relative) and positive definite."""
    cov = np.asarray(covariance, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        return False
    scale = float(np.abs(cov).max())
    if not np.isfinite(scale):
        return False
    if float(np.abs(cov - cov.T).max()) > 1e-9 * max(scale, 1e-300):
        return False
    try:
        np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        return False
    return True
