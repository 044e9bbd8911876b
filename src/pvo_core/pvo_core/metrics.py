"""Trajectory metrics: KITTI devkit segment errors, the thesis's variants, ATE, RPE, NEES.

All poses are ``T_w_c`` (camera -> world), arrays (N, 4, 4), estimate and ground truth index-aligned
(pose k of both taken at the same time). Translations in metres, rotations in radians unless a name
says otherwise.

- :func:`devkit_segment_errors`: KITTI ``evaluate_odometry.cpp`` - lengths 100..800 m, a start every
  10th frame, error ``E = (P_f^-1 P_l)_est^-1 (P_f^-1 P_l)_gt``, t = ||E.t|| / len,
  r = angle(E) / len; the score pools all segments.
- :func:`thesis_segment_errors`: every frame a start, the segment ends at the first frame whose
  distance exceeds the length (``searchsorted(..., "right")``), error ``T_est,rel^-1 T_gt,rel``; the
  score is the mean of the per-length means (thesis / DPC-Net / HydraNet tables).
- :func:`mean_trajectory_errors`: m-ATE and c-ATE (thesis eqs. 6.31-6.32), both trajectories
  expressed relative to the ground truth's first pose.
- :func:`absolute_trajectory_error` (RMSE of positions after optional SE(3)/Sim(3) alignment),
  :func:`relative_pose_errors` (frame-to-frame), :func:`nees` / ANEES.
- :func:`rotation_drift`: frame-pair rotation errors split into their shared mean (a drift) and the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .lie import se3_inverse, se3_log, so3_log

Array = NDArray[np.float64]

SEGMENT_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def _check_pair(gt: ArrayLike, est: ArrayLike) -> tuple[Array, Array]:
    g = np.asarray(gt, dtype=float)
    e = np.asarray(est, dtype=float)
    if g.ndim != 3 or g.shape[1:] != (4, 4) or e.shape != g.shape:
        raise ValueError(f"trajectories must be (N, 4, 4) of equal length, got {g.shape} and {e.shape}")
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(e))):
        raise ValueError("trajectory contains NaN or infinite values")
    return g, e


def path_distances(poses: ArrayLike) -> Array:
    """Cumulative distance travelled (N,) along the positions of ``poses``."""
    p = np.asarray(poses, dtype=float)[:, :3, 3]
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def rotation_angle(rotations: Array) -> Array:
    """Rotation angles (rad) of (..., 3, 3) matrices, clamped like the devkit."""
    trace = np.trace(rotations, axis1=-2, axis2=-1)
    return np.arccos(np.clip(0.5 * (trace - 1.0), -1.0, 1.0))


@dataclass(frozen=True)
class SegmentErrors:
    """Per-segment errors: first frame, rotation error (rad/m), translation error (fraction),
    length (m), speed (m/s) - the columns of the devkit's ``errors/XX.txt``."""

    first: NDArray[np.int64]
    rotation: Array
    translation: Array
    length: Array
    speed: Array

    def __len__(self) -> int:
        return int(self.first.size)

    def as_rows(self) -> Array:
        return np.column_stack([self.first, self.rotation, self.translation, self.length, self.speed])

    def per_length(self) -> dict[float, tuple[float, float, int]]:
        """{length: (mean translation fraction, mean rotation rad/m, count)}."""
        out = {}
        for length in np.unique(self.length):
            m = self.length == length
            out[float(length)] = (float(self.translation[m].mean()), float(self.rotation[m].mean()), int(m.sum()))
        return out


