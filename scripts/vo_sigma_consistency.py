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
from itertools import pairwise
from pathlib import Path

import numpy as np
from pvo_core.readers import KittiSequence
from pvo_frontend.vo_calibration import read_vo_calibration, resolve_calibration
from pvo_fusion.calibration import AXES, CalibrationSequence, SigmaConsistency, sigma_consistency

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydranet_validation_drives import vo_of


def consistency_table(consistency: SigmaConsistency) -> list[str]:
    """Markdown rows: per axis, ρ and the mean e²/σ² (pair count) in each bin of σ/ρ."""
    edges = consistency.edges
    lines = ["| axis | ρ (p90 of σ) | " + " | ".join(f"σ/ρ {lo:g}–{hi:g}" for lo, hi in pairwise(edges)) + " |"]
    lines.append("|---" * (len(edges) + 1) + "|")
    for i, axis in enumerate(AXES):
        cells = [
            f"{mean:.2f} ({count})" if count else "–"
            for mean, count in zip(consistency.mean_nees[i], consistency.counts[i], strict=True)
        ]
        rho = consistency.reference[i]
        shown = f"{rho:.3g} m" if i < 3 else f"{np.degrees(rho):.3g} deg"
        lines.append(f"| {axis} | {shown} | " + " | ".join(cells) + " |")
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
    by_rig: dict[str, list[CalibrationSequence]] = {}
    for folder in drives:
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        _, relative = vo_of(folder, sequence, args.vo_cache)
        by_rig.setdefault(folder.parent.name, []).append(
            CalibrationSequence(folder.name, sequence.poses, relative["transforms"], relative["covariances"])
        )
    every = [s for sequences in by_rig.values() for s in sequences]
    for name, sequences in [("every rig", every), *sorted(by_rig.items())]:
        consistency = sigma_consistency(sequences, scale)
        print(f"\n{name}: {consistency.counts[0].sum()} pairs, mean e²/σ² (pairs) by σ/ρ\n")
        print("\n".join(consistency_table(consistency)))


if __name__ == "__main__":
    main()
