"""PROBE's prediction space (thesis §4.5, app. A): per-feature predictors of how well a feature will track,
computed for all features of a frame at once.

- ``entropy``: Shannon entropy (bits) of the grey levels of the patch around the feature, in
  ``entropy_bins`` equal bins (eq. 4.31, the counts normalised to frequencies);
- ``blur``: the blur metric of Crété-Roffet et al. (2007) on the patch: the share of the patch's vertical
  (horizontal) grey-level variation that a ``blur_taps``-tap box blur leaves, the larger of the two
  (0 sharp, 1 fully blurred);
- ``fft_low`` / ``fft_high``: mean log(1 + magnitude) of the patch's 2-D FFT over the lowest (around DC,
  DC excluded) and the highest frequencies (around Nyquist), square blocks of about ``frequency_block`` of
  the spectrum per axis - texture-poor or self-similar patches have little high-frequency energy (the
  thesis's code took "the first and the last 20 x 20" coefficients of an unshifted FFT, both of which are
  low frequencies);
- ``flow_variance``: log(var_small / var_large) of the feature tracks' image motion (current - reference
  left position, both axes averaged) among the features within a small and a large square window around
  the feature (eq. 4.32); moving objects stand out; 0 when the small window holds fewer than three tracks
  or the ratio is below e^-20 (as the thesis's code);
- ``specific_force`` / ``angular_rate``: |f| (m/s²) and |omega| (rad/s) of the IMU at the frame, when an
  IMU is given (the same for every feature of the frame);
- ``disparity`` / ``row``: the feature's disparity in the reference frame and its image row in the current one
  (px) - beyond the thesis's list: how far a point is sets how its triangulation error reaches the
  reprojection error; on KITTI 07's held-out frames they lowered PROBE-GK's ARMSE from 0.541 to 0.529 m.

Patches are ``patch`` x ``patch`` px centred on the feature, taken from the image reflected at its borders
(the thesis's code zeroed predictors near the border instead). Entropy and the FFT work on a batch of
gathered patches (one bincount, one FFT); blur on whole-image difference maps summed over each patch by
integral images; the flow windows by one masked matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

IMAGE_PREDICTORS = ("entropy", "blur", "fft_low", "fft_high")
TRACK_PREDICTORS = ("flow_variance",)
GEOMETRY_PREDICTORS = ("disparity", "row")
IMU_PREDICTORS = ("specific_force", "angular_rate")


@dataclass(frozen=True)
class PredictorConfig:
    """patch: side of the square patch (px, even); entropy_bins: grey-level bins; blur_taps: box-blur length;
    frequency_block: side of the low and high FFT blocks as a fraction of the patch; flow_small /
    flow_large: half-sides (px) of the flow windows; image / imu: which predictor groups are used."""

    patch: int = 32
    entropy_bins: int = 16
    blur_taps: int = 9
    frequency_block: float = 0.2
    flow_small: float = 50.0
    flow_large: float = 200.0
    image: bool = True
    imu: bool = False
    geometry: bool = True

    def __post_init__(self) -> None:
        if self.patch < 8 or self.patch % 2:
            raise ValueError(f"probe patch must be an even number of pixels >= 8, got {self.patch}")
        if not 2 <= self.entropy_bins <= 256:
            raise ValueError(f"probe entropy_bins must be in [2, 256], got {self.entropy_bins}")
        if self.blur_taps < 3 or self.blur_taps % 2 == 0:
            raise ValueError(f"probe blur_taps must be odd and >= 3, got {self.blur_taps}")
        if not 0.0 < self.frequency_block <= 0.5:
            raise ValueError(f"probe frequency_block must be in (0, 0.5], got {self.frequency_block}")
        if not 0.0 < self.flow_small < self.flow_large:
            raise ValueError(f"probe flow windows need 0 < flow_small < flow_large, got {self.flow_small}, {self.flow_large}")

    @property
    def names(self) -> tuple[str, ...]:
        """The predictors this configuration computes, in column order."""
        return (
            (IMAGE_PREDICTORS if self.image else ())
            + TRACK_PREDICTORS
            + (IMU_PREDICTORS if self.imu else ())
            + (GEOMETRY_PREDICTORS if self.geometry else ())
        )

    @property
    def block(self) -> int:
        return max(1, round(self.frequency_block * self.patch))


def gather_patches(image: NDArray[np.uint8], centres: Array, patch: int) -> NDArray[np.uint8]:
    """(N, patch, patch) patches whose centre pixel (row patch/2, column patch/2) is the feature's pixel
    (rounded), from the image reflected at its borders."""
    half = patch // 2
    padded = cv2.copyMakeBorder(image, half, half, half, half, cv2.BORDER_REFLECT_101)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (patch, patch))
    cols = np.clip(np.rint(centres[:, 0]).astype(np.int64), 0, image.shape[1] - 1)
    rows = np.clip(np.rint(centres[:, 1]).astype(np.int64), 0, image.shape[0] - 1)
    return windows[rows, cols]


def patch_entropy(patches: NDArray[np.uint8], bins: int) -> Array:
    """Entropy (bits) of each patch's grey levels in ``bins`` equal bins, (N,)."""
    n, rows, cols = patches.shape
    counts = np.empty((n, bins))
    # one histogram of (patch, bin) labels per chunk, as 16-bit integers (OpenCV's histogram of a 16-bit image is
    # several times faster than numpy's bincount of the same labels widened to intp)
    chunk = 65536 // bins
    for start in range(0, n, chunk):
        part = patches[start : start + chunk]
        m = len(part)
        if bins & (bins - 1) == 0:  # a power of two: the bin is the top bits
            which = (part >> (8 - bins.bit_length() + 1)).astype(np.uint16)
        else:
            which = (part.astype(np.uint16) * bins) >> 8
        which += (bins * np.arange(m, dtype=np.uint16))[:, None, None]
        histogram = cv2.calcHist([which.reshape(m * rows, cols)], [0], None, [m * bins], [0, m * bins])
        counts[start : start + m] = histogram.reshape(m, bins)
    p = counts / float(rows * cols)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.sum(np.where(p > 0.0, p * np.log2(p), 0.0), axis=1)


