"""HydraNet's figures against the truth (numpy, no torch): angular error, NLL (eq. 7.17) and ANEES of relative
rotation estimates with their covariance."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pvo_core.lie import quaternion_to_rotation, so3_log

Array = NDArray[np.float64]


def true_relative_rotations(poses: ArrayLike, earlier: ArrayLike, later: ArrayLike) -> Array:
    """(N, 3, 3) C_later,earlier from camera-to-world poses (M, 4, 4) and frame numbers (N,) each."""
    poses = np.asarray(poses, dtype=float)
    earlier, later = np.asarray(earlier, dtype=int), np.asarray(later, dtype=int)
    return poses[later, :3, :3].transpose(0, 2, 1) @ poses[earlier, :3, :3]


def rotation_errors(estimates: ArrayLike, truth: ArrayLike) -> Array:
    """(N, 3) left-tangent errors phi = Log(C_true C_est^T) (rad): C_true = Exp(phi) C_est, the perturbation
    the covariance describes."""
    estimates, truth = np.asarray(estimates, dtype=float), np.asarray(truth, dtype=float)
    return np.stack([so3_log(t @ e.T) for e, t in zip(estimates, truth, strict=True)])


def angular_errors_deg(estimates: ArrayLike, truth: ArrayLike) -> Array:
    """(N,) angles (deg) between estimated and true rotations (N, 3, 3)."""
    return np.degrees(np.linalg.norm(rotation_errors(estimates, truth), axis=1))


def evaluate_rotations(quaternions: ArrayLike, covariances: ArrayLike, truth: ArrayLike) -> dict[str, float]:
    """Figures of estimates (N, 4) (w, x, y, z) with covariances (N, 3, 3) against true rotations (N, 3, 3):
    mean / median / RMS angular error (deg), mean NLL (eq. 7.17 without its constant: 1/2 NEES + 1/2 log det),
    ANEES (mean NEES / 3; 1 when the covariance is consistent) and the mean covariance trace (rad²)."""
    estimates = np.stack([quaternion_to_rotation(q) for q in np.asarray(quaternions, dtype=float)])
    covariances = np.asarray(covariances, dtype=float)
    errors = rotation_errors(estimates, truth)
    angles = np.degrees(np.linalg.norm(errors, axis=1))
    nees = np.einsum("ni,ni->n", errors, np.linalg.solve(covariances, errors[..., None])[..., 0])
    _, log_det = np.linalg.slogdet(covariances)
    return {
        "pairs": float(len(errors)),
        "angle_mean_deg": float(angles.mean()),
        "angle_median_deg": float(np.median(angles)),
        "angle_rms_deg": float(np.sqrt(np.mean(angles**2))),
        "nll": float(np.mean(0.5 * nees + 0.5 * log_det)),
        "anees": float(nees.mean() / 3.0),
        "covariance_trace": float(np.trace(covariances, axis1=1, axis2=2).mean()),
    }
