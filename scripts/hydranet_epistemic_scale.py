"""How much of a HydraNet's covariance is epistemic, and whether scaling Sigma_e fixes its out-of-distribution
ANEES: Sigma = Sigma_a + lambda * Sigma_e with lambda fitted by maximum likelihood on the in-distribution
*validation* pairs only, then every split and preset's ANEES with lambda = 1 and with the fitted one:

    python scripts/hydranet_epistemic_scale.py --corpus data/corpus-hydra7 --model src/pvo_pseudosensors/models/hydranet
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from hydranet_widening_forms import collect as collect_pairs
from hydranet_widening_forms import load_or_exit
from numpy.typing import NDArray

Array = NDArray[np.float64]


def collect(model, card, corpus: Path, split: str, preset: str) -> tuple[Array, Array, Array]:
    """Left rotation errors log(C_true C_pred^T) (N, 3) rad, Sigma_e and Sigma_a (N, 3, 3) rad² of every pair."""
    pairs = collect_pairs(model, card, corpus, split, preset)
    return pairs["errors"], pairs["epistemic"], pairs["aleatoric"]


def nees(errors: Array, covariance: Array) -> Array:
    return np.einsum("ni,nij,nj->n", errors, np.linalg.inv(covariance), errors)


def negative_log_likelihood(scale: float, errors: Array, epistemic: Array, aleatoric: Array) -> float:
    covariance = aleatoric + scale * epistemic
    return float(np.mean(0.5 * nees(errors, covariance) + 0.5 * np.linalg.slogdet(covariance)[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--in-preset", default="urban", help="the preset the model was trained on (lambda is fitted there)")
    parser.add_argument("--out-preset", default="planetary")
    args = parser.parse_args()
    model, card = load_or_exit(args.model)
    keys = [(split, preset) for split in ("validation", "test") for preset in (args.in_preset, args.out_preset)]
    sets = {key: collect(model, card, args.corpus, *key) for key in keys}
    fit = sets[("validation", args.in_preset)]
    scales = np.exp(np.linspace(np.log(0.1), np.log(1000.0), 121))
    best = float(scales[int(np.argmin([negative_log_likelihood(s, *fit) for s in scales]))])
    print(f"lambda fitted on the {args.in_preset} validation pairs: {best:.1f}")
    for (split, preset), (errors, epistemic, aleatoric) in sets.items():
        share = np.mean(np.trace(epistemic, axis1=1, axis2=2) / np.trace(epistemic + aleatoric, axis1=1, axis2=2))
        as_is = nees(errors, aleatoric + epistemic).mean() / 3.0
        scaled = nees(errors, aleatoric + best * epistemic).mean() / 3.0
        print(
            f"{split} {preset}: {len(errors)} pairs, tr Sigma_e / tr Sigma {100 * share:.2f} %, "
            f"ANEES {as_is:.3f} (lambda 1), {scaled:.3f} (lambda {best:.1f})"
        )


if __name__ == "__main__":
    main()
