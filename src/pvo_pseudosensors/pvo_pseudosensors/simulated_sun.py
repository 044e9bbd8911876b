"""A simulated sun sensor: ground-truth sun directions corrupted to a chosen mean angular error.

Thesis §5.8.2 (GT-Sun-0/10/20/30): zero-mean Gaussian noise with a given *mean angular distance* from
the truth. The truth is rotated by a random angle about a random axis perpendicular to it; the
tangent-plane noise is isotropic with per-axis standard deviation ``sigma``, so the angular distance
is Rayleigh distributed with mean ``sigma * sqrt(pi / 2)``. The reported covariance over
(zenith, azimuth) (thesis eq. 5.7) is the first-order image of that noise:
``diag(sigma^2, sigma^2 / sin^2(zenith))``, with ``sigma`` no smaller than the floor so that an exact
(0 deg) sensor still carries a usable covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

RAYLEIGH_MEAN = float(np.sqrt(np.pi / 2.0))


@dataclass(frozen=True)
class SimulatedSunConfig:
    """``mean_error_deg``: mean angular distance from the truth; one measurement every ``every_n`` inputs."""

    mean_error_deg: float = 10.0
    every_n: int = 10
    covariance_floor_deg: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (0.0 <= self.mean_error_deg < 90.0):
            raise ValueError(f"invalid simulated sun configuration: mean_error_deg must be in [0, 90), got {self.mean_error_deg}")
        if self.every_n < 1:
            raise ValueError(f"invalid simulated sun configuration: every_n must be >= 1, got {self.every_n}")
        if self.covariance_floor_deg <= 0.0:
            raise ValueError("invalid simulated sun configuration: covariance_floor_deg must be positive")


def zenith_azimuth_covariance(direction: Array, sigma: float) -> Array:
    """2x2 (zenith, azimuth) covariance (rad²) of isotropic tangent noise ``sigma`` (rad) at ``direction``."""
    sin_zenith = float(np.hypot(direction[0], direction[2]))
    # At the camera's zenith the azimuth is undefined: cap its variance at a full turn.
    azimuth_variance = min(sigma**2 / max(sin_zenith, 1e-12) ** 2, np.pi**2)
    return np.diag([sigma**2, azimuth_variance])


def perturb_direction(direction: Array, angle_sigma: float, rng: np.random.Generator) -> Array:
    """``direction`` rotated by isotropic tangent-plane noise of per-axis std ``angle_sigma`` (rad)."""
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    a = np.cross(d, helper)
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    w = rng.normal(0.0, angle_sigma, 2) if angle_sigma > 0.0 else np.zeros(2)
    axis = w[0] * a + w[1] * b
    angle = float(np.linalg.norm(axis))
    if angle < 1e-15:
        return d.copy()
    k = axis / angle
    # Rodrigues; k is perpendicular to d, so the result is exactly `angle` away from d.
    return d * np.cos(angle) + np.cross(k, d) * np.sin(angle)


class SimulatedSunSensor:
    """Feed every ground-truth direction to :meth:`measure`; every N-th returns a noisy measurement."""

    def __init__(self, config: SimulatedSunConfig | None = None) -> None:
        self.config = config or SimulatedSunConfig()
        self.sigma = np.radians(self.config.mean_error_deg) / RAYLEIGH_MEAN
        self.covariance_sigma = max(self.sigma, np.radians(self.config.covariance_floor_deg) / RAYLEIGH_MEAN)
        self._rng = np.random.default_rng(self.config.seed)
        self._inputs = 0

    def measure(self, truth: ArrayLike) -> tuple[Array, Array] | None:
        """(unit direction, 2x2 zenith/azimuth covariance) for every N-th input (the first included), else None.

        Raises ``ValueError`` for a zero or non-finite truth vector (the input is then not counted).
        """
        d = np.asarray(truth, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"ground-truth sun direction {d.tolist()} is not a finite non-zero 3-vector")
        index = self._inputs
        self._inputs += 1
        if index % self.config.every_n != 0:
            return None
        measured = perturb_direction(d / np.linalg.norm(d), self.sigma, self._rng)
        return measured, zenith_azimuth_covariance(measured, self.covariance_sigma)