def devkit_segment_errors(
    gt: ArrayLike,
    est: ArrayLike,
    lengths: tuple[float, ...] = SEGMENT_LENGTHS,
    step: int = 10,
    frame_period: float = 0.1,
    has_estimate: NDArray[np.bool_] | None = None,
) -> SegmentErrors:
    """KITTI devkit segment errors (``calcSequenceErrors``).

    ``has_estimate`` (N,) marks frames that have an estimate when the result covers only some
    frames (distances still run over all ground-truth frames); segments touching others are skipped.
    """
    g, e = _check_pair(gt, est)
    dist = path_distances(g)
    have = np.ones(len(g), dtype=bool) if has_estimate is None else np.asarray(has_estimate, dtype=bool)
    firsts, rots, trans, lens, speeds = [], [], [], [], []
    # a general 4x4 inverse, as the devkit: pose files carry ~9 digits, so their rotations are not
    # exactly orthonormal and the transpose would shift near-zero angles by up to ~1e-3 rad
    g_inv = np.linalg.inv(g)
    e_inv = np.linalg.inv(e)
    for first in range(0, len(g), step):
        for length in lengths:
            # first frame whose distance exceeds dist[first] + length (devkit lastFrameFromSegmentLength)
            last = int(np.searchsorted(dist, dist[first] + length, side="right"))
            if last >= len(g) or not (have[first] and have[last]):
                continue
            delta_gt = g_inv[first] @ g[last]
            delta_est = e_inv[first] @ e[last]
            err = np.linalg.inv(delta_est) @ delta_gt
            firsts.append(first)
            rots.append(rotation_angle(err[:3, :3]) / length)
            trans.append(np.linalg.norm(err[:3, 3]) / length)
            lens.append(length)
            speeds.append(length / (frame_period * (last - first + 1)))
    return SegmentErrors(
        np.asarray(firsts, dtype=np.int64), np.asarray(rots), np.asarray(trans), np.asarray(lens, dtype=float), np.asarray(speeds)
    )


def kitti_odom_eval(gt: ArrayLike, frames: ArrayLike, est: ArrayLike, alignment: str = "none") -> SegmentErrors:
    """Segment errors exactly as the KITTI evaluation toolbox (Huangying-Zhan/kitti-odom-eval) computes
    them, for a result with poses ``est`` (M, 4, 4) at ground-truth frame numbers ``frames`` (M,).

    Both trajectories are re-based on the first result frame - the toolbox re-bases only the frames
    that have a result, which shifts the ground-truth distances of the frames before it; kept, so the
    printed figures are reproduced - then the estimate is aligned (``none``, ``se3``, ``sim3`` on the
    positions of the result frames) and the devkit segment errors are computed.
    """
    g = np.asarray(gt, dtype=float)
    idx = np.asarray(frames, dtype=np.int64)
    e = np.asarray(est, dtype=float)
    if e.shape != (idx.size, 4, 4) or idx.size == 0 or idx.min() < 0 or idx.max() >= len(g):
        raise ValueError(
            f"result of {e.shape} at frames [{idx.min() if idx.size else ''}..] does not fit {len(g)} ground-truth poses"
        )
    rebased_gt = g.copy()
    rebased_gt[idx] = np.linalg.inv(g[idx[0]]) @ g[idx]
    rebased_est = np.linalg.inv(e[0]) @ e
    aligned = align_trajectory(rebased_gt[idx], rebased_est, alignment)
    full = np.tile(np.eye(4), (len(g), 1, 1))
    full[idx] = aligned
    have = np.zeros(len(g), dtype=bool)
    have[idx] = True
    return devkit_segment_errors(rebased_gt, full, has_estimate=have)


def devkit_score(errors: SegmentErrors) -> tuple[float, float]:
    """(translation %, rotation deg/m) pooled over all segments; NaN when there are none."""
    if len(errors) == 0:
        return float("nan"), float("nan")
    return 100.0 * float(errors.translation.mean()), float(np.degrees(errors.rotation.mean()))


@dataclass(frozen=True)
class ThesisSegmentErrors:
    """Per-length mean errors (translation fraction, rotation rad/m) and their mean over lengths."""

    lengths: Array
    translation: Array
    rotation: Array
    counts: NDArray[np.int64]

    @property
    def translation_percent(self) -> float:
        valid = self.counts > 0
        return 100.0 * float(self.translation[valid].mean()) if valid.any() else float("nan")

    @property
    def rotation_deg_per_m(self) -> float:
        valid = self.counts > 0
        return float(np.degrees(self.rotation[valid].mean())) if valid.any() else float("nan")


