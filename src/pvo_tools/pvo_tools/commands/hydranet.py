"""`pvo hydranet ensemble`: independently trained HydraNets made one model directory (the generated train /
predict / eval / calibrate of :mod:`.models` take it like any other); `pvo hydranet density`: the feature density
that widens the covariance of pairs unlike the model's data (:mod:`pvo_pseudosensors.hydranet.density`); `pvo
hydranet widen`: Sigma_a widened by the heads' spread (:mod:`pvo_pseudosensors.hydranet.widening`); `pvo hydranet
shortfall`: Sigma_a widened where the flow did not follow the image (:mod:`pvo_pseudosensors.hydranet.shortfall`)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any


def register_actions(actions: Any, entry: Any) -> None:
    ensemble = actions.add_parser(
        "ensemble",
        help="run several independently trained HydraNets as one model: all their heads pooled (mean, Sigma_e), "
        "Sigma_a their mean",
    )
    ensemble.set_defaults(handler=run_ensemble)
    ensemble.add_argument("models", type=Path, nargs="+", help="model directories (at least two, the same input size)")
    ensemble.add_argument("--out", "-o", type=Path, required=True, help="new model directory (copies of the weights)")
    register_density(actions)
    register_widening(actions)
    register_shortfall(actions)


def _shift_arguments(parser: Any, corpus_help: str, shift_help: str) -> None:
    """The model, in-distribution corpus and preset, and shift corpus a covariance widening is fitted with."""
    parser.add_argument("--model", type=Path, required=True, help="model directory (its card is rewritten)")
    parser.add_argument("--corpus", type=Path, required=True, help=corpus_help)
    parser.add_argument("--preset", default="urban", help="the corpus's in-distribution preset (default urban)")
    parser.add_argument("--shift-corpus", type=Path, required=True, help=shift_help)


def register_density(actions: Any) -> None:
    density = actions.add_parser(
        "density",
        help="fit the feature density that widens the covariance of pairs unlike the model's data: fitted on a "
        "corpus's training pairs, thresholded on its validation pairs, its power chosen so that a shifted corpus "
        "reads consistent; written into the model's card",
    )
    density.set_defaults(handler=run_density)
    _shift_arguments(
        density,
        "in-distribution corpus: its train and validation splits",
        "a corpus of a shift the model was not trained on (e.g. faster drives): its validation split",
    )
    density.add_argument(
        "--quantile",
        type=float,
        default=0.95,
        help="the quantile of the validation pairs' distances below which no covariance is widened (default 0.95)",
    )
    density.add_argument(
        "--components",
        type=int,
        help="measure the distance along only this many leading principal directions of the features (default all)",
    )
    density.add_argument(
        "--shrinkage",
        type=float,
        default=0.1,
        help="share of the features' covariance shrunk toward its mean variance (default 0.1)",
    )


def run_density(args: argparse.Namespace) -> int:
    from pvo_pseudosensors.hydranet.infer import calibrate_density

    sequences = _corpus_sequences
    calibration = calibrate_density(
        args.model,
        sequences(args.corpus, "train", args.preset),
        sequences(args.corpus, "validation", args.preset),
        sequences(args.shift_corpus, "validation", None),
        quantile=args.quantile,
        components=args.components,
        shrinkage=args.shrinkage,
        say=lambda stage: print(f"pvo hydranet density: {stage} ...", file=sys.stderr, flush=True),
    )
    density = calibration.density
    print(
        f"{args.model}: feature density over {density.features} units fitted on {calibration.fitting_pairs} pairs; "
        f"widening above r = {density.threshold:.3f} with power {density.gamma:.4f}"
    )
    _print_shift_figures(calibration, lambda after: f", {100 * after['widened']:.1f} % of the pairs widened")
    return 0


def register_widening(actions: Any) -> None:
    widen = actions.add_parser(
        "widen",
        help="fit how much Sigma_a widens where the heads disagree beyond their usual spread: the spread's reference "
        "from a corpus's in-distribution validation pairs, the power so that a shift the model was not trained on "
        "reads most likely; written into the model's card (calibration.spread_widening)",
    )
    widen.set_defaults(handler=run_widening)
    _shift_arguments(
        widen,
        "in-distribution corpus: its validation split",
        "a corpus holding a shift the model was not trained on: its validation split",
    )
    widen.add_argument(
        "--shift-preset", help="only this preset of the shift corpus (e.g. planetary for an urban model; default all)"
    )
    widen.add_argument(
        "--reference-quantile",
        type=float,
        default=0.9,
        help="the quantile of the validation pairs' tr Sigma_e that is the spread's reference: pairs below it are "
        "never widened (default 0.9, the shipped card's; 0.5 widens every pair above the median)",
    )
    widen.add_argument(
        "--max-gamma",
        type=float,
        default=3.0,
        help="the largest power the fit tries (default 3; a fit at this bound says so: the shift wants more)",
    )


def register_shortfall(actions: Any) -> None:
    shortfall = actions.add_parser(
        "shortfall",
        help="fit how much Sigma_a widens where the flow did not follow the image (the images' phase-correlation "
        "shift against the flow's median): the reference from a corpus's in-distribution validation pairs, the power "
        "so that a faster-driven shift reads most likely; written into the model's card "
        "(calibration.flow_shortfall_widening)",
    )
    shortfall.set_defaults(handler=run_shortfall)
    _shift_arguments(
        shortfall,
        "in-distribution corpus: its validation split",
        "a corpus of faster drives than the model was trained on: its validation split",
    )
    shortfall.add_argument("--shift-preset", help="only this preset of the shift corpus (default all)")
    shortfall.add_argument(
        "--reference-quantile",
        type=float,
        default=0.99,
        help="the quantile of the validation pairs' shortfalls below which no pair is widened (default 0.99)",
    )


def run_shortfall(args: argparse.Namespace) -> int:
    from pvo_pseudosensors.hydranet.infer import calibrate_shortfall

    calibration = calibrate_shortfall(
        args.model,
        _corpus_sequences(args.corpus, "validation", args.preset),
        _corpus_sequences(args.shift_corpus, "validation", args.shift_preset),
        say=lambda stage: print(f"pvo hydranet shortfall: {stage} ...", file=sys.stderr, flush=True),
        reference_quantile=args.reference_quantile,
    )
    widening = calibration.widening
    print(
        f"{args.model}: Sigma_a widened by 1 + {widening.gamma:.4g} (d / {widening.reference:.3f} px - 1) above it, "
        f"d the flow's shortfall (phase-correlation peaks below {widening.min_response:g} measure none)"
    )
    _print_shift_figures(calibration)
    return 0


def _corpus_sequences(corpus: Path, split: str, preset: str | None) -> list[tuple[Path, Path]]:
    from pvo_core.readers import read_corpus_manifest

    manifest = read_corpus_manifest(corpus)
    chosen = [(s.root, manifest.path.parent / ".cache") for s in manifest.split(split) if preset in (None, s.preset)]
    if not chosen:
        raise ValueError(f"{corpus}: no {preset or ''} sequence in the {split} split".replace("  ", " "))
    return chosen


def run_widening(args: argparse.Namespace) -> int:
    from pvo_pseudosensors.hydranet.infer import calibrate_widening

    calibration = calibrate_widening(
        args.model,
        _corpus_sequences(args.corpus, "validation", args.preset),
        _corpus_sequences(args.shift_corpus, "validation", args.shift_preset),
        say=lambda stage: print(f"pvo hydranet widen: {stage} ...", file=sys.stderr, flush=True),
        reference_quantile=args.reference_quantile,
        max_gamma=args.max_gamma,
    )
    widening = calibration.widening
    edge = " (at --max-gamma: the shift's pairs want more)" if widening.gamma >= args.max_gamma else ""
    print(
        f"{args.model}: Sigma_a widened by 1 + {widening.gamma:.2f} (r - 1) above r = 1, "
        f"r = tr Sigma_e / {widening.reference:.4g} rad^2{edge}"
    )
    _print_shift_figures(calibration)
    return 0


def _print_shift_figures(calibration: Any, extra: Any = lambda after: "") -> None:
    """One line per pair set (validation, shift) of a widening's figures: pairs, mean error, ANEES before -> after."""
    for label, before, after in (
        ("validation", calibration.validation_before, calibration.validation_after),
        ("shift", calibration.shift_before, calibration.shift_after),
    ):
        print(
            f"  {label:<10} {int(before['pairs'])} pairs, mean error {before['angle_mean_deg']:.4f} deg: ANEES "
            f"{before['anees']:.3f} -> {after['anees']:.3f}{extra(after)}"
        )


def run_ensemble(args: argparse.Namespace) -> int:
    from pvo_pseudosensors.hydranet.infer import load_hydranet, write_ensemble

    command = "pvo hydranet ensemble " + shlex.join([*map(str, args.models), "-o", str(args.out)])
    out = write_ensemble(args.models, args.out, command)
    model, _ = load_hydranet(out)
    print(f"{out}: an ensemble of {len(args.models)} HydraNets, {model.head_count} heads pooled")
    return 0
