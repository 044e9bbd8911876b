"""PNG figures of runs (matplotlib, Agg): drawing only, the numbers come from :mod:`pvo_core.metrics`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pvo_core import metrics

Array = NDArray[np.float64]
COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_demo(out: Path, name: str, ground_truth: Array, estimates: dict[str, Array]) -> list[Path]:
    """``trajectory.png`` (top view: camera x right, z forward of the first frame) and ``errors.png`` (position
    and rotation error per frame) of the estimates against the ground truth."""
    plt = pyplot()
    written = []
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.plot(ground_truth[:, 0, 3], ground_truth[:, 2, 3], "k-", lw=2, label="ground truth")
    for (label, poses), colour in zip(estimates.items(), COLOURS, strict=False):
        ax.plot(poses[:, 0, 3], poses[:, 2, 3], "-", color=colour, lw=1.2, label=label)
    ax.plot(ground_truth[0, 0, 3], ground_truth[0, 2, 3], "go", label="start")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    ax.set_title(f"{name}: top view")
    path = out / "trajectory.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for (label, poses), colour in zip(estimates.items(), COLOURS, strict=False):
        errors = metrics.map_frame_errors(ground_truth, poses)
        axes[0].plot(errors["trans"], "-", color=colour, label=label)
        axes[1].plot(np.degrees(errors["rot"]), "-", color=colour, label=label)
    axes[0].set_ylabel("position error (m)")
    axes[1].set_ylabel("rotation error (deg)")
    axes[1].set_xlabel("frame")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"{name}: error against the ground truth per frame")
    path = out / "errors.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    written.append(path)
    return written
