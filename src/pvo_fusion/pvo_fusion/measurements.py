"""Typed measurements the fusion graph consumes (ROS-free mirrors of the pvo_msgs messages).

Stamps are integer nanoseconds (exact, as in ``builtin_interfaces/Time``). Poses follow the
architecture contract: a :class:`RelativeMeasurement` holds **T_to,from** (maps coordinates in the
t_from camera frame to the t_to camera frame) with a 6x6 covariance in ROS order ``[rho; phi]`` of a
LEFT perturbation ``T = exp(xi^) T_hat``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pvo_core.covariance import is_positive_definite
from pvo_core.lie import is_rotation

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RelativeMeasurement:
    """T_to,from between the frames at ``reference_stamp`` (t_from) and ``stamp`` (t_to)."""

    stamp: int
    reference_stamp: int
    transform: Array
    covariance: Array
    rotation_only: bool = False


@dataclass(frozen=True)
class SunMeasurement:
    """Unit vector towards the sun in the camera frame at ``stamp``; 2x2 covariance over (zenith, azimuth), rad²."""

    stamp: int
    direction: Array
    covariance: Array


def relative_problem(m: RelativeMeasurement) -> str | None:
    """Why a relative measurement is unusable (a short reason key), or ``None`` when it is fine."""
    transform = np.asarray(m.transform, dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        return "non_finite_pose"
    if not is_rotation(transform[:3, :3], tol=1e-6):
        return "invalid_rotation"
    covariance = np.asarray(m.covariance, dtype=float)
    if covariance.shape != (6, 6) or not np.all(np.isfinite(covariance)):
        return "non_finite_covariance"
    block = covariance[3:, 3:] if m.rotation_only else covariance
    if not is_positive_definite(block):
        return "covariance_not_positive_definite"
    if m.stamp == m.reference_stamp:
        return "zero_interval"
    if m.reference_stamp > m.stamp:
        return "time_reversed"
    return None


def sun_problem(m: SunMeasurement) -> str | None:
    """Why a sun measurement is unusable (a short reason key), or ``None`` when it is fine."""
    direction = np.asarray(m.direction, dtype=float)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)):
        return "non_finite_direction"
    if abs(float(np.linalg.norm(direction)) - 1.0) > 1e-3:
        return "direction_not_unit"
    covariance = np.asarray(m.covariance, dtype=float)
    if covariance.shape != (2, 2) or not is_positive_definite(covariance):
        return "covariance_not_positive_definite"
    return None
