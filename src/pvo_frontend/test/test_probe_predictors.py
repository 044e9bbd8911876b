"""PROBE's predictors, vectorised over a frame's features, each against a direct per-feature reference."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_frontend.probe.predictors import (
    PredictorConfig,
    blur_metric,
    compute_predictors,
    flow_variance_score,
    frequency_composition,
    gather_patches,
    patch_entropy,
)


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    """A textured frame: smooth gradients, noise on the right half, a blurred band at the bottom."""
    rng = np.random.default_rng(0)
    height, width = 180, 320
    y, x = np.mgrid[0:height, 0:width]
    base = 80 + 60 * np.sin(x / 9.0) * np.cos(y / 13.0)
    base[:, width // 2 :] += rng.normal(0, 25, (height, width - width // 2))
    picture = np.clip(base, 0, 255).astype(np.uint8)
    import cv2

    picture[120:] = cv2.GaussianBlur(picture[120:], (0, 0), 3.0)
    return picture


CENTRES = np.array([[60.0, 40.0], [250.0, 50.0], [100.2, 150.7], [280.0, 140.0], [160.0, 90.0]])


def test_patches_are_centred_on_the_feature_pixel(image: np.ndarray) -> None:
    patches = gather_patches(image, CENTRES, 32)
    assert patches.shape == (5, 32, 32)
    for (u, v), patch in zip(CENTRES, patches, strict=True):
        r, c = round(v), round(u)
        np.testing.assert_array_equal(patch, image[r - 16 : r + 16, c - 16 : c + 16])
    edge = gather_patches(image, np.array([[0.0, 0.0]]), 8)[0]
    assert edge[4, 4] == image[0, 0] and edge[4, 5] == image[0, 1] and edge[4, 3] == image[0, 1]  # reflected


def test_entropy_equals_the_histogram_formula(image: np.ndarray) -> None:
    patches = gather_patches(image, CENTRES, 32)
    for bins in (8, 16, 256):
        fast = patch_entropy(patches, bins)
        for patch, value in zip(patches, fast, strict=True):
            counts, _ = np.histogram(patch, bins=bins, range=(0, 256))
            p = counts[counts > 0] / patch.size
            assert value == pytest.approx(-np.sum(p * np.log2(p)), abs=1e-12)
    flat = np.full((1, 32, 32), 77, np.uint8)
    assert patch_entropy(flat, 16)[0] == 0.0


def test_frequency_blocks_equal_a_direct_fft(image: np.ndarray) -> None:
    patches = gather_patches(image, CENTRES, 32)
    low, high = frequency_composition(patches, 6)
    k = np.fft.fftfreq(32, 1 / 32).astype(int)  # 0 .. 15, -16 .. -1
    for patch, lo, hi in zip(patches, low, high, strict=True):
        spectrum = np.log1p(np.abs(np.fft.fft2(patch.astype(float))))
        cells = [(a, b) for a in range(32) for b in range(32)]
        # the half-plane blocks: rows within 3 of DC, columns 0..3 (DC out); rows and columns within 3 of Nyquist
        half_dc = [spectrum[a, b] for a, b in cells if abs(k[a]) <= 3 and 0 <= k[b] <= 3 and (a, b) != (0, 0)]
        half_nyquist = [spectrum[a, b] for a, b in cells if 13 <= a <= 19 and 13 <= b <= 16]
        assert lo == pytest.approx(np.mean(half_dc), rel=1e-5)
        assert hi == pytest.approx(np.mean(half_nyquist), rel=1e-5)
        # ... which by conjugate symmetry are the full square blocks but for a few duplicated cells
        full_dc = [spectrum[a, b] for a, b in cells if max(abs(k[a]), abs(k[b])) <= 3 and (a, b) != (0, 0)]
        full_nyquist = [spectrum[a, b] for a, b in cells if min(abs(k[a]), abs(k[b])) >= 13]
        assert lo == pytest.approx(np.mean(full_dc), rel=0.05)
        assert hi == pytest.approx(np.mean(full_nyquist), rel=0.05)
    # noise has more high-frequency energy than the smooth left half
    assert high[1] > high[0] and high[3] > high[2]


def direct_blur(image: np.ndarray, u: float, v: float, patch: int, taps: int) -> float:
    """Crété-Roffet on one patch with explicit loops; the box blur from the image around it."""
    f = image.astype(float)
    r0, c0 = round(v) - patch // 2, round(u) - patch // 2
    half = taps // 2
    totals = []
    for axis in (0, 1):
        s_f = s_v = 0.0
        for r in range(r0, r0 + patch):
            for c in range(c0, c0 + patch):
                pr, pc = (r - 1, c) if axis == 0 else (r, c - 1)
                if pr < 0 or pc < 0:
                    continue
                if axis == 0:
                    b_here = np.mean(f[r - half : r + half + 1, c])
                    b_prev = np.mean(f[pr - half : pr + half + 1, c])
                else:
                    b_here = np.mean(f[r, c - half : c + half + 1])
                    b_prev = np.mean(f[r, pc - half : pc + half + 1])
                d_f = abs(f[r, c] - f[pr, pc])
                s_f += d_f
                s_v += max(0.0, d_f - abs(b_here - b_prev))
        totals.append((s_f - s_v) / s_f)
    return max(totals)


def test_blur_metric_equals_a_direct_loop_and_sees_the_blurred_band(image: np.ndarray) -> None:
    inside = CENTRES[[0, 1, 4]]  # patches with the blur taps inside the image
    fast = blur_metric(image, inside, 32, 9)
    for (u, v), value in zip(inside, fast, strict=True):
        assert value == pytest.approx(direct_blur(image, u, v, 32, 9), abs=1e-6)  # float32 maps
    values = blur_metric(image, CENTRES, 32, 9)
    assert np.all((values >= 0.0) & (values <= 1.0))
    assert values[3] > values[1]  # the blurred band against the sharp noise above it


def test_flow_variance_score_equals_a_direct_loop_and_marks_a_moving_object() -> None:
    rng = np.random.default_rng(2)
    current = rng.uniform([0, 0], [600, 180], (200, 2))
    flow = np.tile([-5.0, 0.5], (200, 1)) + rng.normal(0, 0.3, (200, 2))
    mover = (current[:, 0] > 400) & (current[:, 0] < 460) & (current[:, 1] > 60) & (current[:, 1] < 120)
    flow[mover] += rng.normal(0, 6.0, (int(mover.sum()), 2))
    reference = current - flow
    fast = flow_variance_score(reference, current, 40.0, 160.0)
    for i in range(0, 200, 17):
        near = np.abs(current - current[i]).max(axis=1)
        small, large = flow[near <= 40.0], flow[near <= 160.0]
        expected = np.log(small.var(axis=0).mean() / large.var(axis=0).mean()) if len(small) >= 3 else 0.0
        assert fast[i] == pytest.approx(expected if expected >= -20 else 0.0, abs=1e-9)
    assert fast[mover].mean() > fast[~mover].mean() + 0.5


def test_compute_predictors_columns_and_bad_input(image: np.ndarray) -> None:
    config = PredictorConfig(imu=True)
    names = ("entropy", "blur", "fft_low", "fft_high", "flow_variance", "specific_force", "angular_rate", "disparity", "row")
    assert config.names == names
    disparity = np.array([10.0, 20.0, 30.0, 40.0, 50.0])
    values = compute_predictors(config, CENTRES - 1.0, CENTRES, image, np.array([9.9, 0.2]), disparity)
    assert values.shape == (5, 9)
    np.testing.assert_array_equal(values[:, 5], 9.9)
    np.testing.assert_array_equal(values[:, 7], disparity)
    np.testing.assert_array_equal(values[:, 8], CENTRES[:, 1])
    assert PredictorConfig(image=False, geometry=False).names == ("flow_variance",)
    with pytest.raises(ValueError, match="no disparities were given"):
        compute_predictors(PredictorConfig(image=False), CENTRES, CENTRES)
    with pytest.raises(ValueError, match="no image was given"):
        compute_predictors(PredictorConfig(), CENTRES, CENTRES)
    with pytest.raises(ValueError, match="no IMU reading was given"):
        compute_predictors(config, CENTRES, CENTRES, image)
    with pytest.raises(ValueError, match="patch must be an even number"):
        PredictorConfig(patch=31)
    with pytest.raises(ValueError, match="flow_small < flow_large"):
        PredictorConfig(flow_small=100.0, flow_large=50.0)
