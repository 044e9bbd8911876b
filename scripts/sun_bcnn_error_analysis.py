"""Where a Sun-BCNN model errs on a corpus's validation split (never its test split): the median vector error per
condition, and over the sunny images by the true sun's elevation (with the median elevation bias) and by its
bearing from the camera's forward axis (with how often the bearing is off by more than 90 deg: ahead taken for
behind).

    python scripts/sun_bcnn_error_analysis.py --corpus data/corpus-sun-ab-gradient --models runs/sun46/base24

Elevation = asin(-y) and bearing = atan2(x, z) of the unit sun vector in the camera optical frame (x right, y down,
z forward); each model in head-mirrored mode, N = 25, as `scripts/sun_bcnn_validation.py` draws it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from pvo_core.readers import read_corpus_manifest, read_kitti_sun_csv
from pvo_core.sun import UNCALIBRATED
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn, predict_sequence

ELEVATION_BANDS = ((-90, 0), (0, 15), (15, 30), (30, 45), (45, 60), (60, 90))
BEARING_BANDS = ((0, 45), (45, 90), (90, 135), (135, 180))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", required=True, help="model directories or shipped names")
    parser.add_argument("--corpus", type=Path, required=True)
    args = parser.parse_args()

    torch.set_num_threads(1)
    sequences = read_corpus_manifest(args.corpus).split("validation")
    if not sequences:
        raise SystemExit(f"{args.corpus}: no validation sequences")
    for name in args.models:
        model, card = load_sun_bcnn(resolve_model(name))
        predicted, truth, conditions = [], [], []
        for k, sequence in enumerate(sequences):
            p = predict_sequence(
                model,
                card,
                sequence.root,
                samples=25,
                seed=1000 + k,
                calibration=UNCALIBRATED,
                cache_dir=args.corpus / ".cache",
            )
            predicted.append(p.vectors)
            truth.append(read_kitti_sun_csv(sequence.root / "sun.csv")[p.frames])
            conditions += [" ".join(sorted(sequence.conditions)) or "clear"] * len(p.frames)
        s_hat, s, condition = np.vstack(predicted), np.vstack(truth), np.array(conditions)
        s_hat /= np.linalg.norm(s_hat, axis=1, keepdims=True)
        error = np.degrees(np.arccos(np.clip((s_hat * s).sum(axis=1), -1.0, 1.0)))
        elevation, bearing = np.degrees(np.arcsin(-s[:, 1])), np.degrees(np.arctan2(s[:, 0], s[:, 2]))
        elevation_hat, bearing_hat = np.degrees(np.arcsin(-s_hat[:, 1])), np.degrees(np.arctan2(s_hat[:, 0], s_hat[:, 2]))
        bearing_error = np.abs((bearing_hat - bearing + 180.0) % 360.0 - 180.0)
        print(f"{name}: {len(error)} images, median vector error {np.median(error):.2f} deg")
        for c in np.unique(condition):
            m = condition == c
            print(f"  {c:<40} {m.sum():5d} images  median {np.median(error[m]):6.2f}")
        sunny = np.array(["overcast" not in c for c in condition])
        for lo, hi in ELEVATION_BANDS:
            m = sunny & (elevation >= lo) & (elevation < hi)
            if m.any():
                print(
                    f"  sunny, elevation [{lo:3d}, {hi:3d}) {m.sum():5d} images  median {np.median(error[m]):6.2f}  "
                    f"elevation bias {np.median(elevation_hat[m] - elevation[m]):6.2f}  "
                    f"bearing error {np.median(bearing_error[m]):6.2f}"
                )
        for lo, hi in BEARING_BANDS:
            m = sunny & (np.abs(bearing) >= lo) & (np.abs(bearing) < hi)
            if m.any():
                print(
                    f"  sunny, |bearing| [{lo:3d}, {hi:3d}) {m.sum():5d} images  median {np.median(error[m]):6.2f}  "
                    f"bearing error {np.median(bearing_error[m]):6.2f}  off by > 90 deg {np.mean(bearing_error[m] > 90):.2f}"
                )


if __name__ == "__main__":
    main()
