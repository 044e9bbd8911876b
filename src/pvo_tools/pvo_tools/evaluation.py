"""`pvo eval`: trajectory metrics against ground truth, a printed table, PNG plots and metrics.json."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.trajectory import read_kitti_poses, read_kitti_poses_indexed

from pvo_core import metrics

from .errors import PvoError

Array = NDArray[np.float64]


@dataclass
class Evaluation:
    """Every figure of one evaluation, ready for JSON (floats, lists)."""

    figures: dict[str, Any] = field(default_factory=dict)
    per_frame: dict[str, Array] = field(default_factory=dict)
    segments: metrics.SegmentErrors | None = None
    thesis: metrics.ThesisSegmentErrors | None = None


def load_pair(gt_path: Path, est_path: Path, gt_start: int = 0) -> tuple[Array, Array, NDArray[np.int64]]:
    """Ground truth (full), estimate, and the estimate's ground-truth frame numbers.

    An estimate with frame numbers (13 columns) is placed by them; otherwise its k-th pose is frame
    ``gt_start + k``.
    """
    gt = read_kitti_poses(gt_path)
    frames, est = read_kitti_poses_indexed(est_path)
    if est.shape[0] and np.array_equal(frames, np.arange(len(frames))):
        frames = frames + gt_start
    if frames.max() >= len(gt):
        raise PvoError(f"{est_path}: the estimate reaches frame {int(frames.max())} but {gt_path} has only {len(gt)} poses")
    if len(frames) < 2:
        raise PvoError(f"{est_path}: need at least 2 poses to evaluate")
    return gt, est, frames


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
            raise PvoError(f"relative motions: {len(transforms)} for {len(frames)} poses (need one per frame after the first)")
        errors = metrics.relative_motion_errors(gt, transforms)
        n = metrics.nees(errors[ok], covariances[ok])
        f["nees_frames"] = int(ok.sum())
        f["anees"] = float(n.mean() / 6.0)
        f["nees_median_per_dof"] = float(np.median(n) / 6.0)
        f["anees_translation"] = float(metrics.nees(errors[ok][:, :3], covariances[ok][:, :3, :3]).mean() / 3.0)
        f["anees_rotation"] = float(metrics.nees(errors[ok][:, 3:], covariances[ok][:, 3:, 3:]).mean() / 3.0)
    return ev


def format_table(ev: Evaluation) -> str:
    f = ev.figures
    rows = [
        ("frames / path length", f"{f['frames']} / {f['path_length_m']:.2f} m"),
        ("alignment", f["alignment"]),
        ("end-point drift", f"{f['end_drift_percent']:.3f} % ({f['end_point_error_m']:.3f} m)"),
        ("ATE rmse / mean", f"{f['ate_rmse_m']:.4f} m / {f['ate_mean_m']:.4f} m"),
        ("m-ATE (trans / rot)", f"{f['m_ate_translation_m']:.4f} m / {f['m_ate_rotation_deg']:.4f} deg"),
        ("c-ATE (trans / rot)", f"{f['c_ate_translation_m']:.3f} m / {f['c_ate_rotation_deg']:.3f} deg"),
        ("RPE per frame (mean)", f"{f['rpe_translation_mean_m']:.4f} m / {f['rpe_rotation_mean_deg']:.4f} deg"),
    ]
    if f["devkit_segments"]:
        rows.append(
            (
                "KITTI devkit segments",
                f"{f['devkit_translation_percent']:.4f} % / {f['devkit_rotation_deg_per_100m']:.4f} deg/100m "
                f"({f['devkit_segments']} segments)",
            )
        )
        rows.append(
            (
                "thesis segments (mean of lengths)",
                f"{f['thesis_translation_percent']:.4f} % / {f['thesis_rotation_deg_per_m']:.6f} deg/m",
            )
        )
    else:
        rows.append(("segment errors", "n/a: path shorter than 100 m"))
    if "anees" in f:
        rows.append(
            (
                "ANEES (6 / trans / rot)",
                f"{f['anees']:.2f} / {f['anees_translation']:.2f} / {f['anees_rotation']:.2f} "
                f"(median {f['nees_median_per_dof']:.2f}, {f['nees_frames']} frames)",
            )
        )
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def write_report(ev: Evaluation, gt: Array, est_aligned: Array, out_dir: Path) -> list[Path]:
    """metrics.json and the PNG plots into ``out_dir``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    metrics_path = out_dir / "metrics.json"
    figures = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in ev.figures.items()}
    if ev.thesis is not None:
        figures["thesis_per_length"] = {
            str(int(length)): {"translation_percent": 100 * t, "rotation_deg_per_m": float(np.degrees(r)), "count": int(c)}
            for length, t, r, c in zip(
                ev.thesis.lengths, ev.thesis.translation, ev.thesis.rotation, ev.thesis.counts, strict=True
            )
            if c > 0
        }
    metrics_path.write_text(json.dumps(figures, indent=2) + "\n")
    written.append(metrics_path)

    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(gt[:, 0, 3], gt[:, 2, 3], "k-", label="ground truth")
    ax.plot(est_aligned[:, 0, 3], est_aligned[:, 2, 3], "b-", label="estimate")
    ax.plot(gt[0, 0, 3], gt[0, 2, 3], "go", label="start")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title("Trajectory (top-down, camera x-z)")
    path = out_dir / "trajectory.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    fig, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    axes[0].plot(ev.per_frame["ate_m"], "b-")
    axes[0].set_ylabel("position error (m)")
    axes[1].plot(ev.per_frame["rotation_error_deg"], "r-")
    axes[1].set_ylabel("rotation error (deg)")
    axes[1].set_xlabel("frame")
    axes[0].set_title("Per-frame errors")
    path = out_dir / "errors_per_frame.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    if ev.segments is not None and len(ev.segments):
        per_length = ev.segments.per_length()
        lengths = sorted(per_length)
        axes[0].plot(lengths, [100 * per_length[length][0] for length in lengths], "bs-")
        axes[1].plot(lengths, [np.degrees(per_length[length][1]) * 100 for length in lengths], "rs-")
    else:
        for ax in axes:
            ax.text(0.5, 0.5, "path shorter than 100 m", ha="center", va="center", transform=ax.transAxes)
    axes[0].set_xlabel("segment length (m)")
    axes[0].set_ylabel("translation error (%)")
    axes[1].set_xlabel("segment length (m)")
    axes[1].set_ylabel("rotation error (deg/100 m)")
    fig.suptitle("KITTI devkit segment errors")
    path = out_dir / "errors_vs_length.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    written.append(path)
    return written


def run_eval(
    gt_path: Path, est_path: Path, align: str, out_dir: Path | None, gt_start: int = 0, relative_path: Path | None = None
) -> Evaluation:
    gt_full, est, frames = load_pair(gt_path, est_path, gt_start)
    relative = None
    if relative_path is not None:
        if not relative_path.is_file():
            raise PvoError(f"{relative_path}: relative-motion file not found")
        with np.load(relative_path) as data:
            relative = {k: data[k] for k in ("transforms", "covariances", "ok")}
    ev = evaluate(gt_full, est, frames, align, relative)
    print(format_table(ev))
    if out_dir is not None:
        gt = np.linalg.inv(gt_full[frames[0]]) @ gt_full[frames]
        aligned = metrics.align_trajectory(gt, np.linalg.inv(est[0]) @ est, align)
        for path in write_report(ev, gt, aligned, out_dir):
            print(f"wrote {path}")
    return ev
