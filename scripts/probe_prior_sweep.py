"""PROBE-GK's prior chosen on a corpus's validation split (never its test split): the VO with the default noise
against the VO with a PROBE model under each candidate prior, each sequence run with several RANSAC seeds.

    python scripts/probe_prior_sweep.py runs/probe-fitted-gate/probe-corpus-model --corpus data/corpus-sun \\
        --priors nominal fitted:2 fitted:3 fitted:5

Prints, per prior, the mean relative change of translational ARMSE over all sequences, over those where tracking is
hard (moving vehicles, motion blur, texture-poor walls) and the worst clean sequence (no condition drawn) - the
figures the README's PROBE section quotes. The candidate priors are refitted from the model's stored errors.
``--also MODEL...`` compares other models (say, trained on more sequences) on the same runs, each as trained.
``--corpus`` may be given more than once (say, data/corpus-sun and a validation-only corpus rendered for more clean
sequences); ``--propagate-reference`` adds each candidate again with the reference observation's noise propagated
(``solver.propagate_reference_noise``'s whitening, which PROBE-GK leaves off because its stored errors hold that
noise already), labelled ``… +propagated``. ``--jobs N`` runs N sequences at a time (forked workers; the printed
figures do not depend on N).
"""

from __future__ import annotations

import argparse
import multiprocessing
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from pvo_core.readers import KittiSequence, read_corpus_manifest
from pvo_frontend.offline import run_sequence
from pvo_frontend.probe.gk import GKConfig
from pvo_frontend.probe.model import ProbeModel
from pvo_frontend.vo import VOConfig

from pvo_core import metrics

HARD = {"moving vehicles", "motion blur", "texture-poor walls"}


def prior_config(base: GKConfig, spec: str) -> GKConfig:
    """``nominal`` or ``fitted:DOF`` on top of the model's kernel settings (the prior left to be fitted)."""
    if spec == "nominal":
        return GKConfig(base.radius, base.max_neighbours, prior="nominal")
    kind, _, dof = spec.partition(":")
    if kind != "fitted" or not dof:
        raise SystemExit(f"prior {spec!r}: use nominal or fitted:DOF")
    return GKConfig(base.radius, base.max_neighbours, prior="fitted", prior_dof=float(dof))


def propagated(hook: Any) -> Any:
    """``hook``'s noise with the reference observation's noise propagated as well."""

    def propagating_hook(before: Any, after: Any, image: Any, imu: Any = None) -> Any:
        estimate = hook(before, after, image, imu)
        return None if estimate is None else replace(estimate, propagate_reference=True)

    return propagating_hook


#: what every worker needs, set before the workers fork: the candidates (hook, gate) by label and the seeds
_CANDIDATES: dict[str, tuple[Any, float]] = {}
_SEEDS = 5


def sequence_armse(root: Path) -> dict[str, list[float]]:
    """Translational ARMSE of the default VO and of each candidate on one corpus sequence, one per RANSAC seed."""
    sequence = KittiSequence(root, poses_file=root / "poses.txt")
    runs: dict[str, list[float]] = {"default": [], **{label: [] for label in _CANDIDATES}}
    for seed in range(_SEEDS):
        config = replace(VOConfig(), ransac=replace(VOConfig().ransac, seed=seed))
        runs["default"].append(metrics.armse(sequence.poses, run_sequence(sequence, config).poses)["trans"])
        for label, (hook, gate) in _CANDIDATES.items():
            probe_config = replace(config, probe=replace(config.probe, gate_threshold=gate))
            poses = run_sequence(sequence, probe_config, feature_noise=hook).poses
            runs[label].append(metrics.armse(sequence.poses, poses)["trans"])
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path, help="a PROBE-GK model trained on the corpus's training split")
    parser.add_argument(
        "--corpus", type=Path, action="append", help="corpus whose validation split is run (repeatable; default data/corpus-sun)"
    )
    parser.add_argument("--priors", nargs="+", default=["nominal", "fitted:2", "fitted:3", "fitted:5"])
    parser.add_argument("--seeds", type=int, default=5, help="RANSAC seeds per sequence (default 5)")
    parser.add_argument("--max-sequences", type=int, help="the first N validation sequences of each corpus only")
    parser.add_argument(
        "--propagate-reference", action="store_true", help="each candidate also with the reference noise propagated"
    )
    parser.add_argument(
        "--also", type=Path, nargs="+", default=[], help="other models to compare, each with its own prior as trained"
    )
    parser.add_argument(
        "--probe-gates",
        type=float,
        nargs="+",
        default=[VOConfig().probe.gate_threshold],
        help="probe.gate_threshold values, each candidate with each (default: the VO's)",
    )
    parser.add_argument("--jobs", type=int, default=1, help="sequences run at a time (default 1)")
    args = parser.parse_args()
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")

    model = ProbeModel.load(args.model)
    trained = model.estimator.config
    models = {}
    for spec in args.priors:
        estimator = replace(model.estimator)  # a shallow copy: the stored samples are shared
        estimator.config = prior_config(trained, spec).fitted_to(estimator.errors)
        models[spec] = replace(model, estimator=estimator)
    for other in args.also:
        models[str(other)] = ProbeModel.load(other)
    hooks = {label: candidate.feature_noise() for label, candidate in models.items()}
    if args.propagate_reference:
        hooks.update({f"{label} +propagated": propagated(hook) for label, hook in list(hooks.items())})
    gated = {f"{label} gate {gate:g}": (hook, gate) for label, hook in hooks.items() for gate in args.probe_gates}
    labels = list(gated)
    changes: dict[str, dict[str, float]] = {label: {} for label in labels}
    conditions = {}
    items = [
        item
        for corpus in args.corpus or [Path("data/corpus-sun")]
        for item in read_corpus_manifest(corpus).split("validation")[: args.max_sequences or None]
    ]
    global _SEEDS
    _CANDIDATES.update(gated)
    _SEEDS = args.seeds
    roots = [item.root for item in items]
    if args.jobs > 1:
        pool = multiprocessing.get_context("fork").Pool(args.jobs)
        results = pool.imap(sequence_armse, roots)
    else:
        pool, results = None, map(sequence_armse, roots)
    for item, runs in zip(items, results, strict=True):
        key = f"{item.root.parent.name}/{item.name}"  # sequence names repeat across corpora
        conditions[key] = set(item.conditions)
        for label in labels:
            changes[label][key] = float(np.mean(runs[label]) / np.mean(runs["default"]) - 1.0)
        print(
            key,
            sorted(item.conditions),
            " ".join(f"{s} {100 * changes[s][key]:+.1f} %" for s in labels),
            flush=True,
        )
    if pool is not None:
        pool.close()
        pool.join()
    for spec, change in changes.items():
        clean = {name: c for name, c in change.items() if not conditions[name]}
        hard = [c for name, c in change.items() if conditions[name] & HARD]
        worst = max(clean, key=clean.get) if clean else None
        hard_mean = 100 * np.mean(hard) if hard else float("nan")
        over = sum(c > 0.05 for c in clean.values())
        print(
            f"{spec}: all {100 * np.mean(list(change.values())):+.1f} % ({len(change)}), hard {hard_mean:+.1f} % "
            f"({len(hard)}), clean {100 * np.mean(list(clean.values())) if clean else float('nan'):+.1f} % "
            f"({len(clean)}, {over} over +5 %), "
            + (f"worst clean {worst} {100 * clean[worst]:+.1f} %" if worst else "no clean sequence")
        )


if __name__ == "__main__":
    main()
