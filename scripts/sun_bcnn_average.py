"""Snapshot averaging of Sun-BCNN models (as SWA): the mean of several trained models' weights (the same
architecture and settings, e.g. the ends of successive cosine cycles), then their batch-normalisation statistics
re-estimated by one pass over the training split.

    python scripts/sun_bcnn_average.py --models sun_bcnn runs/sun50/cycle3 --corpus data/corpus-sun \\
        --corpus data/corpus-sun-div2 -o runs/sun50/average

The statistics pass runs the network as training did — train mode (dropout on), the training augmentation (jitter,
mirror, turned cameras), batches of 32 in a seeded order — without a gradient: an averaged network's running means
and variances are not the average of its members'. The result is a model directory with the first model's card (its
calibration dropped: calibrate it with `pvo sun-bcnn calibrate`) and a note naming the members.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from pvo_pseudosensors.learning import FrameDataset, corpus_sources
from pvo_pseudosensors.learning.checkpoint import save_model
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn
from pvo_pseudosensors.sun_bcnn.model import SunTask


def average_state(states: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """The element-wise mean of floating-point tensors; integer ones (batch counts) taken from the first."""
    return {
        key: torch.stack([s[key] for s in states]).mean(0) if states[0][key].is_floating_point() else states[0][key]
        for key in states[0]
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", required=True, help="two or more model directories or shipped names")
    parser.add_argument("--corpus", type=Path, action="append", required=True, help="the training corpora (repeat)")
    parser.add_argument("--out", "-o", type=Path, required=True, help="the averaged model's directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    if len(args.models) < 2:
        parser.error("--models: at least two")

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    loaded = [load_sun_bcnn(resolve_model(name)) for name in args.models]
    model, card = loaded[0]
    for name, (_, other_card) in zip(args.models[1:], loaded[1:], strict=True):
        if other_card.hyperparameters != card.hyperparameters:
            raise SystemExit(f"{name}: other settings than {args.models[0]}; only models of one architecture average")
    model.load_state_dict(average_state([m.state_dict() for m, _ in loaded]))

    task = SunTask(model.config)
    parts = [FrameDataset(corpus_sources(corpus, "train"), model.config.spec, corpus / ".cache") for corpus in args.corpus]
    images = torch.utils.data.ConcatDataset(parts)
    loader = torch.utils.data.DataLoader(images, batch_size=32, shuffle=True, generator=torch.Generator().manual_seed(args.seed))
    norms = [layer for layer in model.modules() if isinstance(layer, torch.nn.modules.batchnorm._BatchNorm)]
    momenta = [layer.momentum for layer in norms]
    for layer in norms:
        layer.reset_running_stats()
        layer.momentum = None  # a cumulative average over the whole pass
    model.train()
    with torch.no_grad():
        for step, batch in enumerate(loader, start=1):
            task.loss(model, batch)
            if step % 100 == 0:
                print(f"  batch-norm statistics: {step}/{len(loader)} batches", flush=True)
    for layer, momentum in zip(norms, momenta, strict=True):
        layer.momentum = momentum
    model.eval()

    card.calibration = {}
    card.created = ""
    sequences = sum(len(part.sources) for part in parts)
    card.notes = (
        f"Snapshot average of {', '.join(args.models)}: the mean of their weights, batch-norm statistics re-estimated "
        f"over one pass of {sequences} training sequences ({', '.join(str(c) for c in args.corpus)}), the training "
        f"augmentation, seed {args.seed}."
    )
    card.commands = {
        **(card.commands or {}),
        "average": f"python scripts/sun_bcnn_average.py --models {' '.join(args.models)} "
        + " ".join(f"--corpus {c}" for c in args.corpus)
        + f" -o {args.out}",
    }
    save_model(args.out, model, card)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    from pvo_pseudosensors.learning.checkpoint import ModelFileError

    try:
        main()
    except (ModelFileError, ValueError, OSError) as exc:  # a bad model, corpus or count: one line, no traceback
        raise SystemExit(f"{Path(__file__).name}: {exc}") from None
