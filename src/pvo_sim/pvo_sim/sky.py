"""A sky whose brightness follows the sun: the CIE standard skies, composited where the render saw no geometry.

The default sky of :mod:`.world` is one gradient for every sun, so the only sun cues in a render are shading and
shadows. A real sky is brightest around the sun (the circumsolar glow) and towards the horizon, darker at right
angles to the sun: a camera that sees sky sees where the sun is. This module gives that sky's relative luminance
per viewing direction (the CIE general sky, ISO 15469: the standard clear sky for a sunny render, the standard
overcast sky, which has no sun, for an overcast one) and its grey or RGB value in [0, 1] as the renderer writes
it; :mod:`.render` draws the geometry against a key colour and replaces the key with this sky.

Frames: every direction is a unit 3-vector in one frame (the renderer uses the camera's optical frame: x right,
y down, z forward), ``up`` the local vertical and ``sun`` the direction to the sun in the same frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

SKIES = ("gradient", "sun")
#: The colour the world's skybox is drawn in when the sky is composited (``sky: sun``): no lit surface of the
#: procedural worlds renders pure magenta.
KEY_RGB = (255, 0, 255)
#: CIE standard clear sky (ISO 15469 type 12: "standard clear sky, low illuminance turbidity"): gradation a, b
#: and scattering indicatrix c, d, e.
CLEAR_SKY = (-1.0, -0.32, 10.0, -3.0, 0.45)
#: Pixel value of the zenith of a clear sky, as a fraction of full scale, and the exponent that compresses
#: luminance to pixel values (a camera's response, close to 1/2.2): the zenith renders darker than a sunlit wall, the horizon
#: brighter, the circumsolar sky saturates, as in KITTI's images.
CLEAR_ZENITH_VALUE = 0.35
OVERCAST_ZENITH_VALUE = 0.95
RESPONSE_EXPONENT = 0.45
#: A clear sky's blue, normalised so that its BT.601 grey is the luminance value (saturates towards white).
CLEAR_TINT = np.array([0.80, 0.89, 1.0]) / (0.299 * 0.80 + 0.587 * 0.89 + 0.114 * 1.0)
OVERCAST_TINT = np.array([0.97, 0.98, 1.0]) / (0.299 * 0.97 + 0.587 * 0.98 + 0.114 * 1.0)
#: Degrees of solar depression per tenfold fall of the sky's luminance in twilight (a clear sky's zenith dims by
#: roughly four to five orders of magnitude between sunset and the end of nautical twilight, 12 deg below).
TWILIGHT_DEG_PER_DECADE = 3.0


def _gradation(cos_zenith: Array) -> Array:
    a, b = CLEAR_SKY[0], CLEAR_SKY[1]
    # at and below the horizon the gradation is its horizon value (the sky a camera sees below the horizon is
    # the ground's far edge, where the renderer's ground ends)
    return 1.0 + a * np.exp(b / np.maximum(cos_zenith, 1e-3))


def _indicatrix(angle_to_sun: Array) -> Array:
    c, d, e = CLEAR_SKY[2], CLEAR_SKY[3], CLEAR_SKY[4]
    return 1.0 + c * (np.exp(d * angle_to_sun) - np.exp(d * np.pi / 2.0)) + e * np.cos(angle_to_sun) ** 2


def clear_sky_luminance(rays: Array, up: Array, sun: Array) -> Array:
    """Luminance of the CIE standard clear sky relative to its zenith, (...,) for unit ``rays`` (..., 3); ``up``
    and ``sun`` unit 3-vectors in the rays' frame. The sun may be below the horizon only in name (the renders
    refuse a sun that is); its zenith angle is clipped to 90 deg."""
    rays = np.asarray(rays, dtype=np.float64)
    up, sun = np.asarray(up, dtype=np.float64), np.asarray(sun, dtype=np.float64)
    cos_zenith = rays @ up
    angle = np.arccos(np.clip(rays @ sun, -1.0, 1.0))
    sun_zenith = float(np.arccos(np.clip(sun @ up, 0.0, 1.0)))
    zenith_luminance = _indicatrix(np.asarray(sun_zenith)) * _gradation(np.asarray(1.0))
    return _indicatrix(angle) * _gradation(cos_zenith) / zenith_luminance


def overcast_sky_luminance(rays: Array, up: Array) -> Array:
    """Luminance of the CIE standard overcast sky relative to its zenith, (1 + 2 cos Z) / 3, (...,): no sun."""
    cos_zenith = np.clip(np.asarray(rays, dtype=np.float64) @ np.asarray(up, dtype=np.float64), 0.0, 1.0)
    return (1.0 + 2.0 * cos_zenith) / 3.0


def twilight_factor(up: Array, sun: Array) -> float:
    """The sky's luminance relative to a sun on the horizon: 1 while the sun is up, a tenfold fall every
    :data:`TWILIGHT_DEG_PER_DECADE` deg it sinks below (a render with ``--night``: a dark sky, not a day's)."""
    elevation = float(
        np.degrees(np.arcsin(np.clip(np.asarray(sun, dtype=np.float64) @ np.asarray(up, dtype=np.float64), -1.0, 1.0)))
    )
    return 1.0 if elevation >= 0.0 else 10.0 ** (elevation / TWILIGHT_DEG_PER_DECADE)


def sky_values(rays: Array, up: Array, sun: Array, overcast: bool, colour: bool) -> Array:
    """The sky's pixel values in [0, 1] for unit ``rays`` (..., 3): grey (...,) or RGB (..., 3) when ``colour``;
    a sun below the horizon dims either sky by :func:`twilight_factor`."""
    dimming = twilight_factor(up, sun)
    if overcast:
        value = OVERCAST_ZENITH_VALUE * (dimming * overcast_sky_luminance(rays, up)) ** 0.25
        tint = OVERCAST_TINT
    else:
        value = CLEAR_ZENITH_VALUE * (dimming * clear_sky_luminance(rays, up, sun)) ** RESPONSE_EXPONENT
        tint = CLEAR_TINT
    if not colour:
        return np.clip(value, 0.0, 1.0)
    return np.clip(value[..., None] * tint, 0.0, 1.0)


def pixel_rays(width: int, height: int, focal: float) -> Array:
    """Unit rays (height, width, 3) through the pixel centres of a pinhole camera whose principal point is the
    image centre ((W - 1) / 2, (H - 1) / 2: MuJoCo's symmetric frustum), in its optical frame."""
    u = (np.arange(width, dtype=np.float64) - (width - 1) / 2.0) / focal
    v = (np.arange(height, dtype=np.float64) - (height - 1) / 2.0) / focal
    rays = np.stack(np.broadcast_arrays(u[None, :], v[:, None], np.ones((height, width))), axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def composite_sky(rgb: NDArray[np.uint8], sky: Array, scale: int = 1) -> NDArray[np.uint8]:
    """A render ``rgb`` (H * scale, W * scale, 3) with its :data:`KEY_RGB` pixels replaced by ``sky`` (H, W, 3),
    the sky's values in [0, 1] at the output size, and averaged down to (H, W, 3) over scale x scale blocks
    (the renderer's supersampling). A block the geometry only partly covers gets the sky in proportion to its
    key pixels; the sky is taken as constant over one output pixel. Without key pixels this is the plain
    block mean (``cv2.INTER_AREA``)."""
    import cv2

    height, width = sky.shape[:2]
    key = np.all(rgb == np.asarray(KEY_RGB, dtype=np.uint8), axis=-1)
    if not key.any():
        return rgb if scale == 1 else cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    geometry = np.where(key[..., None], np.uint8(0), rgb)
    if scale > 1:
        geometry = cv2.resize(geometry.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
        coverage = cv2.resize(key.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    else:
        coverage = key.astype(np.float32)
    out = geometry + coverage[..., None] * (255.0 * sky)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
