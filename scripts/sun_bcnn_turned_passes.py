"""Turned cameras at test time for a Sun-BCNN model, on a corpus's validation split (never its test split): each
image also warped as if the camera had yawed by each of ``--yaws`` degrees (the exact homography of `--rotate`'s
training augmentation, `rotate_cameras`), every copy through the head-mirrored MC passes (N = 25 each), the
copies' sun vectors turned back into the image's own frame and all passes pooled by Method I/II — the question
being whether pooling turned views lowers the error as pooling mirrored ones did.

    python scripts/sun_bcnn_turned_passes.py --corpus data/corpus-sun-ab-gradient --model runs/sun46/rotate10-24 \\
        --yaws 0 --yaws=-5,0,5 --yaws=-10,0,10

Prints one line per set of yaws with the figures of `scripts/sun_bcnn_validation.py` (tau infinite). Stop 47:
no set beat the model's own passes (yaw 0), so no such MC mode exists.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch
from pvo_core.readers import read_corpus_manifest, read_kitti_sun_csv
from pvo_pseudosensors.learning.data import FrameDataset, Source
from pvo_pseudosensors.learning.spec import DataSpec
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.evaluation import evaluate_predictions
from pvo_pseudosensors.sun_bcnn.infer import Draws, draw_samples, load_sun_bcnn, predictions_from_draws
from pvo_pseudosensors.sun_bcnn.model import SunBCNNConfig, rotate_cameras, rotation_matrices


def pooled_over_turns(model, images: torch.Tensor, camera: torch.Tensor, yaws: list[float], seed: int) -> Draws:
    """Head-mirrored passes over each turned copy of images (B, C, H, W), their vectors turned back (R^T s)."""
    vectors, inverse = [], []
    count = len(images)
    for j, yaw in enumerate(yaws):
        turn = rotation_matrices(torch.full((count,), math.radians(yaw)), torch.zeros(count), torch.zeros(count))
        turned = images if yaw == 0 else rotate_cameras(images, torch.zeros(count, 3), camera, turn)[0]
        draws = draw_samples(model, turned, 25, seed + 7919 * j, "head-mirrored")
        vectors.append(np.einsum("bji,sbj->sbi", turn.double().numpy(), draws.vectors))
        inverse.append(draws.inverse_concentration)
    return Draws(np.concatenate(vectors), None if inverse[0] is None else np.concatenate(inverse))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="model directory or shipped name")
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument(
        "--yaws", action="append", required=True, help="comma-separated yaws (deg), one set per option (--yaws=-5,0,5)"
    )
    args = parser.parse_args()

    torch.set_num_threads(1)
    model, card = load_sun_bcnn(resolve_model(args.model))
    spec = SunBCNNConfig.from_card(card).spec
    sequences = read_corpus_manifest(args.corpus).split("validation")
    if not sequences:
        raise SystemExit(f"{args.corpus}: no validation sequences")
    for text in args.yaws:
        yaws = [float(y) for y in text.split(",")]
        rows, truth, overcast = [], [], []
        for k, sequence in enumerate(sequences):
            data = FrameDataset(
                [Source(sequence.root, sequence.root.name)],
                DataSpec(spec.size, colour=spec.colour, camera=True),
                args.corpus / ".cache",
            )
            items = [data[i] for i in range(len(data))]
            images = torch.stack([item["left"] for item in items])
            camera = torch.stack([item["camera"] for item in items]).to(images.dtype)
            frames = np.array([int(item["frame"]) for item in items])
            predictions = predictions_from_draws(frames, pooled_over_turns(model, images, camera, yaws, 1000 + k))
            rows.append(predictions.rows())
            truth.append(read_kitti_sun_csv(sequence.root / "sun.csv")[frames])
            overcast.append(np.full(len(frames), "overcast" in sequence.conditions))
        r, t, cloudy = np.vstack(rows), np.vstack(truth), np.concatenate(overcast)
        every, sunny, dull = (evaluate_predictions(r[m], t[m]) for m in (np.ones(len(r), bool), ~cloudy, cloudy))
        print(
            f"yaws {text:<16} {len(r)} images  median {every['vector_median_deg']:6.2f}  mean {every['vector_mean_deg']:6.2f}  "
            f"zenith {every['zenith_median_deg']:6.2f}  azimuth {every['azimuth_median_deg']:6.2f}  ANEES {every['anees']:5.2f}  "
            f"sunny {sunny['vector_median_deg']:6.2f}  overcast {dull['vector_median_deg']:6.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