def thesis_segment_errors(gt: ArrayLike, est: ArrayLike, lengths: tuple[float, ...] = SEGMENT_LENGTHS) -> ThesisSegmentErrors:
    """Segment errors as the thesis reports them (every frame a start, mean of per-length means)."""
    g, e = _check_pair(gt, est)
    dist = path_distances(g)
    n = len(g)
    g_inv = se3_inverse_batch(g)
    e_inv = se3_inverse_batch(e)
    t_means, r_means, counts = [], [], []
    starts = np.arange(n)
    for length in lengths:
        ends = np.searchsorted(dist, dist + length, side="right")
        valid = ends < n
        s, t = starts[valid], ends[valid]
        if s.size == 0:
            t_means.append(np.nan)
            r_means.append(np.nan)
            counts.append(0)
            continue
        rel_gt = g_inv[s] @ g[t]
        rel_est = e_inv[s] @ e[t]
        err = se3_inverse_batch(rel_est) @ rel_gt
        t_means.append(float(np.mean(np.linalg.norm(err[:, :3, 3], axis=1) / length)))
        r_means.append(float(np.mean(rotation_angle(err[:, :3, :3]) / length)))
        counts.append(int(s.size))
    return ThesisSegmentErrors(
        np.asarray(lengths, dtype=float), np.asarray(t_means), np.asarray(r_means), np.asarray(counts, dtype=np.int64)
    )


def se3_inverse_batch(poses: Array) -> Array:
    """Inverses of (N, 4, 4) rigid transforms."""
    out = np.zeros_like(poses)
    rt = np.swapaxes(poses[:, :3, :3], 1, 2)
    out[:, :3, :3] = rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", rt, poses[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


@dataclass(frozen=True)
class TrajectoryErrors:
    """Per-frame translational (m) and rotational (rad) errors with their means (m-ATE) and
    cumulative sums (c-ATE)."""

    translation: Array
    rotation: Array

    @property
    def mean_translation(self) -> float:
        return float(self.translation.mean())

    @property
    def mean_rotation(self) -> float:
        return float(self.rotation.mean())

    @property
    def cumulative_translation(self) -> Array:
        return np.cumsum(self.translation)

    @property
    def cumulative_rotation(self) -> Array:
        return np.cumsum(self.rotation)


def mean_trajectory_errors(gt: ArrayLike, est: ArrayLike) -> TrajectoryErrors:
    """m-ATE / c-ATE inputs (thesis eqs. 6.31-6.32): ``E_k = (T_gt0^-1 T_est,k)^-1 (T_gt0^-1 T_gt,k)``.

    The estimate is expressed relative to the ground truth's first pose; no other alignment.
    """
    g, e = _check_pair(gt, est)
    g0_inv = se3_inverse(g[0])
    err = se3_inverse_batch(g0_inv @ e) @ (g0_inv @ g)
    return TrajectoryErrors(np.linalg.norm(err[:, :3, 3], axis=1), rotation_angle(err[:, :3, :3]))


