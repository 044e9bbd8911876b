"""Frame-to-frame errors of the default VO and of the VO with a PROBE-GK model on one corpus sequence, over several
RANSAC seeds: translational ARMSE and, per axis of the camera frame, the mean (bias) and standard deviation of each
frame's relative rotation (mdeg) and translation (mm) error. Also PROBE's noise scaled, the static Student-t of the
model's prior alone, and PROBE with the reference observation's noise propagated — the variants tried on the clean
sequence whose ARMSE PROBE raises (README, PROBE):

    python scripts/probe_frame_errors.py data/corpus-sun/0351 runs/probe-fitted-gate/probe-corpus-model --seeds 6
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from pvo_core.readers import KittiSequence
from pvo_frontend.offline import run_sequence
from pvo_frontend.probe.model import ProbeModel
from pvo_frontend.vo import VOConfig
from pvo_frontend.vo.pipeline import FeatureNoiseEstimate
from scipy.spatial.transform import Rotation

from pvo_core import metrics


def scaled(hook: Any, factor: float, propagate: bool | None = None) -> Any:
    """``hook``'s noise with its covariances times ``factor`` (and the reference noise propagated or not)."""

    def scaled_hook(before: Any, after: Any, image: Any, imu: Any = None) -> Any:
        estimate = hook(before, after, image, imu)
        if estimate is None:
            return None
        changed = replace(estimate, covariances=estimate.covariances * factor)
        return changed if propagate is None else replace(changed, propagate_reference=propagate)

    return scaled_hook


def static_student_t(model: ProbeModel) -> Any:
    """The model's prior alone: the static Student-t every feature without a stored neighbour gets."""
    config = model.estimator.config
    scale = np.diag(np.asarray(config.prior_sigma) ** 2) * config.prior_samples / config.prior_dof

    def hook(before: Any, after: Any, image: Any, imu: Any = None) -> Any:
        count = len(after.left)
        return FeatureNoiseEstimate(
            np.broadcast_to(scale, (count, 3, 3)).copy(), np.full(count, config.prior_dof), "student_t", False
        )

    return hook


def frame_errors(truth: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Per frame pair, the relative motion's error: rotation vector (rad) and translation (m), camera frame (N-1, 6)."""
    rows = []
    for k in range(len(truth) - 1):
        true = np.linalg.inv(truth[k]) @ truth[k + 1]
        estimate = np.linalg.inv(poses[k]) @ poses[k + 1]
        rotation = Rotation.from_matrix(true[:3, :3].T @ estimate[:3, :3]).as_rotvec()
        rows.append(np.r_[rotation, estimate[:3, 3] - true[:3, 3]])
    return np.asarray(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=Path, help="a corpus sequence (poses.txt inside)")
    parser.add_argument("model", type=Path, help="a PROBE-GK model")
    parser.add_argument("--seeds", type=int, default=6, help="RANSAC seeds (default 6)")
    args = parser.parse_args()

    sequence = KittiSequence(args.sequence, poses_file=args.sequence / "poses.txt")
    model = ProbeModel.load(args.model)
    probe = model.feature_noise()
    variants = {
        "default": None,
        "PROBE": probe,
        "PROBE x4": scaled(probe, 4.0),
        "PROBE x16": scaled(probe, 16.0),
        "static Student-t": static_student_t(model),
        "static Student-t x4": scaled(static_student_t(model), 4.0),
        "PROBE, reference propagated": scaled(probe, 1.0, True),
        "PROBE x0.5, reference propagated": scaled(probe, 0.5, True),
    }
    print(f"{sequence.root}: {len(sequence)} frames, {args.seeds} seeds")
    print(f"{'VO noise':<34}{'ARMSE mm':>9}  rotation bias / sd (mdeg, x y z)      translation bias / sd (mm, x y z)")
    baseline = None
    for name, hook in variants.items():
        armse, errors = [], []
        for seed in range(args.seeds):
            config = replace(VOConfig(), ransac=replace(VOConfig().ransac, seed=seed))
            poses = run_sequence(sequence, config, feature_noise=hook).poses
            armse.append(metrics.armse(sequence.poses, poses)["trans"])
            errors.append(frame_errors(sequence.poses, poses))
        stacked = np.concatenate(errors)
        bias, spread = stacked.mean(axis=0), stacked.std(axis=0)
        mean = 1000 * float(np.mean(armse))
        baseline = baseline or mean
        rotation = (
            " ".join(f"{v:5.1f}" for v in np.degrees(bias[:3]) * 1000)
            + " / "
            + " ".join(f"{v:4.1f}" for v in np.degrees(spread[:3]) * 1000)
        )
        translation = " ".join(f"{v:5.2f}" for v in 1000 * bias[3:]) + " / " + " ".join(f"{v:4.2f}" for v in 1000 * spread[3:])
        print(f"{name:<34}{mean:9.2f} ({100 * (mean / baseline - 1):+5.1f} %)  {rotation}   {translation}", flush=True)


if __name__ == "__main__":
    main()
