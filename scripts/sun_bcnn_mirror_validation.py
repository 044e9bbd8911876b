"""Sun-BCNN's mirrored MC mode against the plain one on a corpus's validation split (never its test split): the
Method I mean of N passes, of 2N passes, of N passes pooled with N over the mirrored image, and of N/2 + N/2
(the same cost as N), each image's vector error against the truth.

    python scripts/sun_bcnn_mirror_validation.py --model sun_bcnn --corpus data/corpus-sun --passes 24
    python scripts/sun_bcnn_mirror_validation.py --model sun_bcnn --corpus data/corpus-sun --passes 25 --modes

Prints the median and mean vector error (deg) of each over the validation images - the figures behind the
default MC mode (``pvo_pseudosensors.sun_bcnn.infer.DEFAULT_MODE``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from pvo_core.readers import read_corpus_manifest
from pvo_pseudosensors.learning.data import FrameDataset, Source
from pvo_pseudosensors.sun_bcnn.config import SunBCNNConfig
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.infer import MODES, Draws, combine, draw_samples, load_sun_bcnn

MIRROR_X = np.array([-1.0, 1.0, 1.0])


def pooled(*parts: Draws) -> Draws:
    inverse = [p.inverse_concentration for p in parts]
    return Draws(np.concatenate([p.vectors for p in parts]), None if any(i is None for i in inverse) else np.concatenate(inverse))


def first(draws: Draws, count: int) -> Draws:
    inverse = draws.inverse_concentration
    return Draws(draws.vectors[:count], None if inverse is None else inverse[:count])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="sun_bcnn", help="model directory or a shipped name (default sun_bcnn)")
    parser.add_argument("--corpus", type=Path, default=Path("data/corpus-sun"))
    parser.add_argument("--passes", type=int, default=24, help="N, MC-dropout passes (even without --modes; default 24)")
    parser.add_argument("--max-sequences", type=int, help="the first N validation sequences only")
    parser.add_argument(
        "--modes",
        action="store_true",
        help="instead: every MC mode of the node (full, head, full-mirrored, head-mirrored) at --passes, as the node draws them",
    )
    args = parser.parse_args()
    if args.passes < 2 or (args.passes % 2 and not args.modes):
        raise SystemExit(f"--passes must be even and >= 2 (>= 2 with --modes), got {args.passes}")

    torch.set_num_threads(1)
    model, card = load_sun_bcnn(resolve_model(args.model))
    spec = SunBCNNConfig.from_card(card).spec
    sequences = read_corpus_manifest(args.corpus).split("validation")[: args.max_sequences or None]
    n, half = args.passes, args.passes // 2
    labels = (f"plain {n}", f"plain {2 * n}", f"mirrored {n} + {n}", f"mirrored {half} + {half}")
    if args.modes:
        labels = MODES
    errors: dict[str, list[float]] = {label: [] for label in labels}
    seconds = dict.fromkeys(labels, 0.0)
    for k, item in enumerate(sequences):
        data = FrameDataset([Source(item.root, item.root.name)], spec, args.corpus / ".cache")
        samples = [data[i] for i in range(len(data))]
        images = torch.stack([s["left"] for s in samples])
        truth = torch.stack([s["sun"] for s in samples]).double().numpy()
        if args.modes:
            for mode in MODES:
                tic = time.perf_counter()
                mean, _ = combine(draw_samples(model, images, n, 1000 + k, mode=mode))
                seconds[mode] += time.perf_counter() - tic
                cosine = np.clip(np.sum(mean * truth, axis=1), -1.0, 1.0)
                errors[mode] += list(np.degrees(np.arccos(cosine)))
            print(f"{item.name}: {len(samples)} images", flush=True)
            continue
        direct = draw_samples(model, images, n, 1000 + k, mode="full")
        more = draw_samples(model, images, n, 3000 + k, mode="full")
        flipped = draw_samples(model, torch.flip(images, dims=[-1]), n, 2000 + k, mode="full")
        mirror = Draws(flipped.vectors * MIRROR_X, flipped.inverse_concentration)
        candidates = (direct, pooled(direct, more), pooled(direct, mirror), pooled(first(direct, half), first(mirror, half)))
        for label, draws in zip(labels, candidates, strict=True):
            mean, _ = combine(draws)
            cosine = np.clip(np.sum(mean * truth, axis=1), -1.0, 1.0)
            errors[label] += list(np.degrees(np.arccos(cosine)))
        print(f"{item.name}: {len(samples)} images", flush=True)
    for label, values in errors.items():
        timing = f", {1e3 * seconds[label] / max(len(values), 1):.1f} ms per image (batches of 40)" if args.modes else ""
        print(f"{label:<20} {len(values)} images, median {np.median(values):.2f} deg, mean {np.mean(values):.2f} deg{timing}")


if __name__ == "__main__":
    main()