def umeyama_alignment(source: ArrayLike, target: ArrayLike, with_scale: bool = False) -> tuple[Array, Array, float]:
    """(R, t, s) minimising sum ||target - (s R source + t)||^2 for point sets (N, 3) (Umeyama 1991)."""
    x = np.asarray(source, dtype=float)
    y = np.asarray(target, dtype=float)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 3:
        raise ValueError(f"alignment needs two (N>=3, 3) point sets, got {x.shape} and {y.shape}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    cov = yc.T @ xc / x.shape[0]
    u, d, vt = np.linalg.svd(cov)
    s_mat = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s_mat[2, 2] = -1.0
    rotation = u @ s_mat @ vt
    scale = float(np.trace(np.diag(d) @ s_mat) / (xc**2).sum() * x.shape[0]) if with_scale else 1.0
    translation = my - scale * rotation @ mx
    return rotation, translation, scale


def align_trajectory(gt: ArrayLike, est: ArrayLike, mode: str = "none") -> Array:
    """The estimate aligned to the ground truth: ``none``, ``se3`` or ``sim3`` (Umeyama on positions).

    For ``sim3`` the estimate's translations are scaled before the rigid part is applied, as the
    KITTI evaluation toolbox does.
    """
    g, e = _check_pair(gt, est)
    if mode == "none":
        return e.copy()
    if mode not in ("se3", "sim3"):
        raise ValueError(f"unknown alignment {mode!r}: use none, se3 or sim3")
    rotation, translation, scale = umeyama_alignment(e[:, :3, 3], g[:, :3, 3], with_scale=mode == "sim3")
    out = e.copy()
    out[:, :3, 3] *= scale
    align = np.eye(4)
    align[:3, :3] = rotation
    align[:3, 3] = translation
    return align @ out


def absolute_trajectory_error(gt: ArrayLike, est: ArrayLike) -> Array:
    """Position errors (N,) in metres (align first with :func:`align_trajectory` if wanted)."""
    g, e = _check_pair(gt, est)
    return np.linalg.norm(g[:, :3, 3] - e[:, :3, 3], axis=1)


def relative_pose_errors(gt: ArrayLike, est: ArrayLike, delta: int = 1) -> tuple[Array, Array]:
    """Translational (m) and rotational (rad) errors of the ``delta``-frame motions
    ``(T_gt,rel^-1 T_est,rel)``, each (N - delta,)."""
    g, e = _check_pair(gt, est)
    if not 1 <= delta < len(g):
        raise ValueError(f"RPE delta must be in [1, {len(g) - 1}], got {delta}")
    rel_gt = se3_inverse_batch(g[:-delta]) @ g[delta:]
    rel_est = se3_inverse_batch(e[:-delta]) @ e[delta:]
    err = se3_inverse_batch(rel_gt) @ rel_est
    return np.linalg.norm(err[:, :3, 3], axis=1), rotation_angle(err[:, :3, :3])


def relative_motion_errors(gt: ArrayLike, transforms: ArrayLike) -> Array:
    """Left errors xi_k = log(T_est,k T_gt,k^-1) (N-1, 6) of estimated motions T_k,k-1 (N-1, 4, 4)
    against the ground truth poses (N, 4, 4) (T_k,k-1 = T_w,k^-1 T_w,k-1), [rho; phi] order."""
    g = np.asarray(gt, dtype=float)
    t = np.asarray(transforms, dtype=float)
    if t.shape != (len(g) - 1, 4, 4):
        raise ValueError(f"need N-1 = {len(g) - 1} motions for {len(g)} poses, got {t.shape}")
    truth = se3_inverse_batch(g[1:]) @ g[:-1]
    return np.array([se3_log(t[k] @ se3_inverse(truth[k])) for k in range(len(t))])


def nees(errors: ArrayLike, covariances: ArrayLike) -> Array:
    """Normalised estimation error squared e^T Sigma^-1 e per sample, errors (N, d), covariances (N, d, d)."""
    e = np.asarray(errors, dtype=float)
    c = np.asarray(covariances, dtype=float)
    if e.ndim != 2 or c.shape != (*e.shape, e.shape[1]):
        raise ValueError(f"NEES needs errors (N, d) and covariances (N, d, d), got {e.shape} and {c.shape}")
    return np.einsum("ni,ni->n", e, np.linalg.solve(c, e[..., None])[..., 0])


def anees(errors: ArrayLike, covariances: ArrayLike) -> float:
    """Average NEES per degree of freedom (1 for a consistent estimator)."""
    e = np.asarray(errors, dtype=float)
    return float(nees(e, covariances).mean() / e.shape[1])


def rotation_errors_axis_angle(gt_rotations: ArrayLike, est_rotations: ArrayLike) -> Array:
    """Axis-angle vectors log(C_gt^T C_est) (N, 3)."""
    g = np.asarray(gt_rotations, dtype=float)
    e = np.asarray(est_rotations, dtype=float)
    return np.array([so3_log(a.T @ b) for a, b in zip(g, e, strict=True)])


@dataclass(frozen=True)
class RotationDrift:
    """How an estimator's frame-pair rotation errors split into a slow part every pair shares and the rest.

    The errors are e_k = Log(C_true,k^T C_est,k) of each pair's rotation C_{k-1,k} (rad, about the earlier
    camera's x y z: for an optical frame pitch, yaw, roll). ``bias`` (3,) is their mean (rad per pair),
    ``spread`` (3,) their standard deviation about it, ``mean_angle`` the mean of |e_k| (rad). Integrated over
    the ``pairs`` the bias grows as ``pairs * bias`` and the rest as ``sqrt(pairs) * spread``: the first is the
    drift a second sensor without that bias removes, the second what averaging two sensors' noise can remove.
    ``turn_gain`` is the least-squares slope of the yaw error on the true yaw (a sensor reading every turn 2 %
    short has -0.02)."""

    pairs: int
    bias: Array
    spread: Array
    mean_angle: float
    turn_gain: float

    @property
    def integrated_bias(self) -> Array:
        """pairs * bias (rad): what the shared part adds up to over the pairs, per axis."""
        return self.pairs * self.bias

    @property
    def integrated_spread(self) -> Array:
        """sqrt(pairs) * spread (rad): what independent errors of that spread add up to, per axis."""
        return np.sqrt(self.pairs) * self.spread


def rotation_drift(true_rotations: ArrayLike, estimated_rotations: ArrayLike, yaw_axis: int = 1) -> RotationDrift:
    """:class:`RotationDrift` of estimated frame-pair rotations (N, 3, 3) against the true ones (N, 3, 3), both
    C_{k-1,k} (the later frame's axes in the earlier's); ``yaw_axis`` 1 for a camera's optical frame (y down)."""
    truth = np.asarray(true_rotations, dtype=float)
    estimate = np.asarray(estimated_rotations, dtype=float)
    if truth.ndim != 3 or truth.shape[1:] != (3, 3) or estimate.shape != truth.shape or len(truth) < 2:
        raise ValueError(f"need two or more (N, 3, 3) rotations of each, got {truth.shape} and {estimate.shape}")
    errors = rotation_errors_axis_angle(truth, estimate)
    yaw = np.array([so3_log(c)[yaw_axis] for c in truth])
    gain = float(errors[:, yaw_axis] @ yaw / (yaw @ yaw)) if yaw @ yaw > 0 else 0.0
    return RotationDrift(len(errors), errors.mean(axis=0), errors.std(axis=0), float(np.linalg.norm(errors, axis=1).mean()), gain)


def shared_error_covariance(errors_a: ArrayLike, errors_b: ArrayLike) -> Array:
    """Covariance of the error component two estimators share, E[e_a e_b^T] symmetrised and clipped PSD.

    Errors of two *independent* estimators measured against the same ground truth share only the
    ground truth's own error, so this estimates the reference's noise covariance (per sample).
    """
    a = np.asarray(errors_a, dtype=float)
    b = np.asarray(errors_b, dtype=float)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"need two (N, d) error arrays of the same shape, got {a.shape} and {b.shape}")
    cross = a.T @ b / a.shape[0]
    sym = 0.5 * (cross + cross.T)
    w, v = np.linalg.eigh(sym)
    return (v * np.maximum(w, 0.0)) @ v.T


