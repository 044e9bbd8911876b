"""The camera model: exposure control, noise statistics, gamma, vignetting, JPEG, determinism, bad values."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from pvo_sim.degrade import CameraModel, Degradations, ImageDegrader


def degrader(camera: CameraModel, frames: int = 40, **degradations) -> ImageDegrader:
    return ImageDegrader(Degradations(**degradations), 200, 100, 150.0, frames, seed=5, camera=camera)


def test_linear_camera_leaves_the_render_unchanged() -> None:
    image = np.random.default_rng(0).integers(0, 256, (100, 200), dtype=np.uint8)
    np.testing.assert_array_equal(degrader(CameraModel.linear())(image, 0, 0), image)


def test_auto_exposure_settles_on_the_target_brightness() -> None:
    camera = CameraModel(target=0.45, gamma=2.0, vignetting=0.0, full_well=0.0, read_noise=0.0, sharpening=0.0)
    process = degrader(camera)
    dark = np.full((100, 200), 20, np.uint8)
    first = process(dark, 0, 0)
    assert abs(first.mean() / 255.0 - 0.45) < 0.01  # the first frame is metered exactly
    bright = np.full((100, 200), 120, np.uint8)
    means = [process(bright, k, 0).mean() / 255.0 for k in range(1, 30)]
    assert means[0] > 0.6  # the scene brightened: the gain lags
    assert abs(means[-1] - 0.45) < 0.01  # and adapts back
    assert all(a >= b - 1e-9 for a, b in itertools.pairwise(means))


def test_both_cameras_share_the_gain_of_the_frame() -> None:
    camera = CameraModel(vignetting=0.0, full_well=0.0, read_noise=0.0, sharpening=0.0)
    process = degrader(camera)
    left = np.full((100, 200), 60, np.uint8)
    right = np.full((100, 200), 90, np.uint8)  # metered on the left only
    a, b = process(left, 0, 0), process(right, 0, 1)
    gain = (a.mean() / 255.0) ** camera.gamma / (60 / 255.0)
    assert (b.mean() / 255.0) ** camera.gamma == pytest.approx(gain * 90 / 255.0, rel=0.02)


def test_noise_follows_shot_plus_read_noise() -> None:
    camera = CameraModel(auto_exposure=False, gamma=1.0, vignetting=0.0, full_well=2000.0, read_noise=2.0, sharpening=0.0)
    process = degrader(camera)
    level = 128
    flat = np.full((100, 200), level, np.uint8)
    out = np.stack([process(flat, k, 0).astype(float) for k in range(6)])
    expected = np.sqrt((level / 255.0) / camera.full_well + (camera.read_noise / 255.0) ** 2) * 255.0
    assert out.std() == pytest.approx(expected, rel=0.05)
    assert out.mean() == pytest.approx(level, abs=0.3)


def test_noise_is_seeded_per_frame_and_camera_whatever_the_order() -> None:
    camera = CameraModel(auto_exposure=False, sharpening=0.0)
    image = np.full((100, 200), 100, np.uint8)
    a = degrader(camera)
    first = [a(image, k, c) for k in range(3) for c in (0, 1)]
    b = degrader(camera)
    again = [b(image, k, c) for k in range(3) for c in (0, 1)]
    for x, y in zip(first, again, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(first[0], first[1])  # left and right noise differ


def test_gamma_and_vignetting() -> None:
    camera = CameraModel(auto_exposure=False, gamma=2.0, vignetting=0.3, full_well=0.0, read_noise=0.0, sharpening=0.0)
    out = degrader(camera)(np.full((100, 200), 64, np.uint8), 0, 0).astype(float)
    assert out[50, 100] == pytest.approx(255.0 * (64 / 255.0) ** 0.5, abs=1.0)
    assert out[0, 0] == pytest.approx(255.0 * (0.7 * 64 / 255.0) ** 0.5, abs=1.0)


def test_jpeg_compression_changes_the_image_a_little() -> None:
    rng = np.random.default_rng(1)
    image = (rng.random((100, 200)) * 40 + 100).astype(np.uint8)
    plain = degrader(CameraModel(auto_exposure=False, gamma=1.0, vignetting=0.0, full_well=0.0, read_noise=0.0, sharpening=0.0))(
        image, 0
    )
    jpeg = degrader(
        CameraModel(
            auto_exposure=False, gamma=1.0, vignetting=0.0, full_well=0.0, read_noise=0.0, sharpening=0.0, jpeg_quality=50
        )
    )(image, 0)
    difference = np.abs(plain.astype(float) - jpeg)
    assert 0.5 < difference.mean() < 15.0


def test_sharpening_overshoots_at_edges_and_leaves_flat_areas() -> None:
    base = {"auto_exposure": False, "gamma": 1.0, "vignetting": 0.0, "full_well": 0.0, "read_noise": 0.0}
    step = np.full((100, 200), 80, np.uint8)
    step[:, 100:] = 160
    plain = degrader(CameraModel(**base, sharpening=0.0))(step, 0).astype(float)
    sharp = degrader(CameraModel(**base, sharpening=1.0))(step, 0).astype(float)
    np.testing.assert_array_equal(plain, step)
    assert sharp[50, 20] == 80 and sharp[50, 180] == 160  # flat areas untouched
    assert sharp[50, 99] < 75 and sharp[50, 100] > 165  # dark and bright overshoot either side of the edge


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("gamma", 0.1, "gamma"),
        ("vignetting", 1.0, "vignetting"),
        ("jpeg_quality", 101, "jpeg_quality"),
        ("target", 0.0, "target"),
        ("read_noise", -1.0, "read_noise"),
        ("sharpening", 5.0, "sharpening"),
    ],
)
def test_bad_camera_values_are_refused(field: str, value: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        CameraModel(**{field: value})
