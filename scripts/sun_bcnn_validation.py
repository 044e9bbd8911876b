"""Sun-BCNN models side by side on a corpus's validation split (never its test split): every validation image
through each model in one MC mode, as the node draws them, and Table 5.1's figures over all images, the sunny
and the overcast ones — the comparison behind choosing a model to ship.

    python scripts/sun_bcnn_validation.py --models sun_bcnn runs/sun8/more runs/sun8/more-bn --corpus data/corpus-sun

Prints one line per model: images, median and mean vector error, zenith and azimuth median (deg), the
uncalibrated ANEES (tau infinite: the covariance the MC passes and the aleatoric output give), and the
sunny / overcast medians. ``--decode-radius 4 6 inf`` evaluates a classifying model at other decode radii.
``--split train`` reads training sequences instead: how well a network fits what it learned from, beside how well it
reads new ones.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch
from pvo_core.readers import read_corpus_manifest, read_kitti_sun_csv
from pvo_core.sun import UNCALIBRATED
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.evaluation import evaluate_predictions
from pvo_pseudosensors.sun_bcnn.infer import DEFAULT_MODE, MODES, load_sun_bcnn, predict_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["sun_bcnn"], help="model directories or shipped names")
    parser.add_argument("--corpus", type=Path, default=Path("data/corpus-sun"))
    parser.add_argument("--mode", default=DEFAULT_MODE, choices=MODES, help=f"MC mode (default {DEFAULT_MODE})")
    parser.add_argument("--samples", type=int, default=25, help="MC passes per image (default 25, the node's)")
    parser.add_argument("--max-sequences", type=int, help="the first N sequences of the split only")
    parser.add_argument(
        "--split",
        default="validation",
        choices=("validation", "train"),
        help="the corpus split read (default validation; train shows how well the network fits what it learned from; "
        "the test split is read by `pvo experiment sun-bcnn` only)",
    )
    parser.add_argument(
        "--decode-radius",
        type=float,
        nargs="+",
        help="classifying models: evaluate each at these decode radii (bin spacings; inf: the whole sphere) instead of its own",
    )
    args = parser.parse_args()

    torch.set_num_threads(1)
    sequences = read_corpus_manifest(args.corpus).split(args.split)[: args.max_sequences or None]
    if not sequences:
        raise SystemExit(f"{args.corpus}: no {args.split} sequences")
    cloudy_sequences = sum("overcast" in s.conditions for s in sequences)
    print(
        f"{args.corpus}: {len(sequences)} {args.split} sequences ({cloudy_sequences} overcast); mode {args.mode}, "
        f"{args.samples} passes, tau infinite"
    )
    runs = [(name, radius) for name in args.models for radius in (args.decode_radius or [None])]
    for name, radius in runs:
        model, card = load_sun_bcnn(resolve_model(name))
        if radius is not None:
            if not model.config.bins:
                raise SystemExit(f"{name}: --decode-radius needs a classifying model (bins > 0)")
            try:
                model.config = dataclasses.replace(model.config, decode_radius=radius)
            except ValueError as exc:
                raise SystemExit(f"--decode-radius: {exc}") from None
            name = f"{name}@{radius:g}"
        rows, truth, cloudy_rows = [], [], []
        for k, sequence in enumerate(sequences):
            predictions = predict_sequence(
                model,
                card,
                sequence.root,
                samples=args.samples,
                seed=1000 + k,
                mode=args.mode,
                calibration=UNCALIBRATED,
                cache_dir=args.corpus / ".cache",
            )
            rows.append(predictions.rows())
            truth.append(read_kitti_sun_csv(sequence.root / "sun.csv")[predictions.frames])
            cloudy_rows.append(np.full(len(predictions.frames), "overcast" in sequence.conditions))
        r, t, overcast = np.vstack(rows), np.vstack(truth), np.concatenate(cloudy_rows)
        every = evaluate_predictions(r, t)
        sunny = evaluate_predictions(r[~overcast], t[~overcast]) if (~overcast).any() else None
        cloudy = evaluate_predictions(r[overcast], t[overcast]) if overcast.any() else None
        print(
            f"{name:<28} {len(r)} images  median {every['vector_median_deg']:7.3f}  mean {every['vector_mean_deg']:6.2f}  "
            f"zenith {every['zenith_median_deg']:6.2f}  azimuth {every['azimuth_median_deg']:6.2f}  "
            f"ANEES {every['anees']:5.2f}  sunny {sunny['vector_median_deg'] if sunny else float('nan'):6.2f}  "
            f"overcast {cloudy['vector_median_deg'] if cloudy else float('nan'):6.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
