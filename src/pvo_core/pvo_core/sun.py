"""Sun direction parametrisation (thesis eq. 5.7) in a camera optical frame (x right, y down, z fwd).

``zenith = acos(-s_y)`` in [0, pi]; ``azimuth = atan2(s_x, s_z)`` in (-pi, pi].
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def unit_vector(vector: ArrayLike, what: str = "sun vector") -> Array:
    """The vector normalised to unit length; raises ValueError when it is zero or not finite."""
    v = np.asarray(vector, dtype=float)
    norm = float(np.linalg.norm(v, axis=-1).min()) if v.ndim > 1 else float(np.linalg.norm(v))
    if not np.all(np.isfinite(v)) or norm < 1e-12:
        raise ValueError(f"{what} {v.tolist()} is zero or not finite")
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def vector_to_zenith_azimuth(vector: ArrayLike) -> tuple[Array, Array]:
    """Zenith and azimuth (rad) of unit vector(s) (3,) or (N, 3) (normalised first).

    The zenith is ``acos(-s_y)`` computed as ``atan2(hypot(s_x, s_z), -s_y)``: exact to round-off near
    0 and pi, where acos loses half the digits (the sun factor differentiates it there).
    """
    return unit_zenith_azimuth(unit_vector(vector))


def unit_zenith_azimuth(s: Array) -> tuple[Array, Array]:
    """:func:`vector_to_zenith_azimuth` for vectors known to be unit and finite (no checks: hot paths)."""
    return np.arctan2(np.hypot(s[..., 0], s[..., 2]), -s[..., 1]), np.arctan2(s[..., 0], s[..., 2])


def zenith_azimuth_to_vector(zenith: ArrayLike, azimuth: ArrayLike) -> Array:
    """Unit vector(s) from zenith and azimuth (rad), inverse of :func:`vector_to_zenith_azimuth`."""
    zen = np.asarray(zenith, dtype=float)
    azi = np.asarray(azimuth, dtype=float)
    sin_zen = np.sin(zen)
    return np.stack([sin_zen * np.sin(azi), -np.cos(zen), sin_zen * np.cos(azi)], axis=-1)


def wrap_angle(angle: ArrayLike) -> Array:
    """Angles (rad) wrapped to (-pi, pi]."""
    return -np.mod(-np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) + np.pi


def sample_mean_and_covariance(samples: ArrayLike, tau: float = np.inf) -> tuple[Array, Array]:
    """Sun-BCNN's MC estimates (thesis §5.3) from stochastic samples (S, N, 3) of unit vectors.

    Method I: the mean direction is the normalised mean of the sample vectors, (N, 3). Method II: the
    covariance (N, 2, 2) over (zenith, azimuth) of the samples' angles about the mean's (azimuth wrapped),
    plus tau^-1 I (the model precision of the MC-dropout variance; ``inf`` adds nothing)."""
    draws = np.asarray(samples, dtype=float)
    if draws.ndim != 3 or draws.shape[2] != 3 or draws.shape[0] < 2:
        raise ValueError(f"samples must be (S >= 2, N, 3), got {draws.shape}")
    mean = draws.mean(axis=0)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    zenith, azimuth = unit_zenith_azimuth(draws / np.linalg.norm(draws, axis=2, keepdims=True))
    mean_zenith, mean_azimuth = unit_zenith_azimuth(mean)
    deviations = np.stack([zenith - mean_zenith, wrap_angle(azimuth - mean_azimuth)], axis=2)  # (S, N, 2)
    covariance = np.einsum("sni,snj->nij", deviations, deviations) / (draws.shape[0] - 1)
    if np.isfinite(tau):
        covariance = covariance + np.eye(2) / tau
    return mean, covariance


def angle_mean(samples: ArrayLike) -> Array:
    """The thesis's Method II mean (§5.9.3): the arithmetic mean of the samples' zenith and azimuth angles
    (S, N, 3) -> (N, 3) unit vectors. As the text has it, the azimuths are averaged as numbers: samples on
    both sides of the +-pi cut average to the wrong side (one reason Method I wins in Table 5.7)."""
    draws = np.asarray(samples, dtype=float)
    zenith, azimuth = unit_zenith_azimuth(draws / np.linalg.norm(draws, axis=2, keepdims=True))
    return zenith_azimuth_to_vector(zenith.mean(axis=0), azimuth.mean(axis=0))


def zenith_azimuth_jacobian(vectors: ArrayLike) -> Array:
    """d(zenith, azimuth)/ds (N, 2, 3) at unit vectors (N, 3) of eq. 5.7 (zenith = atan2(hypot(sx, sz), -sy),
    azimuth = atan2(sx, sz))."""
    s = np.asarray(vectors, dtype=float)
    sx, sy, sz = s[:, 0], s[:, 1], s[:, 2]
    r2 = np.maximum(sx**2 + sz**2, 1e-12)
    r = np.sqrt(r2)
    rho2 = r2 + sy**2
    jacobian = np.zeros((len(s), 2, 3))
    jacobian[:, 0] = np.stack([-sy * sx / (r * rho2), r / rho2, -sy * sz / (r * rho2)], axis=1)
    jacobian[:, 1] = np.stack([sz / r2, np.zeros_like(sx), -sx / r2], axis=1)
    return jacobian


def vector_covariance_in_angles(samples: ArrayLike, mean: ArrayLike) -> Array:
    """The thesis's Method I covariance (§5.9.4): the 3x3 sample covariance of the unit vectors (S, N, 3),
    propagated to (zenith, azimuth) through eq. 5.7 linearised at ``mean`` (N, 3) -> (N, 2, 2) rad²."""
    draws = np.asarray(samples, dtype=float)
    deviations = draws - draws.mean(axis=0)
    covariance3 = np.einsum("sni,snj->nij", deviations, deviations) / (draws.shape[0] - 1)
    jacobian = zenith_azimuth_jacobian(np.asarray(mean, dtype=float))
    return np.einsum("nij,njk,nlk->nil", jacobian, covariance3, jacobian)


def aleatoric_covariance(mean: ArrayLike, inverse_concentration: ArrayLike) -> Array:
    """(N, 2, 2) covariance over (zenith, azimuth) in rad² of a von Mises-Fisher spread about unit vectors
    ``mean`` (N, 3) with 1/kappa ``inverse_concentration`` (N,): for a concentrated vMF the angular deviation
    along each tangent direction has variance 1/kappa; an azimuth step moves the vector by sin(zenith) times
    as much, so its variance is 1/(kappa sin² zenith) (capped near the poles, where azimuth is undefined)."""
    m = np.asarray(mean, dtype=float)
    variance = np.asarray(inverse_concentration, dtype=float)
    zenith, _ = unit_zenith_azimuth(m)
    sin2 = np.maximum(np.sin(zenith) ** 2, 1e-3)
    covariance = np.zeros((len(m), 2, 2))
    covariance[:, 0, 0] = variance
    covariance[:, 1, 1] = variance / sin2
    return covariance


def angular_errors(predicted: ArrayLike, truth: ArrayLike) -> dict[str, Array]:
    """Per-vector errors (rad) of predicted against true unit vectors (N, 3): the angle between them, and the
    absolute zenith and (wrapped) azimuth differences."""
    p = np.asarray(predicted, dtype=float)
    t = np.asarray(truth, dtype=float)
    p = p / np.linalg.norm(p, axis=1, keepdims=True)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    pz, pa = unit_zenith_azimuth(p)
    tz, ta = unit_zenith_azimuth(t)
    angle = np.arctan2(np.linalg.norm(np.cross(p, t), axis=1), np.sum(p * t, axis=1))
    return {"vector": angle, "zenith": np.abs(pz - tz), "azimuth": np.abs(wrap_angle(pa - ta))}


def zenith_azimuth_residuals(predicted: ArrayLike, truth: ArrayLike) -> Array:
    """(N, 2) residuals predicted - true over (zenith, azimuth) of unit vectors (N, 3), azimuth wrapped."""
    pz, pa = unit_zenith_azimuth(np.asarray(predicted, dtype=float))
    tz, ta = unit_zenith_azimuth(np.asarray(truth, dtype=float))
    return np.column_stack([pz - tz, wrap_angle(pa - ta)])


def anees(residuals: ArrayLike, covariances: ArrayLike) -> float:
    """The average normalised estimation error squared of residuals (N, 2) under covariances (N, 2, 2), over
    the two dimensions: 1 when the covariances state the spread the residuals have."""
    r = np.asarray(residuals, dtype=float)
    c = np.asarray(covariances, dtype=float)
    return float(np.mean(np.einsum("ni,nij,nj->n", r, np.linalg.inv(c), r)) / 2.0)


@dataclass(frozen=True)
class CovarianceCalibration:
    """How a sun model's own covariance over (zenith, azimuth) in rad² becomes the stated one:
    Sigma = scale * Sigma_model + tau^-1 I. tau is the thesis's model precision (Method II), which widens an
    overconfident model; scale (<= 1) narrows one whose covariance is too wide, which tau cannot."""

    tau: float = float("inf")
    scale: float = 1.0

    def __post_init__(self) -> None:
        if not (self.tau > 0.0):  # also rejects NaN
            raise ValueError(f"covariance calibration: tau must be positive (inf for none), got {self.tau}")
        if not (np.isfinite(self.scale) and self.scale > 0.0):
            raise ValueError(f"covariance calibration: scale must be positive and finite, got {self.scale}")

    @classmethod
    def from_mapping(cls, figures: Mapping[str, object]) -> CovarianceCalibration:
        """From a model card's ``calibration`` block (``tau`` and ``scale``; absent: none); ``ValueError``
        naming the field that is not a number."""
        values = {}
        for name, default in (("tau", np.inf), ("scale", 1.0)):
            value = figures.get(name, default)
            try:
                values[name] = float(value)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                raise ValueError(f"covariance calibration: {name} must be a number, got {value!r}") from None
        return cls(**values)

    def apply(self, covariances: ArrayLike) -> Array:
        """The stated covariances (N, 2, 2) from the model's own (N, 2, 2)."""
        stated = self.scale * np.asarray(covariances, dtype=float)
        return stated if np.isinf(self.tau) else stated + np.eye(2) / self.tau


