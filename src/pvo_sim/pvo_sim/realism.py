"""How much rendered images share with real ones: image statistics that a learned model or a feature
tracker is sensitive to, and distances between two sets of them (numpy only, no I/O).

- the slope of the radially averaged power spectrum (log power against log spatial frequency; natural
  images fall off as about f^-2): the balance of coarse and fine structure;
- the intensity histogram (exposure, contrast, clipping);
- the gradient-magnitude histogram (edge strength: what corner detectors and KLT feed on).

Histogram distances are the 1-Wasserstein (earth mover's) distance, in the quantity's own units (grey
levels; grey levels per pixel), so "how far" reads directly.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
INTENSITY_BINS = np.linspace(0.0, 256.0, 65)
GRADIENT_BINS = np.linspace(0.0, 128.0, 65)
SPECTRUM_BAND = (0.02, 0.25)  # cycles per pixel over which the slope is fitted


@dataclass(frozen=True)
class ImageStatistics:
    """Statistics of a set of grey images: spectrum slope (mean and std over images), mean intensity, and the
    normalised intensity and gradient-magnitude histograms (over ``INTENSITY_BINS``, ``GRADIENT_BINS``)."""

    images: int
    spectrum_slope: float
    spectrum_slope_std: float
    mean_intensity: float
    intensity_histogram: Array
    gradient_histogram: Array


def spectrum_slope(image: NDArray) -> float:
    """Slope of log power against log frequency of the radially averaged power spectrum of a grey image
    (Hann-windowed, mean removed), fitted over ``SPECTRUM_BAND``."""
    grey = np.asarray(image, dtype=np.float64)
    h, w = grey.shape
    window = np.outer(np.hanning(h), np.hanning(w))
    power = np.abs(np.fft.fft2((grey - grey.mean()) * window)) ** 2
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    radius = np.hypot(fy, fx)
    edges = np.geomspace(SPECTRUM_BAND[0], SPECTRUM_BAND[1], 16)
    index = np.digitize(radius.ravel(), edges)
    sums = np.bincount(index, weights=power.ravel(), minlength=len(edges) + 1)
    counts = np.bincount(index, minlength=len(edges) + 1)
    inside = slice(1, len(edges))  # the bands between consecutive edges
    centres = np.sqrt(edges[:-1] * edges[1:])
    mean_power = sums[inside] / np.maximum(counts[inside], 1)
    ok = (counts[inside] > 0) & (mean_power > 0)
    if ok.sum() < 3:
        return float("nan")
    slope, _ = np.polyfit(np.log(centres[ok]), np.log(mean_power[ok]), 1)
    return float(slope)


def gradient_magnitude(image: NDArray) -> Array:
    """Central-difference gradient magnitude (grey levels per pixel) of the interior pixels."""
    grey = np.asarray(image, dtype=np.float64)
    gx = 0.5 * (grey[1:-1, 2:] - grey[1:-1, :-2])
    gy = 0.5 * (grey[2:, 1:-1] - grey[:-2, 1:-1])
    return np.hypot(gx, gy)


def image_statistics(images: Iterable[NDArray]) -> ImageStatistics:
    """The statistics of a set of grey (H, W) uint8 images."""
    slopes, means = [], []
    intensity = np.zeros(len(INTENSITY_BINS) - 1)
    gradient = np.zeros(len(GRADIENT_BINS) - 1)
    for image in images:
        if image.ndim != 2:
            raise ValueError(f"image statistics need grey (H, W) images, got shape {image.shape}")
        slopes.append(spectrum_slope(image))
        means.append(float(image.mean()))
        intensity += np.histogram(image, INTENSITY_BINS)[0]
        gradient += np.histogram(np.clip(gradient_magnitude(image), 0, GRADIENT_BINS[-1] - 1e-9), GRADIENT_BINS)[0]
    if not slopes:
        raise ValueError("image statistics need at least one image")
    return ImageStatistics(
        len(slopes),
        float(np.nanmean(slopes)),
        float(np.nanstd(slopes)),
        float(np.mean(means)),
        intensity / intensity.sum(),
        gradient / gradient.sum(),
    )


def wasserstein(histogram_a: Array, histogram_b: Array, edges: Array) -> float:
    """1-Wasserstein distance between two normalised histograms over the same bin ``edges`` (in their units)."""
    cdf_gap = np.abs(np.cumsum(histogram_a) - np.cumsum(histogram_b))
    return float(np.sum(cdf_gap[:-1] * np.diff(edges)[:-1]))


@dataclass(frozen=True)
class Comparison:
    """Rendered against real: spectrum-slope gap, and histogram distances (grey levels; grey levels/px)."""

    slope_gap: float
    intensity_distance: float
    gradient_distance: float


def compare(rendered: ImageStatistics, real: ImageStatistics) -> Comparison:
    return Comparison(
        abs(rendered.spectrum_slope - real.spectrum_slope),
        wasserstein(rendered.intensity_histogram, real.intensity_histogram, INTENSITY_BINS),
        wasserstein(rendered.gradient_histogram, real.gradient_histogram, GRADIENT_BINS),
    )
