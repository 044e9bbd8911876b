"""The stereo VO pipeline object: ``StereoVO(camera, config).process(left, right, stamp)``.

Frames: estimates are of the left camera optical frame (x right, y down, z forward). ``odom`` is the
first camera frame. Each processed frame yields ``T_cur,prev`` (maps coordinates in the previous
camera frame to the current one, thesis T_t = T_c1,w T_c0,w^-1) with a 6x6 covariance over
[rho; phi] of a left perturbation (= ROS order x, y, z, rotX, rotY, rotZ), and the integrated pose
``T_odom,cur = T_odom,prev T_cur,prev^-1``.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.lie import se3_adjoint, se3_exp, se3_inverse, se3_log

from .config import VOConfig, default_feature_covariance
from .features import Image, StereoFeatures, StereoMatcher
from .ransac import ransac_motion
from .solver import OBSERVATION_DIM, RobustLoss, SolveResult, feature_information, quadratic_form, solve_motion

Array = NDArray[np.float64]


@dataclass
class FeatureNoiseEstimate:
    """Per-feature noise for one frame's matched features: (u, v, d) covariances (N, 3, 3) px²; optional
    robust-loss constants (N,), a loss replacing ``solver.loss``, whether to propagate the reference
    observation's noise (replacing ``solver.propagate_reference_noise``) and which features to use."""

    covariances: Array
    loss_scale: Array | None = None
    loss: str | None = None
    propagate_reference: bool | None = None
    keep: NDArray[np.bool_] | None = None


#: (features in the reference frame, the same features in the current frame, the current left image, the IMU
#: reading at the frame [wx, wy, wz, fx, fy, fz] or None) -> the noise, or None for the default noise
FeatureNoise = Callable[[StereoFeatures, StereoFeatures, NDArray[np.uint8], Array | None], FeatureNoiseEstimate | None]


class FrameStatus(enum.Enum):
    FIRST = "first"  # first frame: features initialised, no motion yet
    TRACKING = "tracking"  # motion estimated
    LOST = "lost"  # motion could not be estimated; a huge covariance is reported
    REJECTED = "rejected"  # input refused (bad images, stamp not increasing); state unchanged


@dataclass
class FrameResult:
    """Result of one :meth:`StereoVO.process` call.

    stamp: image time (s). status / message: what happened, in words for ``REJECTED``/``LOST``.
    transform: T_cur,prev (4, 4), None for FIRST and REJECTED. covariance: (6, 6) over [rho; phi]
    (m^2, rad^2), lost_covariance * I when LOST. pose: T_odom,cur (4, 4) after this frame, and
    pose_covariance its (6, 6) covariance (ROS order, left perturbation) accumulated over the motions.
    reference_stamp: the previous frame's stamp. Counts: features tracked around the circle,
    RANSAC/GN inliers, features alive after replenishment. timings: seconds per stage.
    """

    stamp: float
    status: FrameStatus
    message: str = ""
    transform: Array | None = None
    covariance: Array | None = None
    pose: Array = field(default_factory=lambda: np.eye(4))
    pose_covariance: Array = field(default_factory=lambda: np.zeros((6, 6)))
    reference_stamp: float | None = None
    tracked: int = 0
    inliers: int = 0
    features: int = 0
    ransac_iterations: int = 0
    gn_iterations: int = 0
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status is FrameStatus.TRACKING


@dataclass
class _Frame:
    stamp: float
    left: Image
    right: Image
    features: StereoFeatures


@dataclass
class MotionEstimate:
    """Outcome of :func:`estimate_motion`: the GN solution (None on failure), inlier mask, counts,
    per-stage times and, on failure, why."""

    solve: SolveResult | None
    inliers: NDArray[np.bool_]
    ransac_iterations: int = 0
    gn_iterations: int = 0
    failure: str = ""
    timings: dict[str, float] = field(default_factory=dict)


def inlier_gate(threshold: float, loss_name: str, loss_scale: Array | None) -> float | Array:
    """The whitened squared error below which a feature is an inlier: ``threshold`` (a chi-square quantile of
    d = 3 dof for Gaussian noise, 16 ~ 99.9 %), or, for per-feature Student-t noise (PROBE-GK: covariances that
    are the Student-t's scale matrices, ``loss_scale`` its dof nu), the same probability under each feature's
    own distribution, d F_(d, nu)^-1(p) - e^T S^-1 e / d of a Student-t is F-distributed. Gating a Student-t's
    errors at the chi-square quantile would drop a tenth of a dof-3 feature's true errors (and half of a
    Cauchy's) before its heavy-tailed loss could weigh them."""
    if loss_name != "student_t" or loss_scale is None:
        return threshold
    from scipy.stats import chi2, f

    dof = np.asarray(loss_scale, dtype=float)
    probability = chi2.cdf(threshold, OBSERVATION_DIM)
    return OBSERVATION_DIM * f.ppf(probability, OBSERVATION_DIM, dof)


