"""Image statistics of `pvo_sim.realism` against cases with a known answer."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_sim.realism import INTENSITY_BINS, compare, image_statistics, spectrum_slope, wasserstein


def power_law_image(alpha: float, size: int = 256, seed: int = 0) -> np.ndarray:
    """Gaussian noise shaped to a power spectrum f^-alpha, scaled to 8 bits."""
    rng = np.random.default_rng(seed)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.fftfreq(size)[None, :]
    radius = np.hypot(fy, fx)
    radius[0, 0] = 1.0
    spectrum = np.fft.fft2(rng.standard_normal((size, size))) * radius ** (-alpha / 2)
    field = np.real(np.fft.ifft2(spectrum))
    field = (field - field.mean()) / field.std()
    return np.clip(128 + 30 * field, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("alpha", [1.0, 2.0, 3.0])
def test_spectrum_slope_recovers_the_power_law(alpha: float) -> None:
    slopes = [spectrum_slope(power_law_image(alpha, seed=s)) for s in range(4)]
    assert np.mean(slopes) == pytest.approx(-alpha, abs=0.15)


def test_wasserstein_of_a_shifted_histogram_is_the_shift() -> None:
    a = np.zeros(len(INTENSITY_BINS) - 1)
    b = np.zeros(len(INTENSITY_BINS) - 1)
    a[10], b[13] = 1.0, 1.0  # three bins of 4 grey levels apart
    assert wasserstein(a, b, INTENSITY_BINS) == pytest.approx(12.0)
    assert wasserstein(a, a, INTENSITY_BINS) == 0.0


def test_statistics_tell_a_blurred_set_from_a_sharp_one() -> None:
    import cv2

    sharp = [power_law_image(2.0, seed=s) for s in range(3)]
    blurred = [cv2.GaussianBlur(i, (0, 0), 2.0) for i in sharp]
    same = compare(image_statistics(sharp), image_statistics(sharp))
    assert same.slope_gap == 0.0 and same.gradient_distance == 0.0
    gap = compare(image_statistics(blurred), image_statistics(sharp))
    assert gap.slope_gap > 0.5 and gap.gradient_distance > 1.0


def test_colour_images_are_refused() -> None:
    with pytest.raises(ValueError, match="grey"):
        image_statistics([np.zeros((8, 8, 3), np.uint8)])
    with pytest.raises(ValueError, match="at least one"):
        image_statistics([])
