"""`pvo eval`: a trajectory against ground truth — the printed table, PNG plots and the run-result record."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.evaluation import Evaluation, aligned_estimate, evaluate, thesis_per_length
from pvo_core.results import RunResult
from pvo_core.trajectory import read_estimate_with_ground_truth

from .errors import PvoError

Array = NDArray[np.float64]


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


def write_plots(ev: Evaluation, gt: Array, est_aligned: Array, out_dir: Path) -> list[Path]:
    """The PNG plots of one evaluation into ``out_dir``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
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


def eval_record(ev: Evaluation, name: str, inputs: dict[str, str]) -> RunResult:
    """The run-result record of one evaluation (figures, the thesis's per-length table)."""
    return RunResult(
        "eval",
        name,
        figures=dict(ev.figures),
        tables={"thesis_per_length": thesis_per_length(ev)},
        inputs=inputs,
    )


def run_eval(
    gt_path: Path, est_path: Path, align: str, out_dir: Path | None, gt_start: int = 0, relative_path: Path | None = None
) -> Evaluation:
    gt_full, est, frames = read_estimate_with_ground_truth(gt_path, est_path, gt_start)
    if len(frames) < len(gt_full):
        print(
            f"pvo: warning: {est_path} has {len(frames)} poses (frames {int(frames[0])}-{int(frames[-1])}) of the "
            f"{len(gt_full)} in {gt_path}; evaluating those frames only",
            file=sys.stderr,
        )
    relative = None
    if relative_path is not None:
        if not relative_path.is_file():
            raise PvoError(f"{relative_path}: relative-motion file not found")
        with np.load(relative_path) as data:
            relative = {k: data[k] for k in ("transforms", "covariances", "ok")}
    ev = evaluate(gt_full, est, frames, align, relative)
    print(format_table(ev))
    if out_dir is not None:
        gt, aligned = aligned_estimate(gt_full, est, frames, align)
        inputs = {"gt": str(gt_path), "est": str(est_path), "align": align, "gt_start": str(gt_start)}
        if relative_path is not None:
            inputs["relative"] = str(relative_path)
        print(f"wrote {eval_record(ev, est_path.stem, inputs).write(out_dir)}")
        for path in write_plots(ev, gt, aligned, out_dir):
            print(f"wrote {path}")
    return ev