def estimate_motion(
    camera: StereoCamera,
    obs_ref: Array,
    obs_cur: Array,
    covariances: Array,
    config: VOConfig,
    rng: np.random.Generator,
    prediction: Array | None = None,
    loss_scale: Array | None = None,
    loss_name: str | None = None,
    propagate_reference: bool | None = None,
) -> MotionEstimate:
    """T_cur,ref from matched stereo observations [u, v, d] (N, 3) in both frames.

    ``covariances`` (N, 3, 3) are per-feature pixel covariances (the same for both frames; PROBE
    predicts them), ``loss_scale`` optional per-feature robust-loss constants, ``loss_name`` and
    ``propagate_reference`` override ``solver.loss`` and ``solver.propagate_reference_noise``. Steps: 3-point RANSAC
    on the whitened reprojection error, robust GN on its inliers, inliers re-decided at that solution
    and GN again until they settle (``solver.inlier_rounds`` at most); fails (``failure`` set) with
    too few inliers or degenerate geometry.
    """
    cfg = config
    n = obs_ref.shape[0]
    prediction = np.eye(4) if prediction is None else prediction
    out = MotionEstimate(None, np.zeros(n, dtype=bool))
    if n < max(3, cfg.tracking.min_inliers):
        out.failure = f"only {n} features tracked (need {cfg.tracking.min_inliers})"
        return out
    points_ref = camera.triangulate(obs_ref)
    points_cur = camera.triangulate(obs_cur)
    propagate = cfg.solver.propagate_reference_noise if propagate_reference is None else propagate_reference
    cov_ref = covariances if propagate else None

    tic = time.perf_counter()
    loss_name = loss_name or cfg.solver.loss
    # features with learned Student-t noise (PROBE-GK) at their own gate; the rest at the RANSAC threshold
    learned = loss_name == "student_t" and loss_scale is not None
    gate = inlier_gate(cfg.probe.gate_threshold if learned else cfg.ransac.inlier_threshold, loss_name, loss_scale)
    information = feature_information(camera, prediction, obs_ref, covariances, cov_ref)
    ransac = ransac_motion(
        camera,
        points_ref,
        points_cur,
        obs_cur,
        information,
        gate,
        rng,
        cfg.ransac.confidence,
        cfg.ransac.min_iterations,
        cfg.ransac.max_iterations,
        cfg.ransac.batch,
    )
    out.timings["ransac"] = time.perf_counter() - tic
    out.ransac_iterations = ransac.iterations
    inliers = ransac.inliers
    out.inliers = inliers
    n_in = int(inliers.sum())
    if n_in < max(cfg.tracking.min_inliers, cfg.tracking.min_inlier_ratio * n):
        out.failure = f"only {n_in} RANSAC inliers of {n} tracked features"
        return out

    tic = time.perf_counter()
    loss = RobustLoss(loss_name or cfg.solver.loss, cfg.solver.loss_scale if loss_scale is None else loss_scale)
    transform = ransac.transform
    solve: SolveResult | None = None
    # solve on the RANSAC inliers, re-decide the inliers at the solution, and repeat until they settle
    for _ in range(cfg.solver.inlier_rounds):
        information = feature_information(camera, transform, obs_ref, covariances, cov_ref)
        if solve is not None:
            residual = camera.project(points_ref @ transform[:3, :3].T + transform[:3, 3]) - obs_cur
            refined = quadratic_form(residual, information) < gate
            if np.array_equal(refined, inliers) or int(refined.sum()) < cfg.tracking.min_inliers:
                break
            inliers = refined
        loss_in = loss if loss.scale.ndim == 0 else RobustLoss(loss.name, loss.scale[inliers])
        solve = solve_motion(
            camera,
            points_ref[inliers],
            obs_cur[inliers],
            information[inliers],
            loss_in,
            transform,
            cfg.solver.max_iterations,
            cfg.solver.relative_cost_tolerance,
            cfg.solver.min_update_norm,
        )
        transform = solve.transform
        out.gn_iterations += solve.iterations
    out.timings["gauss_newton"] = time.perf_counter() - tic
    out.inliers = inliers
    out.solve = solve
    assert solve is not None
    if (
        not (np.all(np.isfinite(solve.transform)) and np.all(np.isfinite(solve.covariance)))
        or solve.condition > cfg.tracking.max_condition
    ):
        out.failure = f"degenerate geometry (normal-matrix condition {solve.condition:.3g})"
    return out


