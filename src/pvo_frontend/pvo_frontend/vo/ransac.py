"""3-point RANSAC over triangulated stereo points (thesis §3.2.3).

Each hypothesis aligns three reference points with the same three points triangulated in the current
frame by the closed-form least-squares rotation (Arun et al. 1987 / Umeyama 1991, no scale). All
hypotheses of a batch are solved together (batched 3x3 SVDs) and scored on the whitened stereo
reprojection error of every feature. The iteration count adapts to the best inlier ratio so far:
n = log(1 - confidence) / log(1 - w^3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera

from .solver import quadratic_form

Array = NDArray[np.float64]


def align_points(source: Array, target: Array) -> Array:
    """Rigid transforms (B, 4, 4) minimising sum ||target - (R source + t)||^2 for batches (B, M, 3)."""
    mu_s = source.mean(axis=1, keepdims=True)
    mu_t = target.mean(axis=1, keepdims=True)
    cross = np.einsum("bmi,bmj->bij", source - mu_s, target - mu_t)  # sum (s - mu_s)(t - mu_t)^T
    u, _, vt = np.linalg.svd(cross)
    det = np.linalg.det(np.einsum("bji,bkj->bik", vt, u))  # det(V U^T)
    d = np.ones((source.shape[0], 3))
    d[:, 2] = np.sign(det)
    d[d[:, 2] == 0.0, 2] = 1.0
    rotation = np.einsum("bji,bj,bkj->bik", vt, d, u)  # V diag(d) U^T
    translation = mu_t[:, 0] - np.einsum("bij,bj->bi", rotation, mu_s[:, 0])
    out = np.zeros((source.shape[0], 4, 4))
    out[:, :3, :3] = rotation
    out[:, :3, 3] = translation
    out[:, 3, 3] = 1.0
    return out


@dataclass(frozen=True)
class RansacResult:
    transform: Array  # best hypothesis T_cur,ref (4, 4)
    inliers: NDArray[np.bool_]  # (N,)
    iterations: int


def required_iterations(inlier_ratio: float, confidence: float, sample_size: int = 3) -> float:
    """Samples needed to draw one all-inlier sample with probability ``confidence``."""
    good = inlier_ratio**sample_size
    if good >= 1.0:
        return 1.0
    if good <= 0.0:
        return float("inf")
    return float(np.log(1.0 - confidence) / np.log(1.0 - good))


def ransac_motion(
    camera: StereoCamera,
    points_ref: Array,
    points_cur: Array,
    obs_cur: Array,
    information: Array,
    threshold: float,
    rng: np.random.Generator,
    confidence: float = 0.999,
    min_iterations: int = 32,
    max_iterations: int = 512,
    batch: int = 64,
) -> RansacResult:
    """Best 3-point hypothesis for T_cur,ref by inlier count (ties: lower truncated cost).

    points_ref, points_cur: (N, 3) triangulations of the same features in both frames; obs_cur:
    (N, 3) current [u, v, d]; information: (N, 3, 3) residual inverse covariances; a feature is an
    inlier when e^T Sigma^-1 e < threshold.
    """
    n = points_ref.shape[0]
    if n < 3:
        raise ValueError(f"RANSAC needs at least 3 features, got {n}")
    best_t = np.eye(4)
    best_inliers = np.zeros(n, dtype=bool)
    best_score = (-1, -np.inf)
    done = 0
    needed = float(min_iterations)
    while done < min(max(needed, min_iterations), max_iterations):
        size = min(batch, max_iterations - done)
        # three distinct indices per hypothesis
        samples = np.argsort(rng.random((size, n)), axis=1)[:, :3] if n <= 64 else _distinct_triples(rng, n, size)
        hyp = align_points(points_ref[samples], points_cur[samples])
        counts, truncated, inliers = _score(camera, hyp, points_ref, obs_cur, information, threshold)
        k = int(np.lexsort((truncated, -counts))[0])
        score = (int(counts[k]), -float(truncated[k]))
        if score > best_score:
            best_score, best_t, best_inliers = score, hyp[k], inliers[k]
            # local optimisation (LO-RANSAC): refit on all inliers of the new best and keep it if better
            while best_inliers.sum() >= 3:
                refit = align_points(points_ref[None, best_inliers], points_cur[None, best_inliers])
                c, tr, inl = _score(camera, refit, points_ref, obs_cur, information, threshold)
                if (int(c[0]), -float(tr[0])) <= best_score:
                    break
                best_score, best_t, best_inliers = (int(c[0]), -float(tr[0])), refit[0], inl[0]
            needed = required_iterations(best_score[0] / n, confidence)
        done += size
    return RansacResult(best_t, best_inliers, done)


def _score(
    camera: StereoCamera, hyp: Array, points_ref: Array, obs_cur: Array, information: Array, threshold: float
) -> tuple[NDArray[np.int64], Array, NDArray[np.bool_]]:
    """Inlier counts (B,), truncated whitened costs (B,) and inlier masks (B, N) of hypotheses (B, 4, 4)."""
    q = np.einsum("bij,nj->bni", hyp[:, :3, :3], points_ref) + hyp[:, None, :3, 3]
    valid_depth = q[..., 2] > 1e-3
    q[..., 2] = np.where(valid_depth, q[..., 2], 1.0)
    residual = camera.project(q) - obs_cur[None]
    eps2 = np.where(valid_depth, quadratic_form(residual, information), np.inf)
    inliers = eps2 < threshold
    return inliers.sum(axis=1), np.minimum(eps2, threshold).sum(axis=1), inliers


def _distinct_triples(rng: np.random.Generator, n: int, size: int) -> NDArray[np.int64]:
    """(size, 3) index triples without repeats inside a triple."""
    a = rng.integers(0, n, size)
    b = (a + rng.integers(1, n, size)) % n
    c = rng.integers(0, n - 2, size)
    # map c into [0, n) \ {a, b}
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = c + (c >= lo)
    c = c + (c >= hi)
    return np.stack([a, b, c], axis=1)
