"""The VO's covariance calibrated on a corpus split: per-axis variance scales that make its frame-to-frame
covariances consistent (`pvo_fusion.calibrate_vo`, span 1) for the VO with a given configuration: a PROBE model's
(`pvo probe calibrate`, recorded in its card) or the default VO's (`pvo vo calibrate`, a record of its own); the
record's form is `pvo_frontend.vo_calibration`'s."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pvo_frontend.vo import VOConfig
from pvo_fusion.calibration import AXES

from .errors import PvoError

if TYPE_CHECKING:
    from pvo_fusion.calibration import SigmaConsistency


@dataclass(frozen=True)
class VOCovarianceCalibration:
    """``scale`` (6,): ROS-order variance scales x y z rx ry rz; over ``sequences`` sequences and ``pairs`` frame
    pairs of the corpus whose manifest digest is ``digest``; ``consistency``: the VO with those scales, its e²/σ² by
    the size of its own σ (`pvo_fusion.calibration.sigma_consistency`)."""

    scale: NDArray[np.float64]
    sequences: int
    pairs: int
    digest: str
    consistency: SigmaConsistency | None = None


def calibrate_vo_on_corpus(
    corpus: Path,
    config: VOConfig,
    split: str = "validation",
    preset: str = "urban",
    progress: Callable[[str], None] | None = None,
) -> VOCovarianceCalibration:
    """Run the VO (``config``) over the ``preset`` sequences of the corpus's ``split`` and calibrate its covariance
    (span 1: the frame-to-frame motions the fusion takes)."""
    from pvo_core.readers import KittiSequence, read_corpus_manifest
    from pvo_core.trajectory import read_kitti_poses
    from pvo_frontend.offline import run_sequence
    from pvo_fusion.calibration import sigma_consistency

    from pvo_fusion import CalibrationSequence, calibrate_vo

    try:
        manifest = read_corpus_manifest(corpus)
    except (OSError, ValueError) as exc:
        raise PvoError(f"{corpus}: not a readable corpus ({exc})") from None
    items = [s for s in manifest.split(split) if s.preset == preset]
    if not items:
        raise PvoError(f"{corpus}: no {preset} sequence in the {split} split")
    sequences = []
    for k, item in enumerate(items, 1):
        run = run_sequence(KittiSequence(item.root), config)
        relative = run.relative()
        sequences.append(
            CalibrationSequence(
                item.name, read_kitti_poses(item.root / "poses.txt"), relative["transforms"], relative["covariances"]
            )
        )
        if progress is not None:
            progress(f"  [{k}/{len(items)}] {item.name}: {len(relative['transforms'])} pairs")
    calibration = calibrate_vo(sequences, 1)
    pairs = sum(len(s.motions) for s in sequences)
    scale = np.asarray(calibration.scale, dtype=float)
    try:
        consistency = sigma_consistency(sequences, scale)
    except ValueError:  # every motion lost: the scales say so already
        consistency = None
    return VOCovarianceCalibration(scale, len(items), pairs, manifest.sha256, consistency)


def consistency_lines(consistency: SigmaConsistency) -> list[str]:
    """`SigmaConsistency` as a table to print: per axis, ρ and the mean e²/σ² (pairs) in each bin of σ/ρ."""
    edges = consistency.edges
    names = [f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}" for lo, hi in pairwise(edges)]
    lines = [f"  {'axis':4s} {'rho':>10s}  " + " ".join(f"{n:>12s}" for n in names)]
    for axis, name in enumerate(AXES):
        rho = consistency.reference[axis]
        shown = f"{rho:.3g} m" if axis < 3 else f"{np.degrees(rho):.3g} deg"
        cells = [
            f"{mean:6.2f} ({count})" if count else "-"
            for mean, count in zip(consistency.mean_nees[axis], consistency.counts[axis], strict=True)
        ]
        lines.append(f"  {name:4s} {shown:>10s}  " + " ".join(f"{c:>12s}" for c in cells))
    return lines


def calibration_entry(
    result: VOCovarianceCalibration, config: VOConfig, corpus: Path, split: str, preset: str, command: str
) -> dict[str, Any]:
    """The ``vo_calibration`` entry recording ``result`` for the VO ``config``: its scales (rounded to 4 digits),
    every VO setting it was measured with (the PROBE model left to the record's home), the corpus and the
    command that made it, and how consistent the VO is with those scales by the size of its own σ."""
    from pvo_frontend.vo_calibration import recorded_settings

    entry = {
        "covariance_scale": [round(float(v), 4) for v in result.scale],
        "span_frames": 1,
        "corpus": {"path": str(corpus), "digest": result.digest, "split": split, "preset": preset},
        "sequences": result.sequences,
        "pairs": result.pairs,
        "command": command,
        "vo_settings": recorded_settings(config),
        "notes": "per-axis variance scales (ROS order) that make this VO's frame-to-frame covariances consistent on "
        "those sequences (fusion: inputs.vo.covariance_scale; pvo demo applies them where stereo_vo runs this VO, "
        "these settings)",
    }
    if result.consistency is not None:
        entry["consistency_by_sigma"] = consistency_entry(result.consistency)
    return entry


def consistency_entry(consistency: SigmaConsistency) -> dict[str, Any]:
    """`SigmaConsistency` as a record entry: per axis the mean e²/σ² (3 decimals; null where no pair) and the pairs
    in each bin of σ over ``reference`` (m, rad)."""
    means = np.round(consistency.mean_nees, 3)
    return {
        "reference_quantile": consistency.quantile,
        "reference": [float(f"{v:.4g}") for v in consistency.reference],
        "sigma_over_reference_edges": [float(v) for v in consistency.edges],
        "mean_nees": {a: [None if np.isnan(v) else float(v) for v in row] for a, row in zip(AXES, means, strict=True)},
        "pairs": {a: [int(v) for v in row] for a, row in zip(AXES, consistency.counts, strict=True)},
    }


def calibrate_and_report(corpus: Path, config: VOConfig, split: str, preset: str, label: str) -> VOCovarianceCalibration:
    """`calibrate_vo_on_corpus` as the commands run it: progress on stderr, then one line with the scales on stdout,
    ``label`` saying whose VO they are."""
    import sys

    result = calibrate_vo_on_corpus(corpus, config, split, preset, progress=lambda line: print(line, file=sys.stderr, flush=True))
    listed = " ".join(f"{v:.3g}" for v in result.scale)
    print(
        f"{label}covariance scales (x y z rx ry rz) on {result.sequences} {preset} {split} sequences of {corpus} "
        f"({result.pairs} frame pairs): {listed}"
    )
    if result.consistency is not None:
        print(
            "with them, the mean e^2/sigma^2 (pairs) by sigma / rho, rho the 90th percentile of each axis's sigma "
            "(1 = consistent; far above 1 in the high bins: the VO errs more where it is unsure than it says):"
        )
        print("\n".join(consistency_lines(result.consistency)))
    return result
