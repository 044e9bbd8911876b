"""The sky that follows the sun (`pvo_sim.sky`, `pvo sim --sky sun`): the CIE skies against the standard's formula
written out by hand, the compositing, and renders whose sky is brightest on the sun's side."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pvo_sim.render import SimConfig, simulate
from pvo_sim.sky import (
    KEY_RGB,
    clear_sky_luminance,
    composite_sky,
    overcast_sky_luminance,
    pixel_rays,
    sky_values,
    twilight_factor,
)

UP = np.array([0.0, 0.0, 1.0])


def direction(zenith_deg: float, azimuth_deg: float) -> np.ndarray:
    z, a = math.radians(zenith_deg), math.radians(azimuth_deg)
    return np.array([math.sin(z) * math.sin(a), math.sin(z) * math.cos(a), math.cos(z)])


def cie_type_12(zenith_deg: float, angle_to_sun_deg: float, sun_zenith_deg: float) -> float:
    """ISO 15469 / CIE S 011, sky type 12, L / L_z, from the standard's formula with its tabulated a..e."""
    a, b, c, d, e = -1.0, -0.32, 10.0, -3.0, 0.45

    def phi(z: float) -> float:
        return 1.0 + a * math.exp(b / math.cos(math.radians(z)))

    def f(chi: float) -> float:
        x = math.radians(chi)
        return 1.0 + c * (math.exp(d * x) - math.exp(d * math.pi / 2.0)) + e * math.cos(x) ** 2

    return f(angle_to_sun_deg) * phi(zenith_deg) / (f(sun_zenith_deg) * phi(0.0))


@pytest.mark.parametrize(
    ("ray", "sun"), [((80.0, 200.0), (60.0, 20.0)), ((45.0, 30.0), (30.0, 90.0)), ((85.0, 10.0), (70.0, 15.0))]
)
def test_clear_sky_is_the_cie_standard_formula(ray, sun) -> None:
    r, s = direction(*ray), direction(*sun)
    angle = math.degrees(math.acos(float(np.clip(r @ s, -1, 1))))
    assert clear_sky_luminance(r, UP, s) == pytest.approx(cie_type_12(ray[0], angle, sun[0]), rel=1e-12)


def test_clear_sky_is_one_at_the_zenith_brightest_about_the_sun_and_symmetric_about_it() -> None:
    sun = direction(55.0, 120.0)
    assert clear_sky_luminance(UP, UP, sun) == pytest.approx(1.0)
    near, across, far = direction(60.0, 125.0), direction(60.0, 210.0), direction(60.0, 300.0)
    values = clear_sky_luminance(np.stack([near, across, far]), UP, sun)
    assert values[0] > 3.0 * values[1] and values[0] > 3.0 * values[2]
    mirrored = clear_sky_luminance(np.stack([direction(70.0, 120.0 - 40.0), direction(70.0, 120.0 + 40.0)]), UP, sun)
    assert mirrored[0] == pytest.approx(mirrored[1], rel=1e-12)


def test_overcast_sky_has_no_sun_and_is_a_third_as_bright_at_the_horizon() -> None:
    rays = np.stack([UP, direction(90.0, 0.0), direction(60.0, 45.0)])
    assert overcast_sky_luminance(rays, UP) == pytest.approx([1.0, 1.0 / 3.0, 2.0 / 3.0])
    grey = sky_values(rays, UP, direction(30.0, 0.0), overcast=True, colour=False)
    assert grey[0] > grey[2] > grey[1]


def test_a_sun_below_the_horizon_darkens_the_sky_tenfold_every_three_degrees() -> None:
    up = np.array([0.0, -1.0, 0.0])
    rays = pixel_rays(64, 24, 40.0)

    def sun_at(elevation_deg: float) -> np.ndarray:
        e = np.radians(elevation_deg)
        return np.array([0.0, -np.sin(e), np.cos(e)])

    assert twilight_factor(up, sun_at(0.0)) == twilight_factor(up, sun_at(40.0)) == 1.0  # daylight is unchanged
    assert twilight_factor(up, sun_at(-6.0)) == pytest.approx(0.01)
    for overcast in (False, True):
        dusk = sky_values(rays, up, sun_at(-3.0), overcast=overcast, colour=False)
        night = sky_values(rays, up, sun_at(-18.0), overcast=overcast, colour=True)
        assert float(dusk.max()) < float(sky_values(rays, up, sun_at(0.0), overcast=overcast, colour=False).max())
        assert float(night.max()) < 0.05  # dark: not the day's sky (stop 45's --night painted one)