def _size(image: NDArray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


def as_grey(image: NDArray, what: str) -> NDArray[np.uint8]:
    """A contiguous 2-D uint8 image from mono8 / rgb8 arrays; ``ValueError`` naming ``what`` otherwise."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise ValueError(f"{what} image must be HxW or HxWx3, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise ValueError(f"{what} image must be 8-bit, got {img.dtype}")
    return np.ascontiguousarray(img)


class StereoVO:
    """Frame-to-frame stereo VO on rectified images (thesis ch. 3, app. B).

    ``feature_noise`` (optional) maps the matched features (reference, current) and the current left image
    to a :class:`FeatureNoiseEstimate` - the hook PROBE uses; without it, and without ``probe.model`` in the
    configuration (which loads that model as the hook), every feature gets the covariance that
    ``solver.pixel_sigma`` and ``solver.noise_model`` make (:func:`~pvo_frontend.vo.config.default_feature_covariance`).
    """

    def __init__(self, camera: StereoCamera, config: VOConfig | None = None, feature_noise: FeatureNoise | None = None) -> None:
        self.camera = camera
        self.config = config or VOConfig()
        if feature_noise is None and self.config.probe.model:
            from ..probe.model import ProbeModel, resolve_model

            feature_noise = ProbeModel.load(resolve_model(self.config.probe.model)).feature_noise()

        self.feature_noise = feature_noise
        self.matcher = StereoMatcher(self.config.detector, self.config.tracker)
        self._rng = np.random.default_rng(self.config.ransac.seed)
        self._default_cov = default_feature_covariance(self.config.solver)
        self._previous: _Frame | None = None
        self._motion = np.eye(4)  # last good T_cur,prev, for the KLT prediction
        self._velocity_dt = 0.0
        self.pose = np.eye(4)
        self.pose_covariance = np.zeros((6, 6))
        self.frames = 0
        self._imu: Array | None = None

    def reject(self, stamp: float, message: str) -> FrameResult:
        """A REJECTED result for an input refused before or by :meth:`process`: the state is unchanged."""
        return FrameResult(
            stamp, FrameStatus.REJECTED, message, pose=self.pose.copy(), pose_covariance=self.pose_covariance.copy()
        )

    def process(self, left: NDArray, right: NDArray, stamp: float, imu: Array | None = None) -> FrameResult:
        """Process one rectified stereo pair taken at ``stamp`` (s); ``imu``: the IMU reading at that time,
        [wx, wy, wz] rad/s and [fx, fy, fz] m/s² (only a PROBE model with IMU predictors reads it)."""
        self._imu = None if imu is None else np.asarray(imu, dtype=float).reshape(6)
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        try:
            left_img = as_grey(left, "left")
            right_img = as_grey(right, "right")
        except ValueError as exc:
            return self.reject(stamp, str(exc))
        if left_img.shape != right_img.shape:
            return self.reject(stamp, f"stereo images differ in size: left {_size(left_img)}, right {_size(right_img)}")
        if not np.isfinite(stamp):
            return self.reject(stamp, "stamp is not finite")
        prev = self._previous
        if prev is not None:
            if stamp == prev.stamp:
                return self.reject(stamp, f"repeated frame: stamp {stamp:.9f} s already processed")
            if stamp < prev.stamp:
                return self.reject(stamp, f"stamp goes backwards: {stamp:.9f} s after {prev.stamp:.9f} s")
            if (prev.left.shape[0], prev.left.shape[1]) != left_img.shape:
                return self.reject(stamp, f"image size changed from {_size(prev.left)} to {_size(left_img)}")

        shape = left_img.shape

        result: FrameResult
        if prev is None:
            result = FrameResult(stamp, FrameStatus.FIRST, "first frame", pose=self.pose.copy())
            tracked = StereoFeatures.empty()
        else:
            result, tracked = self._estimate(prev, left_img, right_img, shape, stamp, timings)

        tic = time.perf_counter()
        fresh_points = self.matcher.detect(left_img, tracked.left)
        timings["detection"] = time.perf_counter() - tic
        tic = time.perf_counter()
        fallback = float(np.median(tracked.observations()[:, 2])) if len(tracked) else 10.0
        prior = self.matcher.disparity_prior(left_img, right_img) if fresh_points.shape[0] else np.zeros((1, 1))
        fresh = self.matcher.match_stereo(left_img, right_img, fresh_points, shape, prior, fallback)
        timings["stereo_matching"] = time.perf_counter() - tic
        features = StereoFeatures.concatenate(tracked, fresh)
        self._previous = _Frame(stamp, left_img, right_img, features)
        self.frames += 1
        result.features = len(features)
        timings["total"] = time.perf_counter() - t_start
        result.timings = timings
        return result

    def _estimate(
        self,
        prev: _Frame,
        left_img: Image,
        right_img: Image,
        shape: tuple[int, int],
        stamp: float,
        timings: dict[str, float],
    ) -> tuple[FrameResult, StereoFeatures]:
        cfg = self.config
        cam = self.camera
        dt = stamp - prev.stamp
        prediction = self._predicted_motion(dt)
        tic = time.perf_counter()
        flow = self._predicted_flow(prev.features, prediction)
        before, after = self.matcher.track(prev.features, prev.left, prev.right, left_img, right_img, shape, flow)
        timings["tracking"] = time.perf_counter() - tic
        n = len(after)
        base = FrameResult(stamp, FrameStatus.TRACKING, reference_stamp=prev.stamp, tracked=n)
        if n < cfg.tracking.min_inliers:
            return self._lost(base, f"only {n} features tracked (need {cfg.tracking.min_inliers})", prediction), after

        noise = FeatureNoiseEstimate(np.broadcast_to(self._default_cov, (n, 3, 3)))
        if self.feature_noise is not None:
            tic = time.perf_counter()
            noise = self.feature_noise(before, after, left_img, self._imu) or noise
            timings["feature_noise"] = time.perf_counter() - tic
            if noise.keep is not None and int(noise.keep.sum()) >= cfg.tracking.min_inliers:
                before, after = before.subset(noise.keep), after.subset(noise.keep)
                scale = None if noise.loss_scale is None else noise.loss_scale[noise.keep]
                noise = FeatureNoiseEstimate(noise.covariances[noise.keep], scale, noise.loss, noise.propagate_reference)
        motion = estimate_motion(
            cam,
            before.observations(),
            after.observations(),
            noise.covariances,
            cfg,
            self._rng,
            prediction,
            noise.loss_scale,
            noise.loss,
            noise.propagate_reference,
        )
        timings.update(motion.timings)
        base.ransac_iterations = motion.ransac_iterations
        base.gn_iterations = motion.gn_iterations
        base.inliers = int(motion.inliers.sum())
        if motion.failure:
            return self._lost(base, motion.failure, prediction), after
        solve = motion.solve
        assert solve is not None
        inliers = motion.inliers
        base.transform = solve.transform
        base.covariance = solve.covariance
        self._integrate(solve.transform, solve.covariance)
        base.pose = self.pose.copy()
        base.pose_covariance = self.pose_covariance.copy()
        self._motion = solve.transform
        self._velocity_dt = dt
        # keep only the features that agreed with the motion as tracks for the next frame
        return base, after.subset(inliers)

    def _lost(self, result: FrameResult, why: str, prediction: Array) -> FrameResult:
        """Report a lost frame: constant-velocity guess, huge covariance, pose carried on by the guess."""
        result.status = FrameStatus.LOST
        result.message = why
        result.transform = prediction
        result.covariance = self.config.tracking.lost_covariance * np.eye(6)
        self._integrate(prediction, result.covariance)
        result.pose = self.pose.copy()
        result.pose_covariance = self.pose_covariance.copy()
        return result

    def _integrate(self, transform: Array, covariance: Array) -> None:
        """T_odom,k = T_odom,k-1 T_k,k-1^-1. A left perturbation xi of T_k,k-1 moves T_odom,k by
        -Ad(T_odom,k) xi, so the pose covariance grows by Ad Sigma Ad^T."""
        self.pose = self.pose @ se3_inverse(transform)
        adjoint = se3_adjoint(self.pose)
        self.pose_covariance = self.pose_covariance + adjoint @ covariance @ adjoint.T

    def _predicted_motion(self, dt: float) -> Array:
        """Constant-velocity T_cur,prev over ``dt`` from the last good motion (identity at start)."""
        if self._velocity_dt <= 0.0:
            return np.eye(4)
        ratio = min(dt / self._velocity_dt, 5.0)
        return se3_exp(ratio * se3_log(self._motion))

    def _predicted_flow(self, features: StereoFeatures, prediction: Array) -> Array | None:
        """Image motion (N, 2) of the left features under the predicted motion, None when unknown."""
        if len(features) == 0 or np.allclose(prediction, np.eye(4)):
            return None
        obs = features.observations()
        q = self.camera.triangulate(obs) @ prediction[:3, :3].T + prediction[:3, 3]
        ok = q[:, 2] > 0.1
        flow = np.zeros((len(features), 2))
        flow[ok] = self.camera.project(q[ok])[:, :2] - obs[ok, :2]
        return flow
