"""How much of Sun-BCNN's error along a drive is one offset: per drive, the (zenith, azimuth) errors whitened by the
published covariance — their mean (the drive's offset) and spread about it — and the autocorrelation of the whitened
errors between readings LAG readings apart (one reading every --every frames, as the fusion takes them).

    pvo sun-bcnn predict DIR --model sun_bcnn -o pred.csv
    python scripts/sun_bcnn_error_offsets.py pred.csv DIR [pred2.csv DIR2 ...]

Stop 52 measured with it that the errors are mostly one offset per drive that wanders (the reason for the fusion's
sun offset state, `inputs.sun.bias_sigma`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def autocorrelation(x: np.ndarray, lag: int) -> float:
    x = x - x.mean()
    denominator = float(np.sum(x * x))
    return float(np.sum(x[:-lag] * x[lag:]) / denominator) if lag < len(x) and denominator > 0 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="+", metavar="PRED.csv DIR", help="a prediction file and its sequence (sun.csv)")
    parser.add_argument("--every", type=int, default=10, help="one reading every this many frames (default 10)")
    parser.add_argument("--lags", default="1,5,20", help="lags in readings, comma-separated (default 1,5,20)")
    args = parser.parse_args()
    if len(args.pairs) % 2:
        sys.exit("sun_bcnn_error_offsets.py: give PRED.csv DIR pairs")
    try:
        lags = [int(v) for v in args.lags.split(",")]
    except ValueError:
        lags = []
    if not lags or min(lags) < 1 or args.every < 1:
        sys.exit(f"sun_bcnn_error_offsets.py: --lags {args.lags!r} / --every {args.every}: positive integers")

    from pvo_core.errors import DataFormatError
    from pvo_core.readers import read_kitti_sun_csv, read_sun_predictions_csv
    from pvo_core.sun import zenith_azimuth_residuals

    for pred, folder in zip(args.pairs[::2], args.pairs[1::2], strict=True):
        try:
            rows = read_sun_predictions_csv(Path(pred))
            truth = read_kitti_sun_csv(Path(folder) / "sun.csv")
        except (DataFormatError, OSError) as exc:
            sys.exit(f"sun_bcnn_error_offsets.py: {exc}")
        frames = rows[:, 0].astype(int)
        if frames.max() >= len(truth):
            sys.exit(f"sun_bcnn_error_offsets.py: {pred} has frame {frames.max()}, {folder}/sun.csv {len(truth)} rows")
        residuals = zenith_azimuth_residuals(rows[:, 1:4], truth[frames])
        sigmas = np.sqrt(rows[:, [6, 9]])
        whitened = (residuals / sigmas)[frames % args.every == 0]
        cells = []
        for i, name in enumerate(("zenith", "azimuth")):
            w = whitened[:, i]
            acf = " ".join(f"{autocorrelation(w, lag):+.2f}" for lag in lags)
            degrees = np.degrees(residuals[:, i]).mean()
            cells.append(f"{name} mean {w.mean():+.2f} sd {w.std():.2f} ({degrees:+.1f} deg) acf {acf}")
        print(f"{pred}: {len(whitened)} readings; " + "; ".join(cells))


if __name__ == "__main__":
    main()
