"""Five forms of HydraNet's spread widening compared on *validation* pairs (stop 67's rule chose among them):

    Sigma = Sigma_e + Sigma_a (1 + gamma max(0, r - 1)),   r = tr Sigma_e / reference, by form:

    median      the in-distribution median tr Sigma_e (stop 66's pilot)
    aleatoric   (tr Sigma_e / tr Sigma_a) over its in-distribution median
    by-angle    the median tr Sigma_e of in-distribution pairs whose predicted rotation is as large (ten bins)
    p90         the in-distribution 90th percentile of tr Sigma_e (shipped since stop 67)
    by-angle90  each bin's 90th percentile

References from the in-distribution preset's validation pairs, gamma by maximum likelihood on the shift preset's
validation pairs (0..20); printed per form: gamma, and ANEES of every (split, preset) read, over all pairs and over the
tenth that turn most (the criterion that ruled out the median form: its widest turns read four times too wide).

    python scripts/hydranet_widening_forms.py --corpus data/corpus-hydra7 --model runs/COPY_WITHOUT_WIDENING
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.readers import read_corpus_manifest
from pvo_core.trajectory import read_kitti_poses
from pvo_pseudosensors.hydranet.evaluation import true_relative_rotations
from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]
GAMMAS = np.linspace(0.0, 20.0, 2001)


def collect(model: torch.nn.Module, card: object, corpus: Path, split: str, preset: str) -> dict[str, Array]:
    """Per pair: rotation error log(C_true C_pred^T) (N, 3) rad, Sigma_e and Sigma_a (N, 3, 3) rad², the true and
    the predicted rotation angle (N,) deg."""
    parts: dict[str, list[Array]] = {k: [] for k in ("errors", "epistemic", "aleatoric", "true_deg", "predicted_deg")}
    for item in read_corpus_manifest(corpus).split(split):
        if item.preset != preset:
            continue
        p = predict_sequence(model, card, item.root, cache_dir=corpus / ".cache")
        truth = true_relative_rotations(read_kitti_poses(item.root / "poses.txt"), p.earlier, p.frames)
        predicted = Rotation.from_quat(p.quaternions[:, [1, 2, 3, 0]]).as_matrix()
        parts["errors"].append(Rotation.from_matrix(truth @ np.transpose(predicted, (0, 2, 1))).as_rotvec())
        parts["epistemic"].append(p.epistemic)
        parts["aleatoric"].append(p.aleatoric)
        parts["true_deg"].append(np.degrees(Rotation.from_matrix(truth).magnitude()))
        parts["predicted_deg"].append(np.degrees(Rotation.from_matrix(predicted).magnitude()))
    if not parts["errors"]:
        raise SystemExit(f"{corpus}: no {preset} sequence in the {split} split")
    return {k: np.concatenate(v) for k, v in parts.items()}


def load_or_exit(directory: Path) -> tuple[torch.nn.Module, object]:
    """The model and its card, on two threads; a model file it cannot read is one line and exit status 1."""
    torch.set_num_threads(2)
    try:
        return load_hydranet(directory)
    except ModelFileError as error:
        raise SystemExit(str(error)) from None


def trace(matrices: Array) -> Array:
    return np.trace(matrices, axis1=-2, axis2=-1)


def ratio_forms(reference: dict[str, Array]) -> dict[str, Callable[[dict[str, Array]], Array]]:
    """Each form's r of a pair set, its reference taken from the in-distribution ``reference`` pairs."""
    spread = trace(reference["epistemic"])
    relative = spread / trace(reference["aleatoric"])
    edges = np.quantile(reference["predicted_deg"], np.linspace(0.0, 1.0, 11))
    bins = [(reference["predicted_deg"] >= lo) & (reference["predicted_deg"] <= hi) for lo, hi in itertools.pairwise(edges)]
    centres = np.array([np.median(reference["predicted_deg"][b]) for b in bins])
    by_angle = {q: np.log([np.quantile(spread[b], q) for b in bins]) for q in (0.5, 0.9)}

    def angle_form(q: float) -> Callable[[dict[str, Array]], Array]:
        return lambda s: trace(s["epistemic"]) / np.exp(np.interp(s["predicted_deg"], centres, by_angle[q]))

    return {
        "median": lambda s: trace(s["epistemic"]) / np.median(spread),
        "aleatoric": lambda s: trace(s["epistemic"]) / trace(s["aleatoric"]) / np.median(relative),
        "by-angle": angle_form(0.5),
        "p90": lambda s: trace(s["epistemic"]) / np.quantile(spread, 0.9),
        "by-angle90": angle_form(0.9),
    }


def covariance(ratio: Array | None, gamma: float, pairs: dict[str, Array]) -> Array:
    if ratio is None:
        return pairs["epistemic"] + pairs["aleatoric"]
    factor = 1.0 + gamma * np.maximum(0.0, ratio - 1.0)
    return pairs["epistemic"] + pairs["aleatoric"] * factor[:, None, None]


def nees(errors: Array, covariances: Array) -> Array:
    return np.einsum("ni,nij,nj->n", errors, np.linalg.inv(covariances), errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--model", type=Path, required=True, help="a HydraNet model (any widening in its card is ignored)")
    parser.add_argument("--in-preset", default="urban", help="the preset the model was trained on (the references)")
    parser.add_argument("--shift-preset", default="planetary", help="the shift gamma is fitted on")
    parser.add_argument("--splits", default="validation", help="splits to read, comma-separated (choose on validation)")
    args = parser.parse_args()
    model, card = load_or_exit(args.model)
    model.widening = None
    splits = args.splits.split(",")
    sets = {(s, p): collect(model, card, args.corpus, s, p) for s in splits for p in (args.in_preset, args.shift_preset)}
    forms = ratio_forms(collect(model, card, args.corpus, "validation", args.in_preset))
    shift = collect(model, card, args.corpus, "validation", args.shift_preset)
    for name, form in {"none": None, **forms}.items():
        gamma = 0.0
        if form is not None:
            r = form(shift)

            def negative_log_likelihood(g: float, r: Array = r) -> float:
                c = covariance(r, g, shift)
                return float(np.mean(0.5 * nees(shift["errors"], c) + 0.5 * np.linalg.slogdet(c)[1]))

            gamma = float(GAMMAS[int(np.argmin([negative_log_likelihood(g) for g in GAMMAS]))])
        line = [f"{name}: gamma {gamma:.2f}"]
        for (split, preset), pairs in sets.items():
            c = covariance(None if form is None else form(pairs), gamma, pairs)
            turning = pairs["true_deg"] > np.quantile(pairs["true_deg"], 0.9)
            line.append(
                f"{split} {preset} ANEES {nees(pairs['errors'], c).mean() / 3:.3f} "
                f"(the tenth turning most {nees(pairs['errors'][turning], c[turning]).mean() / 3:.3f})"
            )
        print("; ".join(line), flush=True)


if __name__ == "__main__":
    main()
