"""Maximum-likelihood frame-to-frame motion: robust Gauss-Newton (IRLS) on stereo reprojection error.

Thesis eq. 3.11 and app. B: for features observed as ``y = [u, v, d]`` in the reference frame
(t-1) and the current frame (t), the residual of feature i is

    e_i(T) = f(T p_i) - y_i,cur,      p_i = f^-1(y_i,ref)          (current-camera pixels)

with ``T = T_cur,ref`` and left perturbations ``T <- exp(dxi^) T`` (dxi = [rho; phi]), so that
``de_i/dxi = J_p(T p_i) (T p_i)^odot`` (eqs. B.16-B.19). Each feature has a 3x3 covariance Sigma_i;
the robust loss acts on the whitened norm eps_i = sqrt(e_i^T Sigma_i^-1 e_i) (eqs. 3.17-3.20), solved
by IRLS with weights w_i = rho'(eps_i) / eps_i. The frame covariance is (sum J^T w Sigma^-1 J)^-1
(eq. 7.20), in [rho; phi] order for the same left perturbation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.lie import odot, se3_exp

Array = NDArray[np.float64]

#: Dimension of one stereo observation (u, v, d): the Student-t loss's d.
OBSERVATION_DIM = 3


class RobustLoss:
    """An M-estimator rho(eps) on the whitened residual norm, with its IRLS weight rho'(eps)/eps.

    ``scale`` is the loss constant (Huber/Cauchy/Geman-McClure k in whitened units, Student-t nu);
    it may be a scalar or one value per feature (PROBE predicts them).
    """

    def __init__(self, name: str, scale: float | Array = 1.0) -> None:
        if name not in ("l2", "huber", "cauchy", "geman_mcclure", "student_t"):
            raise ValueError(f"unknown robust loss {name!r}")
        scale_arr = np.asarray(scale, dtype=float)
        if np.any(~np.isfinite(scale_arr)) or np.any(scale_arr <= 0.0):
            raise ValueError(f"robust loss {name} needs positive finite scale(s)")
        self.name = name
        self.scale = scale_arr

    def rho(self, eps: Array) -> Array:
        k = self.scale
        e2 = eps * eps
        if self.name == "l2":
            return 0.5 * e2
        if self.name == "huber":
            return np.where(eps <= k, 0.5 * e2, k * eps - 0.5 * k * k)
        if self.name == "cauchy":
            return 0.5 * k * k * np.log1p(e2 / (k * k))
        if self.name == "geman_mcclure":
            return 0.5 * k * k * e2 / (k * k + e2)
        return 0.5 * (k + OBSERVATION_DIM) * np.log1p(e2 / k)

    def weight(self, eps: Array) -> Array:
        k = self.scale
        e2 = eps * eps
        if self.name == "l2":
            return np.ones_like(eps)
        if self.name == "huber":
            return np.where(eps <= k, 1.0, k / np.maximum(eps, 1e-300))
        if self.name == "cauchy":
            return 1.0 / (1.0 + e2 / (k * k))
        if self.name == "geman_mcclure":
            return k**4 / (k * k + e2) ** 2
        return (k + OBSERVATION_DIM) / (k + e2)


@dataclass(frozen=True)
class SolveResult:
    """Outcome of :func:`solve_motion`.

    transform: T_cur,ref (4, 4). covariance: (6, 6) over [rho; phi] of a left perturbation.
    eps: whitened residual norms at the solution (N,). weights: IRLS weights (N,).
    cost: final robust cost; iterations: GN iterations run; condition: condition number of the
    normal matrix (large = degenerate geometry).
    """

    transform: Array
    covariance: Array
    eps: Array
    weights: Array
    cost: float
    iterations: int
    condition: float


def residuals_and_jacobians(camera: StereoCamera, transform: Array, points_ref: Array, obs_cur: Array) -> tuple[Array, Array]:
    """Residuals f(T p) - y (N, 3) and their Jacobians w.r.t. a left perturbation of T (N, 3, 6)."""
    q = points_ref @ transform[:3, :3].T + transform[:3, 3]
    residual = camera.project(q) - obs_cur
    jac = camera.project_jacobian(q) @ odot(q)
    return residual, jac


def feature_information(
    camera: StereoCamera,
    transform: Array,
    obs_ref: Array,
    cov_cur: Array,
    cov_ref: Array | None,
) -> Array:
    """Per-feature inverse covariances (N, 3, 3) of the residual e_i.

    ``cov_cur`` / ``cov_ref`` are (N, 3, 3) pixel covariances of the current and reference
    observations. With ``cov_ref`` the reference noise is carried through triangulation and the motion:
    Sigma_i = R_cur + G R_ref G^T with G = J_p(T p) C J_tri(y_ref).
    """
    cov = cov_cur
    if cov_ref is not None:
        points = camera.triangulate(obs_ref)
        q = points @ transform[:3, :3].T + transform[:3, 3]
        g = camera.project_jacobian(q) @ transform[:3, :3] @ camera.triangulate_jacobian(obs_ref)
        cov = cov_cur + g @ cov_ref @ np.swapaxes(g, 1, 2)
    return np.linalg.inv(cov)


def quadratic_form(residual: Array, information: Array) -> Array:
    """e^T W e for residuals (..., N, 3) and symmetric W (N, 3, 3), written out (faster than einsum)."""
    r0, r1, r2 = residual[..., 0], residual[..., 1], residual[..., 2]
    w = information
    return (
        w[:, 0, 0] * r0 * r0
        + w[:, 1, 1] * r1 * r1
        + w[:, 2, 2] * r2 * r2
        + 2.0 * (w[:, 0, 1] * r0 * r1 + w[:, 0, 2] * r0 * r2 + w[:, 1, 2] * r1 * r2)
    )


def whitened_norms(residual: Array, information: Array) -> Array:
    """eps_i = sqrt(e_i^T Sigma_i^-1 e_i), shape (N,)."""
    return np.sqrt(np.maximum(quadratic_form(residual, information), 0.0))


def normal_equations(jac: Array, weighted_information: Array, residual: Array) -> tuple[Array, Array]:
    """H = sum J^T M J (6, 6) and g = sum J^T M e (6,) for per-feature M (N, 3, 3)."""
    mj = (weighted_information @ jac).reshape(-1, 6)  # (3N, 6)
    flat_j = jac.reshape(-1, 6)
    return flat_j.T @ mj, mj.T @ residual.reshape(-1)


def solve_motion(
    camera: StereoCamera,
    points_ref: Array,
    obs_cur: Array,
    information: Array,
    loss: RobustLoss,
    initial: Array,
    max_iterations: int = 20,
    relative_cost_tolerance: float = 0.01,
    min_update_norm: float = 1e-10,
) -> SolveResult:
    """Gauss-Newton / IRLS for T_cur,ref from points (N, 3) in the reference frame.

    Stops when the relative cost change is below ``relative_cost_tolerance`` (after at least one
    step), the update norm is below ``min_update_norm``, or after ``max_iterations``. A step that
    increases the cost is halved up to 10 times (backtracking) so IRLS never diverges.
    """
    transform = np.array(initial, dtype=float)

    def evaluate(t: Array) -> tuple[Array, Array, Array, float]:
        r, j = residuals_and_jacobians(camera, t, points_ref, obs_cur)
        eps = whitened_norms(r, information)
        return r, j, eps, float(np.sum(loss.rho(eps)))

    residual, jac, eps, cost = evaluate(transform)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
        w = loss.weight(eps)
        hessian, gradient = normal_equations(jac, w[:, None, None] * information, residual)
        try:
            step = -np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            break
        scale = 1.0
        for _ in range(10):
            candidate = se3_exp(scale * step) @ transform
            r_new, j_new, eps_new, cost_new = evaluate(candidate)
            if cost_new <= cost or not np.isfinite(cost):
                break
            scale *= 0.5
        else:
            break
        previous = cost
        transform, residual, jac, eps, cost = candidate, r_new, j_new, eps_new, cost_new
        if np.linalg.norm(scale * step) < min_update_norm:
            break
        if previous > 0.0 and (previous - cost) / previous < relative_cost_tolerance:
            break
    w = loss.weight(eps)
    hessian, _ = normal_equations(jac, w[:, None, None] * information, residual)
    eigenvalues = np.linalg.eigvalsh(0.5 * (hessian + hessian.T))
    condition = float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0.0 else float("inf")
    try:
        covariance = np.linalg.inv(hessian)
        covariance = 0.5 * (covariance + covariance.T)
    except np.linalg.LinAlgError:
        covariance = np.full((6, 6), np.nan)
    return SolveResult(transform, covariance, eps, w, cost, iterations, condition)