def test_pixel_rays_go_through_the_pixel_centres() -> None:
    rays = pixel_rays(5, 3, focal=2.0)
    assert rays.shape == (3, 5, 3)
    assert np.allclose(rays[1, 2], [0.0, 0.0, 1.0])
    expected = np.array([(4 - 2.0) / 2.0, (0 - 1.0) / 2.0, 1.0])
    assert np.allclose(rays[0, 4], expected / np.linalg.norm(expected))


def test_composite_replaces_only_the_key_and_blends_partly_covered_pixels() -> None:
    key = np.array(KEY_RGB, dtype=np.uint8)
    render = np.full((4, 4, 3), 100, dtype=np.uint8)
    render[:2, :2] = key  # one output pixel all sky
    render[2, 2] = key  # one output pixel a quarter sky
    sky = np.full((2, 2, 3), 0.8)
    out = composite_sky(render, sky, scale=2)
    assert out.shape == (2, 2, 3) and out.dtype == np.uint8
    assert np.all(out[0, 0] == round(0.8 * 255))
    assert np.all(out[1, 1] == round(0.75 * 100 + 0.25 * 0.8 * 255))
    assert np.all(out[0, 1] == 100) and np.all(out[1, 0] == 100)
    plain = render.copy()
    plain[plain[..., 1] == 0] = 7  # no key left: the plain block mean
    assert np.array_equal(composite_sky(plain, sky, scale=1), plain)


def render(out: Path, heading: float, sky: str) -> SimConfig:
    """A small straight drive pitched up to see the sky (skipped without an offscreen renderer)."""
    config = SimConfig(
        width=320, height=120, focal=185.4, path="straight", frames=2, heading_deg=heading, pitch_deg=-12.0,
        start_time="2011-09-30T08:00:00Z", sky=sky, depth=True, colour=True, supersample=2,
    )  # fmt: skip
    try:
        simulate(config, out, overwrite=True)
    except ValueError as exc:
        if "no offscreen renderer" in str(exc):
            pytest.skip(str(exc))
        raise
    return config


def test_a_rendered_sky_is_brightest_on_the_sun_side_and_keeps_no_key_colour(tmp_path: Path) -> None:
    import cv2

    # morning at Karlsruhe: the sun is in the south-east (azimuth ~130 deg), ~30 deg up; the camera looks 30 deg
    # left of it (the sun to the right) then 30 deg right of it, pitched up to see sky. (Not behind the camera:
    # the CIE clear sky brightens again towards the antisolar point, its minimum is ~90 deg from the sun.)
    brighter_side = {}
    for heading, side in ((100.0, "right"), (160.0, "left")):
        out = tmp_path / side
        render(out, heading, "sun")
        image = cv2.imread(str(out / "image_2" / "000000.png"))
        depth = cv2.imread(str(out / "depth_0" / "000000.png"), cv2.IMREAD_UNCHANGED)
        assert not np.any(np.all(image == np.array(KEY_RGB[::-1], dtype=np.uint8), axis=-1))
        grey = image.astype(float).mean(axis=2)
        sky = depth == 0
        half = grey.shape[1] // 2
        left, right = grey[:, :half][sky[:, :half]], grey[:, half:][sky[:, half:]]
        assert left.size > 500 and right.size > 500, "the pitched camera should see sky on both sides"
        brighter_side[side] = "right" if right.mean() > left.mean() else "left"
    assert brighter_side == {"right": "right", "left": "left"}
    import yaml

    recorded = yaml.safe_load((tmp_path / "left" / "sim.yaml").read_text())["config"]
    assert recorded["sky"] == "sun"


def test_the_default_sky_is_not_recorded_and_a_wrong_sky_is_one_clear_error(tmp_path: Path) -> None:
    import yaml
    from pvo_sim.render import recorded_config

    config = render(tmp_path / "plain", 0.0, "gradient")
    recorded = yaml.safe_load((tmp_path / "plain" / "sim.yaml").read_text())["config"]
    assert "sky" not in recorded
    # what `pvo bench realism --reuse` compares a render with
    assert recorded == yaml.safe_load(yaml.safe_dump(recorded_config(config), sort_keys=False))
    with pytest.raises(ValueError, match="--sky must be one of gradient, sun"):
        SimConfig(sky="blue")