#: no calibration: the model's own covariance as it is
UNCALIBRATED = CovarianceCalibration()


def calibrate_scale(residuals: ArrayLike, covariances: ArrayLike, keep: ArrayLike) -> float:
    """The scale (<= 1) of :class:`CovarianceCalibration` for covariances (N, 2, 2) too wide for the residuals
    (N, 2): the ANEES scales as 1/scale, so the scale sqrt(ANEES_kept * ANEES_all) puts the ANEES over the rows
    where ``keep`` (the thesis's cosine-distance filter) and over all rows symmetrically about 1 (their
    geometric mean becomes 1): both are reported, and an online consumer sees every row. 1 when the
    covariances are not too wide by that measure (tau widens those)."""
    r = np.asarray(residuals, dtype=float)
    c = np.asarray(covariances, dtype=float)
    kept = np.asarray(keep, dtype=bool)
    if not kept.any():
        raise ValueError("no residual to calibrate the covariance scale on")
    return float(min(1.0, np.sqrt(anees(r[kept], c[kept]) * anees(r, c))))


def calibrate_tau(residuals: ArrayLike, covariances: ArrayLike, keep: ArrayLike | None = None, target: float = 1.0) -> float:
    """The model precision tau of Method II: the covariances (N, 2, 2) plus tau^-1 I give an ANEES of
    ``target`` over the residuals (N, 2) (rows where ``keep``; the thesis's code kept cosine distances < 0.3).
    Returns inf when the covariances alone are already wide enough (ANEES <= target)."""
    r = np.asarray(residuals, dtype=float)
    c = np.asarray(covariances, dtype=float)
    if keep is not None:
        r, c = r[np.asarray(keep, dtype=bool)], c[np.asarray(keep, dtype=bool)]
    if len(r) == 0:
        raise ValueError("no residual to calibrate tau on")

    def widened_anees(inverse_tau: float) -> float:
        return anees(r, c + inverse_tau * np.eye(2))

    floor = 1e-12
    if widened_anees(floor) <= target:
        return float("inf")
    low, high = floor, 1.0
    while widened_anees(high) > target:  # widen until the ANEES falls below the target
        high *= 10.0
        if high > 1e6:
            raise ValueError("residuals too large to calibrate tau")
    for _ in range(200):  # bisection in log space: the ANEES falls monotonically as tau^-1 grows
        middle = np.sqrt(low * high)
        low, high = (middle, high) if widened_anees(middle) > target else (low, middle)
    return float(1.0 / np.sqrt(low * high))