# --------------------------------------------------------------------------- ARMSE / CRMSE (thesis ch. 5)
ARMSE_DEFINITION = (
    "ARMSE = mean over frames k of CRMSE(k) = sqrt(mean_{i<=k} e_i^2), e_k the error against ground truth in the map "
    "frame: trans |r_k - r_gt,k| (m); EN-plane: first two map (ENU) axes only; rot |Log(C_k C_gt,k^T)| (axis-angle, "
    "x1e-3). Estimates are the fixed-lag smoother's final ones."
)


def crmse(errors: ArrayLike) -> Array:
    """Cumulative RMSE curve sqrt(mean_{i<=k} e_i^2) of per-frame errors (N,)."""
    e = np.asarray(errors, dtype=float)
    return np.sqrt(np.cumsum(e**2) / np.arange(1, len(e) + 1))


def map_frame_errors(gt: ArrayLike, est: ArrayLike) -> dict[str, Array]:
    """Per-frame map-frame errors (N,): translation ``trans`` (m), its first-two-axes part ``trans_en`` (m,
    the east-north plane of an ENU map) and the rotation angle ``rot`` (rad) of C_est C_gt^T."""
    from scipy.spatial.transform import Rotation

    g, e = _check_pair(gt, est)
    diff = e[:, :3, 3] - g[:, :3, 3]
    relative = np.einsum("nij,nkj->nik", e[:, :3, :3], g[:, :3, :3])
    return {
        "trans": np.linalg.norm(diff, axis=1),
        "trans_en": np.linalg.norm(diff[:, :2], axis=1),
        # the rotation vector's norm, not arccos of the trace: exact to ~1e-16 rad for small angles
        "rot": np.linalg.norm(Rotation.from_matrix(relative).as_rotvec(), axis=1),
    }