def frequency_indices(
    patch: int, block: int
) -> tuple[tuple[NDArray[np.int64], NDArray[np.int64]], tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Row and column indices into a real 2-D FFT (P, P // 2 + 1) of the lowest frequencies (rows -h..h, columns
    0..h, DC left out) and of the highest (rows and columns within h of Nyquist), h = block // 2. The spectrum of
    a real patch is conjugate-symmetric, so these half-plane blocks hold the magnitudes of the full square
    blocks around DC and around Nyquist."""
    h = max(1, block // 2)
    nyquist = patch // 2
    rows_low, cols_low = np.r_[0 : h + 1, patch - h : patch], np.arange(0, h + 1)
    rows_high, cols_high = np.arange(nyquist - h, nyquist + h + 1), np.arange(nyquist - h, nyquist + 1)
    r, c = np.meshgrid(rows_low, cols_low, indexing="ij")
    keep = (r != 0) | (c != 0)
    low = (r[keep], c[keep])
    r, c = np.meshgrid(rows_high, cols_high, indexing="ij")
    return low, (r.ravel(), c.ravel())


def frequency_composition(patches: NDArray[np.uint8], block: int) -> tuple[Array, Array]:
    """Mean log(1 + |F|) of each patch's 2-D FFT (N, P, P) over its lowest and its highest frequencies
    (:func:`frequency_indices`), (N,) each: a real FFT of every row of the batch, then a complex FFT down the
    few columns the blocks use (the same numbers as the whole 2-D FFT, at about half its cost)."""
    import scipy.fft

    (low_rows, low_cols), (high_rows, high_cols) = frequency_indices(patches.shape[1], block)
    columns, where = np.unique(np.r_[low_cols, high_cols], return_inverse=True)
    rows = scipy.fft.rfft(patches.astype(np.float32), axis=2, workers=1)[:, :, columns]
    spectrum = scipy.fft.fft(rows, axis=1, workers=1)  # (N, P, len(columns))
    split = len(low_rows)
    blocks = np.concatenate([spectrum[:, low_rows, where[:split]], spectrum[:, high_rows, where[split:]]], axis=1)
    # OpenCV's log: numpy's float32 log1p is unvectorised on many builds (10x slower)
    magnitude = cv2.log(np.abs(blocks) + np.float32(1.0))
    return magnitude[:, :split].mean(axis=1).astype(float), magnitude[:, split:].mean(axis=1).astype(float)


def blur_maps(image: NDArray[np.uint8], taps: int) -> list[NDArray[np.uint8]]:
    """Per-pixel terms of the Crété-Roffet metric, (H, W) uint8 each, for vertical and then horizontal
    neighbours (row / column 0 zero): |dF| and min(|F[y+h] - F[y-h-1]|, taps |dF|), h = taps // 2, B the image
    box-blurred along that axis (its border reflected). A box blur's neighbour difference telescopes,
    B[y] - B[y-1] = (F[y+h] - F[y-h-1]) / taps, so no blurred image is formed; and the metric's
    taps * max(0, |dF| - |dB|) = taps |dF| - min(|F[y+h] - F[y-h-1]|, taps |dF|), whose second term never
    exceeds 255: every plane is 8-bit and every patch sum an exact 32-bit integral-image lookup."""
    h = taps // 2
    padded = cv2.copyMakeBorder(image, h + 1, h + 1, h + 1, h + 1, cv2.BORDER_REFLECT_101)
    height, width = image.shape
    top, left = h + 1, h + 1
    saturated = np.minimum(255, taps * np.arange(256)).astype(np.uint8)
    planes: list[NDArray[np.uint8]] = []
    for axis in (0, 1):
        dy, dx = (1, 0) if axis == 0 else (0, 1)

        def at(offset: int, dy: int = dy, dx: int = dx) -> NDArray[np.uint8]:
            return padded[top + dy * offset : top + dy * offset + height, left + dx * offset : left + dx * offset + width]

        d = cv2.absdiff(at(0), at(-1))
        step = cv2.absdiff(at(h), at(-h - 1))
        # min(step, taps d), taps d saturated at 255 (which step never exceeds) by a lookup table
        kept = cv2.min(step, cv2.LUT(d, saturated))
        if axis == 0:
            d[0], kept[0] = 0, 0
        else:
            d[:, 0], kept[:, 0] = 0, 0
        planes += [d, kept]
    return planes


def patch_sums(planes: list[NDArray[np.uint8]], centres: Array, patch: int) -> Array:
    """Sum of each 8-bit plane (H, W) over each feature's patch (the part inside the image), by integral
    images, (N, len(planes))."""
    height, width = planes[0].shape
    half = patch // 2
    cols = np.clip(np.rint(centres[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint(centres[:, 1]).astype(np.int64), 0, height - 1)
    top, bottom = np.clip(rows - half, 0, height), np.clip(rows + half, 0, height)
    left, right = np.clip(cols - half, 0, width), np.clip(cols + half, 0, width)
    sums = []
    integral = np.empty((height + 1, width + 1), np.int32)  # one buffer for every plane: fewer cold pages
    for plane in planes:
        cv2.integral(plane, integral, sdepth=cv2.CV_32S)  # exact: at most 255 H W < 2^31
        corners = [integral[r, c].astype(np.int64) for r, c in ((bottom, right), (top, right), (bottom, left), (top, left))]
        sums.append(corners[0] - corners[1] - corners[2] + corners[3])
    return np.stack(sums, axis=1).astype(float)


def blur_metric(image: NDArray[np.uint8], centres: Array, patch: int, taps: int) -> Array:
    """Crété-Roffet blur of each feature's patch, (N,): max over the two axes of (s_F - s_V) / s_F."""
    sums = patch_sums(blur_maps(image, taps), centres, patch)
    d_ver, kept_ver, d_hor, kept_hor = sums.T
    # s_V = s_F - kept / taps, so (s_F - s_V) / s_F = kept / (taps s_F)
    with np.errstate(divide="ignore", invalid="ignore"):
        b_ver = np.where(d_ver > 0.0, kept_ver / (taps * d_ver), 1.0)
        b_hor = np.where(d_hor > 0.0, kept_hor / (taps * d_hor), 1.0)
    return np.maximum(b_ver, b_hor)


def flow_variance_score(reference: Array, current: Array, small: float, large: float) -> Array:
    """log(var_small / var_large) of the tracks' image motion around each feature (eq. 4.32), (N,)."""
    n = len(current)
    if n == 0:
        return np.zeros(0)
    flow = current - reference
    flow = flow - flow.mean(axis=0)  # centred, so that the variance by sums of squares keeps its digits
    # sums over square windows as masked matrix products; the Chebyshev distances in float32 and in place (fresh
    # N x N float64 arrays cost more in page faults than in arithmetic), the moments' sums in float64 (a small
    # window's variance is a difference of sums that float32 would round)
    moments = np.column_stack([np.ones(n), flow, flow * flow])  # (N, 5)
    position = current.astype(np.float32)
    offset = np.subtract.outer(position[:, 0], position[:, 0])
    np.abs(offset, out=offset)
    rows = np.subtract.outer(position[:, 1], position[:, 1])
    np.maximum(offset, np.abs(rows, out=rows), out=offset)
    scores = []
    for half in (small, large):
        sums = (offset <= half).astype(np.float64) @ moments
        count = sums[:, 0]
        mean = sums[:, 1:3] / count[:, None]
        variance = np.maximum(sums[:, 3:5] / count[:, None] - mean * mean, 0.0).mean(axis=1)
        scores.append((variance, count))
    (var_small, count_small), (var_large, _) = scores
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.log(var_small / var_large)
    return np.where((count_small >= 3) & np.isfinite(score) & (score >= -20.0), score, 0.0)


def compute_predictors(
    config: PredictorConfig,
    reference: Array,
    current: Array,
    image: NDArray[np.uint8] | None = None,
    imu: Array | None = None,
    disparity: Array | None = None,
) -> Array:
    """Predictors (N, len(config.names)) of features tracked from ``reference`` to ``current`` left-image
    positions (N, 2) px; ``image``: the current left image (needed when ``config.image``); ``imu``: (|f|, |w|)
    of the frame (needed when ``config.imu``)."""
    reference, current = np.asarray(reference, dtype=float).reshape(-1, 2), np.asarray(current, dtype=float).reshape(-1, 2)
    if len(reference) != len(current):
        raise ValueError(f"{len(reference)} reference positions but {len(current)} current ones")
    columns: list[Array] = []
    if config.image:
        if image is None:
            raise ValueError("the PROBE model uses image predictors but no image was given")
        patches = gather_patches(image, current, config.patch)
        columns.append(patch_entropy(patches, config.entropy_bins))
        columns.append(blur_metric(image, current, config.patch, config.blur_taps))
        columns.extend(frequency_composition(patches, config.block))
    columns.append(flow_variance_score(reference, current, config.flow_small, config.flow_large))
    if config.imu:
        if imu is None:
            raise ValueError("the PROBE model uses IMU predictors but no IMU reading was given")
        magnitudes = np.asarray(imu, dtype=float).reshape(2)
        columns.extend([np.full(len(current), magnitudes[0]), np.full(len(current), magnitudes[1])])
    if config.geometry:
        if disparity is None:
            raise ValueError("the PROBE model uses geometry predictors but no disparities were given")
        columns.extend([np.asarray(disparity, dtype=float).reshape(-1), current[:, 1]])
    return np.column_stack(columns) if columns else np.zeros((len(current), 0))
