"""Sun direction parametrisation (thesis eq. 5.7) in a camera optical frame (x right, y down, z fwd).

``zenith = acos(-s_y)`` in [0, pi]; ``azimuth = atan2(s_x, s_z)`` in (-pi, pi].
"""

from __future__ import annotations

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