def armse(gt: ArrayLike, est: ArrayLike) -> dict[str, float]:
    """Translational, EN-plane translational (m) and rotational (rad) ARMSE (:data:`ARMSE_DEFINITION`),
    plus the plain RMSEs (``<name>_rmse``)."""
    errors = map_frame_errors(gt, est)
    out = {name: float(crmse(e).mean()) for name, e in errors.items()}
    out.update({f"{name}_rmse": float(np.sqrt(np.mean(e**2))) for name, e in errors.items()})
    return out


def pose_anees(gt: ArrayLike, est: ArrayLike, covariances: ArrayLike, skip_first: bool = True) -> float:
    """ANEES per dof of absolute poses: left errors Log(T_gt T_est^-1) ([rho; phi]) against ROS-order left
    covariances (N, 6, 6). Frames whose covariance is NaN (not queried) are skipped, and so is frame 0
    (a prior, not an estimate) unless ``skip_first`` is False."""
    g = np.asarray(gt, dtype=float)
    e = np.asarray(est, dtype=float)
    c = np.asarray(covariances, dtype=float)
    if g.ndim != 3 or g.shape[1:] != (4, 4) or e.shape != g.shape:
        raise ValueError(f"trajectories must be (N, 4, 4) of equal length, got {g.shape} and {e.shape}")
    if c.shape != (len(g), 6, 6):
        raise ValueError(f"need one 6x6 covariance per pose ({len(g)}), got {c.shape}")
    first = 1 if skip_first else 0
    idx = [k for k in range(first, len(g)) if np.all(np.isfinite(c[k])) and np.all(np.isfinite(e[k]))]
    if not idx:
        raise ValueError("no frame has a finite covariance")
    errors = np.array([se3_log(g[k] @ se3_inverse(e[k])) for k in idx])
    return anees(errors, c[idx])


def mean_relative_change(values: ArrayLike, baseline: ArrayLike) -> float:
    """Mean over items of value / baseline - 1 (negative: better than the baseline)."""
    v = np.asarray(values, dtype=float)
    b = np.asarray(baseline, dtype=float)
    return float(np.mean(v / b - 1.0))


def average_figures(runs: list[dict[str, float]]) -> dict[str, float]:
    """Key-wise mean of several runs' figures (a key missing from some runs is averaged over the others)."""
    if not runs:
        raise ValueError("no runs to average")
    keys = dict.fromkeys(k for run in runs for k in run)
    return {k: float(np.mean([run[k] for run in runs if k in run])) for k in keys}


def max_pose_difference(a: ArrayLike, b: ArrayLike) -> float:
    """Largest absolute element difference of two pose stacks (N, 4, 4), ignoring NaN (frames one lacks)."""
    d = np.abs(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))
    return float(np.nanmax(d)) if np.any(np.isfinite(d)) else float("nan")


