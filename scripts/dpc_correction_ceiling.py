"""What a Δp-frame correction would have to be to meet a fusion target: the long validation drives of one rig (the
default VO, its covariances scaled over ``--vo-span``-frame motions of a corpus's urban validation split, as a card's
fusion weighs them) fused with corrections built from the truth — T_b,a = P_b⁻¹ P_a over consecutive ``--span``-frame
windows — at a fixed covariance: rotation σ per axis (deg), translation σ per axis (m; large: rotation only). Errorless,
or ``--honest``: each window's rotation error drawn from its rotation σ (an unbiased model whose covariance is right, its
errors independent; seeded by the drive's name; the translation σ weighs the translation, which stays errorless). The
mean m-ATE change against the VO alone, per σ:

    pvo dpc-net drives runs/dpc/vlong --split validation
    python scripts/dpc_correction_ceiling.py --rig calib --rot 0.08,0.06,0.05,0.04 --trans 100 \\
        --vo-corpus data/corpus-dpc-calib150lv --vo-span 3 [--honest] [--gate 0.9999]

Each drive's VO run is kept between runs (`scripts/hydranet_validation_drives.py`'s cache).
"""

from __future__ import annotations

import argparse
import sys
import zlib
from pathlib import Path

import numpy as np
from pvo_core.lie import se3_exp
from pvo_core.readers import KittiSequence, read_corpus_manifest
from pvo_core.trajectory import read_kitti_poses
from pvo_frontend.offline import run_sequence
from pvo_frontend.vo import VOConfig
from pvo_tools.experiments.common import TRAJECTORY_METRICS, fusion_figures
from pvo_tools.experiments.hydranet import FIRST_STAMP_NS

from pvo_fusion import (
    CalibrationSequence,
    FusionGraph,
    RelativeMeasurement,
    calibrate_vo,
    ordered_events,
    run_offline,
    vo_measurements,
)
from pvo_fusion.config import from_flat

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydranet_validation_drives import vo_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drives", type=Path, default=Path("runs/dpc/vlong"), help="OUT of `pvo dpc-net drives`")
    parser.add_argument("--rig", default="calib", help="the drives' rig: clean, lens or calib (default calib)")
    parser.add_argument("--rot", default="0.08,0.04", help="rotation sigmas per axis (deg), comma-separated")
    parser.add_argument("--trans", default="100", help="translation sigmas per axis (m), comma-separated (100: none)")
    parser.add_argument("--span", type=int, default=4, help="frames per correction window (default 4, Table 6.1's)")
    parser.add_argument("--gate", type=float, default=0.0, help="inputs.correction.gate_probability (default 0: off)")
    parser.add_argument("--vo-corpus", type=Path, default=Path("data/corpus-dpc-calib150lv"))
    parser.add_argument("--vo-span", type=int, default=3, help="frames over which the VO's covariances are scaled")
    parser.add_argument("--honest", action="store_true", help="rotation errors drawn from the rotation sigma, not none")
    parser.add_argument("--vo-cache", type=Path, default=Path("runs/hydranet-validation-drives/vo"))
    args = parser.parse_args()
    try:
        sigmas = [(float(r), float(t)) for r in args.rot.split(",") for t in args.trans.split(",")]
        assert all(r > 0.0 and t > 0.0 for r, t in sigmas) and args.span >= 1 and args.vo_span >= 1
    except (ValueError, AssertionError):
        parser.error("--rot and --trans take positive sigmas, comma-separated; --span and --vo-span positive frames")
    if not (args.vo_corpus / "manifest.yaml").is_file():
        parser.error(f"--vo-corpus {args.vo_corpus}: no corpus there (its manifest.yaml is missing)")
    drives = sorted(p for p in (args.drives / args.rig).glob("*") if (p / "poses.txt").is_file())
    if not drives:
        parser.error(f"{args.drives / args.rig}: no drive (render them with `pvo dpc-net drives {args.drives}`)")

    sequences = []
    for item in (s for s in read_corpus_manifest(args.vo_corpus).split("validation") if s.preset == "urban"):
        run = run_sequence(KittiSequence(item.root, poses_file=item.root / "poses.txt"), VOConfig())
        relative = run.relative()
        truth = read_kitti_poses(item.root / "poses.txt")
        sequences.append(CalibrationSequence(item.name, truth, relative["transforms"], relative["covariances"]))
    calibration = calibrate_vo(sequences, args.vo_span)
    print(f"VO covariance scales over {args.vo_span} frames on {len(sequences)} sequences: {np.round(calibration.scale, 2)}")

    changes: dict[tuple[float, float], list[list[float]]] = {s: [] for s in sigmas}
    for folder in drives:
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        vo_poses, relative = vo_of(folder, sequence, args.vo_cache)
        truth = sequence.poses
        stamps = FIRST_STAMP_NS + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
        alone = fusion_figures(truth, truth[0] @ vo_poses)
        vo = vo_measurements(stamps, relative["transforms"], relative["covariances"], calibration)
        line = f"{folder.name}: VO {alone['m_ate_trans']:.2f} m {alone['m_ate_rot_deg']:.2f} deg"
        for rot, trans in sigmas:
            corrections = ceiling_corrections(truth, stamps, args.span, rot, trans, args.honest, folder.name)
            graph = FusionGraph(from_flat({"prior.source": "given", "inputs.correction.gate_probability": args.gate}))
            graph.set_initial_pose(truth[0])
            fused = fusion_figures(truth, run_offline(graph, stamps, ordered_events(vo, corrections)).online_poses)
            change = [fused[k] / max(alone[k], 1e-12) - 1.0 for k in TRAJECTORY_METRICS]
            changes[(rot, trans)].append(change)
            line += f"; {rot:g} deg {trans:g} m: {100 * change[0]:+.1f} / {100 * change[1]:+.1f} %"
        print(line, flush=True)
    kind = "honest" if args.honest else "errorless"
    for (rot, trans), rows in changes.items():
        mean = 100 * np.mean(rows, axis=0)
        print(
            f"{kind}, rotation sigma {rot:g} deg, translation {trans:g} m per {args.span}-frame window, gate {args.gate:g}: "
            f"over {len(rows)} drives m-ATE {mean[0]:+.1f} / {mean[1]:+.1f} %, segments {mean[2]:+.1f} / {mean[3]:+.1f} %"
        )


def ceiling_corrections(
    truth: np.ndarray, stamps: np.ndarray, span: int, rot_deg: float, trans_m: float, honest: bool, seed: str
) -> list[tuple[str, RelativeMeasurement]]:
    """Corrections T_b,a = P_b⁻¹ P_a (camera-to-world poses ``truth``, (N, 4, 4)) over consecutive ``span``-frame
    windows, each with the covariance diag(trans², rot²) per axis (ROS order); ``honest``: each rotation perturbed by
    Exp(φ) on the left, φ drawn from N(0, rot² I) (seeded by ``seed``)."""
    covariance = np.diag([trans_m**2] * 3 + [np.radians(rot_deg) ** 2] * 3)
    rng = np.random.default_rng(zlib.crc32(seed.encode()))
    corrections = []
    for a in range(0, len(truth) - span, span):
        b = a + span
        reading = np.linalg.inv(truth[b]) @ truth[a]
        if honest:
            reading = se3_exp(np.r_[np.zeros(3), rng.normal(0.0, np.radians(rot_deg), 3)]) @ reading
        corrections.append(("correction", RelativeMeasurement(int(stamps[b]), int(stamps[a]), reading, covariance)))
    return corrections


if __name__ == "__main__":
    main()
