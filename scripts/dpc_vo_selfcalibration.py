"""DPC-Net on long validation drives with the VO's covariance scales learned on each drive itself against the chain of
its corrected windows (a pseudo-truth: no ground truth is read to weigh, only to score) — what an online, adaptive VO
weighing could learn, here from the whole drive, so an upper bound of it. Validation drives only.

    python scripts/dpc_vo_selfcalibration.py --model dpc_net --drives runs/dpc/vlong/lens --spans 3,30,99,249

Prints, per drive and span, the fused online m-ATE change (translation / rotation, %) against the VO alone, and per
span the mean, the worst drive and how many drives both m-ATEs fell on. Spans must be multiples of the card's Δp
(the pseudo-truth exists at the windows' boundaries only).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.trajectory import read_kitti_poses
from pvo_pseudosensors.dpc_net.config import DPCNetConfig
from pvo_pseudosensors.dpc_net.estimator import resolve_model
from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections
from pvo_tools.dpc import correct_sequence, model_vo, vo_run
from pvo_tools.experiments.common import fusion_figures

from pvo_fusion import CalibrationSequence, calibrate_vo


def corrected_chain(start: np.ndarray, vo_poses: np.ndarray, corrections) -> np.ndarray:
    """Poses T_map,k (N, 4, 4): the corrected windows chained from ``start`` at their boundaries, the VO elsewhere."""
    chain = start @ vo_poses
    pose = chain[0].copy()
    for last, transform in zip(corrections.last, corrections.transforms, strict=True):
        pose = pose @ np.linalg.inv(transform)  # T_map,last = T_map,first T_last,first^-1
        chain[last] = pose
    return chain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="DPC-Net model directory or shipped name")
    parser.add_argument("--drives", type=Path, required=True, help="folder of validation drives (sequence directories)")
    parser.add_argument("--spans", default="3,30,99,249", help="VO spans, frames (multiples of the card's Δp)")
    args = parser.parse_args()
    model, card = load_dpc_net(resolve_model(args.model))
    delta = DPCNetConfig.from_card(card).test_delta
    spans = [int(s) for s in args.spans.split(",")]
    if any(s < 1 or s % delta for s in spans):
        parser.error(f"--spans must be positive multiples of the card's Δp {delta}, got {args.spans}")
    changes: dict[int, list[tuple[float, float]]] = {s: [] for s in spans}
    for root in sorted(p for p in args.drives.iterdir() if (p / "poses.txt").is_file()):
        run, _ = vo_run(root, config=model_vo(card))
        truth = read_kitti_poses(root / "poses.txt")
        alone = fusion_figures(truth, truth[0] @ run.poses)
        corrections = predict_corrections(model, card, root, run.poses)
        relative = run.relative()
        pseudo = CalibrationSequence(
            root.name, corrected_chain(truth[0], run.poses, corrections), relative["transforms"], relative["covariances"]
        )
        line = [f"{root.name:>5}"]
        for span in spans:
            fused = correct_sequence(root, model, card, "fusion", calibrate_vo([pseudo], span), run=run, corrections=corrections)
            figures = fusion_figures(truth, truth[0] @ fused.corrected_online)
            change = (
                figures["m_ate_trans"] / alone["m_ate_trans"] - 1.0,
                figures["m_ate_rot_deg"] / alone["m_ate_rot_deg"] - 1.0,
            )
            changes[span].append(change)
            line.append(f"span {span}: {100 * change[0]:+.1f} / {100 * change[1]:+.1f} %")
        print("  ".join(line), flush=True)
    for span in spans:
        c = np.asarray(changes[span])
        print(
            f"span {span}: mean {100 * c.mean(0)[0]:+.1f} / {100 * c.mean(0)[1]:+.1f} %, worst {100 * c.max():+.1f} %, "
            f"both lowered on {int(np.all(c < 0, axis=1).sum())} of {len(c)}"
        )


if __name__ == "__main__":
    main()