def max_position_difference(a: ArrayLike, b: ArrayLike) -> float:
    """Largest distance (m) between the positions of two pose stacks (N, 4, 4), ignoring NaN."""
    d = np.linalg.norm(np.asarray(a, dtype=float)[:, :3, 3] - np.asarray(b, dtype=float)[:, :3, 3], axis=1)
    return float(np.nanmax(d)) if np.any(np.isfinite(d)) else float("nan")


def latency_summary(milliseconds: ArrayLike) -> dict[str, float]:
    """Median, 95th percentile and maximum of latencies (ms); empty input gives NaN."""
    v = np.asarray(milliseconds, dtype=float)
    if v.size == 0:
        return {"median_ms": float("nan"), "p95_ms": float("nan"), "max_ms": float("nan")}
    return {"median_ms": float(np.median(v)), "p95_ms": float(np.percentile(v, 95)), "max_ms": float(v.max())}


def count_finite_poses(poses: ArrayLike) -> int:
    """How many poses of a stack (N, 4, 4) are finite (NaN marks a frame without an estimate)."""
    p = np.asarray(poses, dtype=float)
    return int(np.all(np.isfinite(p.reshape(len(p), -1)), axis=1).sum())


def interval_statistics(times: ArrayLike) -> dict[str, float]:
    """Rate (Hz) of events at ``times`` (s, increasing) from their mean interval, and the intervals' min, max, std (s)."""
    deltas = np.diff(np.asarray(times, dtype=float))
    if deltas.size == 0:
        raise ValueError("a rate needs at least two event times")
    mean = float(deltas.mean())
    return {
        "rate_hz": 1.0 / mean if mean > 0 else float("inf"),
        "min_s": float(deltas.min()),
        "max_s": float(deltas.max()),
        "std_s": float(deltas.std()),
    }


def step_excess(gt: ArrayLike, est: ArrayLike) -> Array:
    """Per step k-1 -> k (N-1,): how much longer or shorter the estimate's position step is than the truth's (m)
    — a jump of the estimate shows as a large value. Steps touching a NaN pose are NaN."""
    g = np.asarray(gt, dtype=float)[:, :3, 3]
    e = np.asarray(est, dtype=float)[:, :3, 3]
    return np.abs(np.linalg.norm(np.diff(e, axis=0), axis=1) - np.linalg.norm(np.diff(g, axis=0), axis=1))


def fault_figures(gt: ArrayLike, est: ArrayLike, times: ArrayLike, sigma_per_second: float) -> dict[str, float]:
    """Figures of a run with a fault against its ground truth (N, 4, 4), NaN where no estimate came: frames
    estimated, position RMSE over them, and the step between consecutive estimated frames (k, k' at ``times``
    in s) that most exceeds the true step (:func:`step_excess`), with the ratio of that excess to 5 sigma of the
    motion model over the step, ``5 sigma_per_second (t_k' - t_k)``: above 1, the estimate jumped."""
    g = np.asarray(gt, dtype=float)
    e = np.asarray(est, dtype=float)
    t = np.asarray(times, dtype=float)
    idx = np.flatnonzero(np.all(np.isfinite(e.reshape(len(e), -1)), axis=1))
    nan = float("nan")
    if len(idx) < 2:
        return {"frames": float(len(idx)), "rmse_m": nan, "max_step_excess_m": nan, "five_sigma_m": nan, "jump_ratio": nan}
    errors = map_frame_errors(g[idx], e[idx])["trans"]
    excess = step_excess(g[idx], e[idx])
    five_sigma = 5.0 * sigma_per_second * np.diff(t[idx])
    worst = int(np.nanargmax(excess / five_sigma))
    return {
        "frames": float(len(idx)),
        "rmse_m": float(np.sqrt(np.mean(errors**2))),
        "max_step_excess_m": float(excess[worst]),
        "five_sigma_m": float(five_sigma[worst]),
        "jump_ratio": float(excess[worst] / five_sigma[worst]),
        "at_frame": float(idx[worst + 1]),
    }
