"""Typed configuration of the stereo VO pipeline.

One frozen dataclass per stage; :class:`VOConfig` composes them. The ``stereo_vo`` node declares one
ROS parameter per leaf field with the dotted name (``detector.bucket_size``, ``solver.loss`` ...),
and ``config/stereo_vo.yaml`` holds the same defaults; :func:`flatten` / :func:`from_flat` convert.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.config import flatten as _flatten
from pvo_core.config import from_flat as _from_flat

LOSSES = ("l2", "huber", "cauchy", "geman_mcclure", "student_t")
NOISE_MODELS = ("uvd", "stereo")
Array = NDArray[np.float64]


@dataclass(frozen=True)
class DetectorConfig:
    """Corners on the left image, spread by a bucket grid.

    method: "fast" (FAST-9, strongest per bucket) or "gftt" (Shi-Tomasi; ~10x slower, see bench).
    bucket_size: bucket edge (px); features_per_bucket: at most this many live tracks per bucket.
    fast_threshold: FAST intensity threshold. quality_level, block_size: Shi-Tomasi parameters.
    min_distance: no new corner within this of a live track (px).
    border: no feature closer than this to the image edge (px).
    """

    method: str = "fast"
    fast_threshold: int = 20
    bucket_size: int = 48
    features_per_bucket: int = 4
    quality_level: float = 0.005
    min_distance: float = 8.0
    block_size: int = 5
    border: int = 10


@dataclass(frozen=True)
class TrackerConfig:
    """Pyramidal Lucas-Kanade for temporal tracks and stereo matches (the viso2-style circle).

    window, levels: temporal KLT window (px, odd) and pyramid levels above the base image (the
    motion prediction seeds it); stereo_window, stereo_levels: the same for left -> right matches
    (seeded by a coarse block-matching disparity).
    forward_backward / forward_backward_px: a match must track back to within this of its start (px).
    epipolar_px: |v_left - v_right| allowed on rectified images (px).
    min_disparity, max_disparity: accepted stereo disparity range (px).
    """

    window: int = 9
    levels: int = 2
    stereo_window: int = 11
    stereo_levels: int = 2
    iterations: int = 10
    epsilon: float = 0.01
    forward_backward: bool = False
    forward_backward_px: float = 0.5
    epipolar_px: float = 1.0
    min_disparity: float = 0.5
    max_disparity: float = 250.0


@dataclass(frozen=True)
class RansacConfig:
    """3-point RANSAC with closed-form (Arun/Umeyama) alignment of triangulated points.

    inlier_threshold: whitened squared stereo reprojection error eps^2 = e^T Sigma^-1 e below which a
    feature is an inlier (chi-square, 3 dof); confidence: target probability of one all-inlier sample,
    which sets the adaptive iteration count between min_iterations and max_iterations. The threshold is 4
    (2 sigma) rather than a chi-square 4 sigma of 16 because features on moving vehicles pass at 16 and turn the
    estimate (stop 59-60: m-ATE -36 % on the rendered clean drives, -12 % on real KITTI raw tracks).
    """

    inlier_threshold: float = 4.0
    confidence: float = 0.999
    min_iterations: int = 16
    max_iterations: int = 512
    batch: int = 16
    seed: int = 0


@dataclass(frozen=True)
class SolverConfig:
    """Maximum-likelihood motion by Gauss-Newton / IRLS on stereo reprojection error.

    pixel_sigma: default standard deviations of (u, v, d) (px), R = diag(sigma^2) (thesis: 1, 1, 2 px
    -> diag(1, 1, 4) px^2). propagate_reference_noise: whiten each residual with
    R + G R G^T, G the Jacobian of the prediction w.r.t. the reference observation (the point was
    triangulated from noisy pixels too); off gives eq. 3.11 exactly.
    loss / loss_scale: robust loss on the whitened norm eps_i and its constant (nu for student_t).
    relative_cost_tolerance: stop when the relative cost change falls below it (thesis: 1 %).
    inlier_rounds: GN solves at most, re-deciding the inliers at each solution until they settle.
    noise_model: how ``pixel_sigma`` becomes a feature's (u, v, d) covariance. ``uvd`` (the thesis):
    R = diag(sigma_u², sigma_v², sigma_d²), u and d independent — but d = u_left - u_right shares the
    left camera's error, so this trusts the left camera more than the right, and with the left camera as
    the reference the solver reads a yaw out of straight driving (about 0.004 deg per frame at 0.3 px of
    tracking noise, growing with its square; test_solver.py asserts it). ``stereo``: each camera's
    u independent with sigma_u, v with sigma_v: R = [[su², 0, su²], [0, sv², 0], [su², 0, 2 su²]]
    (sigma_d unused); left-right symmetric, so no yaw bias.
    """

    pixel_sigma: tuple[float, float, float] = (1.0, 1.0, 2.0)
    noise_model: str = "uvd"
    propagate_reference_noise: bool = True
    loss: str = "cauchy"
    loss_scale: float = 3.0
    max_iterations: int = 20
    relative_cost_tolerance: float = 0.01
    min_update_norm: float = 1e-10
    inlier_rounds: int = 4


@dataclass(frozen=True)
class TrackingConfig:
    """When a frame counts as lost and what is reported then.

    min_inliers: fewer RANSAC/GN inliers than this -> lost. min_inlier_ratio: likewise as a fraction.
    lost_covariance: variance put on every axis of a lost estimate (m^2 / rad^2).
    max_condition: a GN normal matrix with a larger condition number is degenerate -> lost.
    """

    min_inliers: int = 12
    min_inlier_ratio: float = 0.1
    lost_covariance: float = 9999.0
    max_condition: float = 1e12


@dataclass(frozen=True)
class ProbeSettings:
    """PROBE (thesis ch. 4): a learned per-feature noise model replaces ``solver.pixel_sigma``.

    model: a model directory (``model.npz`` + ``model.yaml``, from ``pvo probe train``) or a shipped model's
    name (``probe_kitti``); "" = off. A PROBE-GK model whitens each feature with its predicted Student-t scale
    and uses its degrees of freedom in a Student-t loss (eq. 4.25) instead of ``solver.loss``; a k-NN model
    scales ``solver.pixel_sigma`` by its beta and drops the features it weighs down most (app. A).
    gate_threshold: the chi-square threshold (3 dof) whose probability gates a PROBE-GK feature under its own
    Student-t (16: 99.9 %). Its covariance is fitted to the tracked features' errors, unlike the nominal
    ``solver.pixel_sigma``, so the tight ``ransac.inlier_threshold`` (a 2 sigma gate of a noise several times the
    tracked features') would drop a quarter of its true errors.
    """

    model: str = ""
    gate_threshold: float = 16.0


@dataclass(frozen=True)
class VOConfig:
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    probe: ProbeSettings = field(default_factory=ProbeSettings)

    def __post_init__(self) -> None:
        validate(self)


def validate(config: VOConfig) -> None:
    """Raise ``ValueError`` naming the parameter for any out-of-range value."""
    checks: list[tuple[bool, str]] = [
        (config.detector.method in ("fast", "gftt"), "detector.method must be fast or gftt"),
        (config.detector.fast_threshold >= 1, "detector.fast_threshold must be >= 1"),
        (
            config.tracker.stereo_window >= 5 and config.tracker.stereo_window % 2 == 1,
            "tracker.stereo_window must be odd and >= 5",
        ),
        (0 <= config.tracker.stereo_levels <= 8, "tracker.stereo_levels must be in [0, 8]"),
        (config.detector.bucket_size >= 8, "detector.bucket_size must be >= 8 px"),
        (config.detector.features_per_bucket >= 1, "detector.features_per_bucket must be >= 1"),
        (0.0 < config.detector.quality_level < 1.0, "detector.quality_level must be in (0, 1)"),
        (config.tracker.window >= 5 and config.tracker.window % 2 == 1, "tracker.window must be odd and >= 5"),
        (0 <= config.tracker.levels <= 8, "tracker.levels must be in [0, 8]"),
        (config.tracker.forward_backward_px > 0.0, "tracker.forward_backward_px must be positive"),
        (config.tracker.epipolar_px > 0.0, "tracker.epipolar_px must be positive"),
        (0.0 < config.tracker.min_disparity < config.tracker.max_disparity, "tracker.min/max_disparity out of order"),
        (config.ransac.inlier_threshold > 0.0, "ransac.inlier_threshold must be positive"),
        (config.probe.gate_threshold > 0.0, "probe.gate_threshold must be positive"),
        (0.0 < config.ransac.confidence < 1.0, "ransac.confidence must be in (0, 1)"),
        (1 <= config.ransac.min_iterations <= config.ransac.max_iterations, "ransac.min/max_iterations out of order"),
        (config.ransac.batch >= 1, "ransac.batch must be >= 1"),
        (
            len(config.solver.pixel_sigma) == 3 and min(config.solver.pixel_sigma) > 0.0,
            "solver.pixel_sigma needs 3 positive values",
        ),
        (config.solver.noise_model in NOISE_MODELS, f"solver.noise_model must be one of {', '.join(NOISE_MODELS)}"),
        (config.solver.loss in LOSSES, f"solver.loss must be one of {', '.join(LOSSES)}"),
        (config.solver.loss_scale > 0.0, "solver.loss_scale must be positive"),
        (config.solver.max_iterations >= 1, "solver.max_iterations must be >= 1"),
        (config.solver.inlier_rounds >= 1, "solver.inlier_rounds must be >= 1"),
        (config.solver.relative_cost_tolerance >= 0.0, "solver.relative_cost_tolerance must be >= 0"),
        (config.tracking.min_inliers >= 3, "tracking.min_inliers must be >= 3"),
        (config.tracking.lost_covariance > 0.0, "tracking.lost_covariance must be positive"),
    ]
    for ok, message in checks:
        if not ok:
            raise ValueError(f"invalid VO configuration: {message}")


def default_feature_covariance(solver: SolverConfig) -> Array:
    """A feature's (u, v, d) covariance (3, 3), px², from ``solver.pixel_sigma`` by ``solver.noise_model``."""
    su, sv, sd = (float(s) for s in solver.pixel_sigma)
    if solver.noise_model == "stereo":
        # u_left and u_right independent, each with su: d = u_left - u_right carries both
        return np.array([[su**2, 0.0, su**2], [0.0, sv**2, 0.0], [su**2, 0.0, 2.0 * su**2]])
    return np.diag([su**2, sv**2, sd**2])


flatten = _flatten  # {"section.leaf": value, ...} of a config; tuples become lists


def from_flat(values: Mapping[str, Any], base: VOConfig | None = None) -> VOConfig:
    """A :class:`VOConfig` from dotted names over ``base`` (defaults); unknown names and bad values are errors."""
    return _from_flat(values, base or VOConfig(), what="VO")
