"""Trajectory evaluation against ground truth: every figure of :mod:`pvo_core.metrics` for one estimate.

Used by ``pvo eval``, the experiments and the demo; returns an :class:`Evaluation` whose ``figures`` go
into the run-result record (:mod:`pvo_core.results`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import metrics
from .lie import se3_inverse, se3_log

Array = NDArray[np.float64]


@dataclass
class Evaluation:
    """Every figure of one evaluation, ready for JSON (floats, lists)."""

    figures: dict[str, Any] = field(default_factory=dict)
    per_frame: dict[str, Array] = field(default_factory=dict)
    segments: metrics.SegmentErrors | None = None
    thesis: metrics.ThesisSegmentErrors | None = None


def evaluate(
    gt_full: Array, est: Array, frames: NDArray[np.int64], align: str = "none", relative: dict[str, Array] | None = None
) -> Evaluation:
    """All metrics of the estimate at ``frames`` against ``gt_full``.

    ``relative`` (optional): ``transforms`` (K, 4, 4) T_k,k-1, ``covariances`` (K, 6, 6) and ``ok``
    (K,) per frame after the first, for NEES/ANEES of the reported covariances.
    """
    gt = gt_full[frames]
    rebased_est = np.linalg.inv(est[0]) @ est
    rebased_gt = np.linalg.inv(gt[0]) @ gt
    aligned = metrics.align_trajectory(rebased_gt, rebased_est, align)
    ev = Evaluation()
    f = ev.figures
    dist = metrics.path_distances(rebased_gt)
    f["frames"] = len(frames)
    f["path_length_m"] = float(dist[-1])
    f["alignment"] = align
    end_error = float(np.linalg.norm(aligned[-1, :3, 3] - rebased_gt[-1, :3, 3]))
    f["end_point_error_m"] = end_error
    f["end_drift_percent"] = 100.0 * end_error / dist[-1] if dist[-1] > 0 else float("nan")
    ate = metrics.absolute_trajectory_error(rebased_gt, aligned)
    f["ate_rmse_m"] = float(np.sqrt(np.mean(ate**2)))
    f["ate_mean_m"] = float(ate.mean())
    traj = metrics.mean_trajectory_errors(rebased_gt, aligned)
    f["m_ate_translation_m"] = traj.mean_translation
    f["m_ate_rotation_deg"] = float(np.degrees(traj.mean_rotation))
    f["c_ate_translation_m"] = float(traj.cumulative_translation[-1])
    f["c_ate_rotation_deg"] = float(np.degrees(traj.cumulative_rotation[-1]))
    rpe_t, rpe_r = metrics.relative_pose_errors(rebased_gt, aligned)
    f["rpe_translation_mean_m"] = float(rpe_t.mean())
    f["rpe_translation_rmse_m"] = float(np.sqrt(np.mean(rpe_t**2)))
    f["rpe_rotation_mean_deg"] = float(np.degrees(rpe_r.mean()))
    f["rpe_rotation_rmse_deg"] = float(np.degrees(np.sqrt(np.mean(rpe_r**2))))
    ev.segments = metrics.kitti_odom_eval(gt_full, frames, est, align)
    t, r = metrics.devkit_score(ev.segments)
    f["devkit_segments"] = len(ev.segments)
    f["devkit_translation_percent"] = t
    f["devkit_rotation_deg_per_100m"] = 100.0 * r
    ev.thesis = metrics.thesis_segment_errors(rebased_gt, aligned)
    f["thesis_translation_percent"] = ev.thesis.translation_percent
    f["thesis_rotation_deg_per_m"] = ev.thesis.rotation_deg_per_m
    ev.per_frame = {"ate_m": ate, "rotation_error_deg": np.degrees(traj.rotation), "distance_m": dist}
    if relative is not None:
        transforms, covariances, ok = relative["transforms"], relative["covariances"], relative["ok"].astype(bool)
        if len(transforms) != len(frames) - 1:
            raise ValueError(f"relative motions: {len(transforms)} for {len(frames)} poses (need one per frame after the first)")
        errors = metrics.relative_motion_errors(gt, transforms)
        n = metrics.nees(errors[ok], covariances[ok])
        f["nees_frames"] = int(ok.sum())
        f["anees"] = float(n.mean() / 6.0)
        f["nees_median_per_dof"] = float(np.median(n) / 6.0)
        f["anees_translation"] = float(metrics.nees(errors[ok][:, :3], covariances[ok][:, :3, :3]).mean() / 3.0)
        f["anees_rotation"] = float(metrics.nees(errors[ok][:, 3:], covariances[ok][:, 3:, 3:]).mean() / 3.0)
    return ev


def thesis_per_length(ev: Evaluation) -> dict[str, dict[str, float]]:
    """The thesis segment errors per segment length (m): translation %, rotation deg/m, count."""
    if ev.thesis is None:
        return {}
    return {
        str(int(length)): {"translation_percent": 100 * t, "rotation_deg_per_m": float(np.degrees(r)), "count": int(c)}
        for length, t, r, c in zip(ev.thesis.lengths, ev.thesis.translation, ev.thesis.rotation, ev.thesis.counts, strict=True)
        if c > 0
    }


def aligned_estimate(gt_full: Array, est: Array, frames: NDArray[np.int64], align: str = "none") -> tuple[Array, Array]:
    """Ground truth at ``frames`` and the estimate, both relative to their first pose, the estimate aligned."""
    gt = np.linalg.inv(gt_full[frames[0]]) @ gt_full[frames]
    return gt, metrics.align_trajectory(gt, np.linalg.inv(est[0]) @ est, align)


def pose_consistency(gt: Array, est: Array, covariances: Array) -> dict[str, Any]:
    """ANEES per dof of absolute poses against their covariances (ROS order, left), overall and per block."""
    out: dict[str, Any] = {"pose_anees": metrics.pose_anees(gt, est, covariances)}
    idx = [k for k in range(1, len(gt)) if np.all(np.isfinite(covariances[k])) and np.all(np.isfinite(est[k]))]
    errors = np.array([se3_log(gt[k] @ se3_inverse(est[k])) for k in idx])
    c = covariances[idx]
    out["pose_anees_translation"] = metrics.anees(errors[:, :3], c[:, :3, :3])
    out["pose_anees_rotation"] = metrics.anees(errors[:, 3:], c[:, 3:, 3:])
    return out
