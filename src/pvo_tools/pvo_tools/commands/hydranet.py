"""`pvo hydranet ensemble`: independently trained HydraNets made one model directory (the generated train /
predict / eval / calibrate of :mod:`.models` take it like any other)."""

from __future__ import annotations

import argparse
import shlex
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


def run_ensemble(args: argparse.Namespace) -> int:
    from pvo_pseudosensors.hydranet.infer import load_hydranet, write_ensemble

    command = "pvo hydranet ensemble " + shlex.join([*map(str, args.models), "-o", str(args.out)])
    out = write_ensemble(args.models, args.out, command)
    model, _ = load_hydranet(out)
    print(f"{out}: an ensemble of {len(args.models)} HydraNets, {model.head_count} heads pooled")
    return 0
