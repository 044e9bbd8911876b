"""How consistent the stereo VO's frame-to-frame covariance is against its own size: per axis (ROS order x y z rx ry
rz), the mean of e²/σ² over the pairs in bins of σ relative to its 90th percentile ρ, on the long validation drives
of `pvo dpc-net drives` (clean, through the thesis's lens, calib.txt's focal length off), σ as the fusion weighs it
(the VO's covariance times a calibration record's scales).

    python scripts/vo_sigma_consistency.py --drives runs/dpc/vlong [--calibration default_vo]

A calibrated VO reads 1 in every bin; a mean scale (what `pvo vo calibrate` learns) makes the average 1 and says
nothing of how the error grows where the VO reports a large σ. The VO's runs are kept as
scripts/hydranet_validation_drives.py keeps them (``--vo-cache``), so either script reuses the other's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from pvo_core.readers import KittiSequence
from pvo_frontend.vo_calibration import read_vo_calibration, resolve_calibration
from pvo_fusion.calibration import CalibrationSequence, span_errors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydranet_validation_drives import vo_of

AXES = ("x", "y", "z", "rx", "ry", "rz")
BINS = ((0.0, 0.5), (0.5, 0.8), (0.8, 1.0), (1.0, 1.5), (1.5, 2.5), (2.5, 5.0), (5.0, np.inf))


def consistency_table(errors: np.ndarray, sigmas: np.ndarray) -> list[str]:
    """Markdown rows: per axis, ρ and the mean e²/σ² (pair count) in each bin of σ/ρ."""
    lines = ["| axis | ρ (p90 of σ) | " + " | ".join(f"σ/ρ {lo:g}–{hi:g}" for lo, hi in BINS) + " |"]
    lines.append("|---" * (len(BINS) + 2) + "|")
    squared = (errors / sigmas) ** 2
    for i, axis in enumerate(AXES):
        rho = float(np.quantile(sigmas[:, i], 0.9))
        ratio = sigmas[:, i] / rho
        cells = []
        for lo, hi in BINS:
            chosen = (ratio >= lo) & (ratio < hi)
            cells.append(f"{squared[chosen, i].mean():.2f} ({chosen.sum()})" if chosen.any() else "–")
        unit = "m" if i < 3 else "deg"
        shown = rho if i < 3 else np.degrees(rho)
        lines.append(f"| {axis} | {shown:.3g} {unit} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", type=Path, default=Path("runs/dpc/vlong"), help="OUT of `pvo dpc-net drives`")
    parser.add_argument(
        "--calibration", default="default_vo", help="the VO calibration record whose scales σ carries ('' for as read)"
    )
    parser.add_argument("--vo-cache", type=Path, default=Path("runs/hydranet-validation-drives/vo"))
    args = parser.parse_args()
    scale = np.ones(6)
    if args.calibration:
        record = read_vo_calibration(resolve_calibration(args.calibration))
        if record is None:
            parser.error(f"--calibration {args.calibration}: no vo_calibration entry there")
        scale = np.asarray(record.covariance_scale)
    drives = sorted(p for p in args.drives.glob("*/*") if (p / "poses.txt").is_file())
    if not drives:
        parser.error(f"--drives {args.drives}: no drive (render them with `pvo dpc-net drives`)")
    by_rig: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for folder in drives:
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        _, relative = vo_of(folder, sequence, args.vo_cache)
        errors, covariances = span_errors(
            CalibrationSequence(folder.name, sequence.poses, relative["transforms"], relative["covariances"]), 1
        )
        sigmas = np.sqrt(np.diagonal(covariances, axis1=1, axis2=2) * scale)
        kept = sigmas.max(axis=1) < 10.0  # lost frames carry the VO's lost covariance, no information
        rig = by_rig.setdefault(folder.parent.name, ([], []))
        rig[0].append(errors[kept])
        rig[1].append(sigmas[kept])
    every = (
        np.concatenate([e for errors, _ in by_rig.values() for e in errors]),
        np.concatenate([s for _, sigmas in by_rig.values() for s in sigmas]),
    )
    for name, (errors, sigmas) in [("every rig", ([every[0]], [every[1]])), *sorted(by_rig.items())]:
        stacked = np.concatenate(errors), np.concatenate(sigmas)
        print(f"\n{name}: {len(stacked[0])} pairs, mean e²/σ² (pairs) by σ/ρ\n")
        print("\n".join(consistency_table(*stacked)))


if __name__ == "__main__":
    main()
