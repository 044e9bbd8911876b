"""HydraNet models' pooled per-pair figures on one split and preset of a corpus (for choosing models on the
validation split; `pvo hydranet eval` gives one sequence's), and the share of the split's pairs that turn more than
2 degrees:

    python scripts/hydranet_split_figures.py --corpus data/corpus-hydra7 --split validation --preset planetary \
        --models runs/hydranet7/urban2-20 runs/hydranet8/urban2-bootstrap-20
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from pvo_core.readers import read_corpus_manifest
from pvo_core.trajectory import read_kitti_poses
from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations, true_relative_rotations
from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--split", default="validation", choices=("train", "validation", "test"))
    parser.add_argument("--preset", default="urban")
    parser.add_argument("--models", nargs="+", type=Path, required=True)
    parser.add_argument("--per-sequence", action="store_true", help="also each sequence's mean error, ANEES and speed")
    args = parser.parse_args()
    torch.set_num_threads(2)
    sequences = [s for s in read_corpus_manifest(args.corpus).split(args.split) if s.preset == args.preset]
    if not sequences:
        raise SystemExit(f"{args.corpus}: no {args.preset} sequence in the {args.split} split")
    for path in args.models:
        try:
            model, card = load_hydranet(path)
        except ModelFileError as error:
            raise SystemExit(str(error)) from None
        quaternions, covariances, truth = [], [], []
        for item in sequences:
            predictions = predict_sequence(model, card, item.root, cache_dir=args.corpus / ".cache")
            poses = read_kitti_poses(item.root / "poses.txt")
            quaternions.append(predictions.quaternions)
            covariances.append(predictions.covariance)
            truth.append(true_relative_rotations(poses, predictions.earlier, predictions.frames))
            if args.per_sequence:
                one = evaluate_rotations(quaternions[-1], covariances[-1], truth[-1])
                step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).mean()
                print(
                    f"  {item.root.name}: mean {one['angle_mean_deg']:.4f} deg, ANEES {one['anees']:.2f}, {step:.3f} m per frame"
                )
        true = np.concatenate(truth)
        f = evaluate_rotations(np.vstack(quaternions), np.concatenate(covariances), true)
        turning = np.degrees(np.arccos(np.clip((np.trace(true, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))) > 2.0
        turns = ""
        if turning.any():
            t = evaluate_rotations(np.vstack(quaternions)[turning], np.concatenate(covariances)[turning], true[turning])
            turns = f"; the turning pairs: mean {t['angle_mean_deg']:.4f} deg, ANEES {t['anees']:.3f}"
        print(
            f"{path}: {args.split} {args.preset}, {len(sequences)} sequences, {int(f['pairs'])} pairs "
            f"({100 * turning.mean():.0f} % turning > 2 deg): mean {f['angle_mean_deg']:.4f} deg, "
            f"median {f['angle_median_deg']:.4f}, NLL {f['nll']:.2f}, ANEES {f['anees']:.3f}{turns}"
        )


if __name__ == "__main__":
    main()
