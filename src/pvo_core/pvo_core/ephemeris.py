"""Solar ephemeris (NREL SPA through pvlib) and the local East-North-Up frame of a GPS origin.

Frames: ENU is the local tangent frame at a geodetic origin (x east, y north, z up). Angles of the sun:
``elevation`` above the horizon and ``azimuth`` clockwise from north (the surveying convention SPA uses);
the direction vector is a unit vector from the observer towards the sun.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

# WGS-84
_A = 6378137.0
_F = 1.0 / 298.257223563
_E2 = _F * (2.0 - _F)


@dataclass(frozen=True)
class GeodeticOrigin:
    """Latitude and longitude in degrees, altitude in metres above the WGS-84 ellipsoid."""

    latitude: float
    longitude: float
    altitude: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.latitude) and -90.0 <= self.latitude <= 90.0):
            raise ValueError(f"latitude {self.latitude} is not in [-90, 90] degrees")
        if not (np.isfinite(self.longitude) and -180.0 <= self.longitude <= 360.0):
            raise ValueError(f"longitude {self.longitude} is not in [-180, 360] degrees")
        if not np.isfinite(self.altitude):
            raise ValueError(f"altitude {self.altitude} is not finite")


def geodetic_to_ecef(latitude: ArrayLike, longitude: ArrayLike, altitude: ArrayLike) -> Array:
    """ECEF coordinates (m), shape (..., 3), of WGS-84 geodetic points (degrees, metres)."""
    lat = np.radians(np.asarray(latitude, dtype=float))
    lon = np.radians(np.asarray(longitude, dtype=float))
    alt = np.asarray(altitude, dtype=float)
    n = _A / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
    return np.stack(
        [
            (n + alt) * np.cos(lat) * np.cos(lon),
            (n + alt) * np.cos(lat) * np.sin(lon),
            (n * (1.0 - _E2) + alt) * np.sin(lat),
        ],
        axis=-1,
    )


def enu_rotation(origin: GeodeticOrigin) -> Array:
    """3x3 rotation C_enu,ecef (rows: east, north, up at the origin, in ECEF)."""
    lat, lon = np.radians(origin.latitude), np.radians(origin.longitude)
    return np.array(
        [
            [-np.sin(lon), np.cos(lon), 0.0],
            [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
            [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
        ]
    )


def geodetic_to_enu(origin: GeodeticOrigin, latitude: ArrayLike, longitude: ArrayLike, altitude: ArrayLike) -> Array:
    """ENU coordinates (m), shape (..., 3), of geodetic points relative to ``origin``."""
    ecef = geodetic_to_ecef(latitude, longitude, altitude)
    ecef0 = geodetic_to_ecef(origin.latitude, origin.longitude, origin.altitude)
    return (ecef - ecef0) @ enu_rotation(origin).T


def sun_elevation_azimuth(origin: GeodeticOrigin, unix_time: ArrayLike) -> tuple[Array, Array]:
    """Apparent sun elevation and azimuth (degrees; azimuth clockwise from north) by NREL SPA.

    ``unix_time`` is seconds since 1970-01-01 UTC, scalar or array.
    """
    from pvlib import spa

    t = np.atleast_1d(np.asarray(unix_time, dtype=float))
    if not np.all(np.isfinite(t)):
        raise ValueError("sun ephemeris: time is not finite")
    # delta_t = TT - UT1 for 2008-2026, to within a second or two (irrelevant at the 1e-4 deg level).
    result = spa.solar_position(t, origin.latitude, origin.longitude, origin.altitude, 1013.25, 12.0, 69.0, 0.5667, numthreads=1)
    # result rows: theta (topocentric zenith), theta0, e (apparent elevation), e0, phi (azimuth) ...
    elevation = np.asarray(result[2], dtype=float)
    azimuth = np.asarray(result[4], dtype=float)
    return elevation, azimuth


def sun_direction_enu(origin: GeodeticOrigin, unix_time: ArrayLike) -> Array:
    """Unit vector(s) towards the sun in the ENU frame at ``origin``, shape (..., 3)."""
    elevation, azimuth = sun_elevation_azimuth(origin, unix_time)
    el, az = np.radians(elevation), np.radians(azimuth)
    direction = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    return direction if np.ndim(unix_time) else direction[0]


def ecef_to_geodetic(ecef: ArrayLike) -> Array:
    """WGS-84 latitude, longitude (degrees) and altitude (m), shape (..., 3), of ECEF points (Bowring)."""
    p = np.asarray(ecef, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    b = _A * (1.0 - _F)
    ep2 = (_A**2 - b**2) / b**2
    r = np.hypot(x, y)
    theta = np.arctan2(z * _A, r * b)
    lat = np.arctan2(z + ep2 * b * np.sin(theta) ** 3, r - _E2 * _A * np.cos(theta) ** 3)
    for _ in range(3):  # refine: Bowring's single step is already at the 1e-9 degree level on the ground
        n = _A / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
        alt = r / np.cos(lat) - n
        lat = np.arctan2(z, r * (1.0 - _E2 * n / (n + alt)))
    n = _A / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
    alt = r / np.cos(lat) - n
    return np.stack([np.degrees(lat), np.degrees(np.arctan2(y, x)), alt], axis=-1)


def enu_to_geodetic(origin: GeodeticOrigin, enu: ArrayLike) -> Array:
    """Latitude, longitude (degrees) and altitude (m) of ENU points (..., 3) relative to ``origin``."""
    ecef0 = geodetic_to_ecef(origin.latitude, origin.longitude, origin.altitude)
    ecef = ecef0 + np.asarray(enu, dtype=float) @ enu_rotation(origin)
    return ecef_to_geodetic(ecef)
