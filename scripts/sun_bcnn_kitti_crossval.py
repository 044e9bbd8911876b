"""A Sun-BCNN KITTI fine-tune recipe judged by cross-validation over KITTI 07 (frames 0-159, never 06).

    python scripts/sun_bcnn_kitti_crossval.py --model sun_bcnn --synthetic 128 --corpus data/corpus-sun \\
        -o runs/sun50/cv-128

07's 160 frames are cut into four contiguous stretches of 40; for each, the model is fine-tuned as
`pvo experiment sun-bcnn` does (its `train_on_kitti`: batch 16, patience 6, cosine schedule; the learning rate,
epochs and synthetic mix given here) on the other 120 frames, selecting its epoch on the held-out 40, and then
predicts them (in the MC mode its card names, N = 25, uncalibrated). One line per fold and one for the 160
pooled held-out predictions (median and mean vector error, ANEES), also written to OUT/crossval.json. Thirty-two
frames (the experiment's 128-159) move by degrees with the seed alone; 160 pooled frames from four stretches of the
drive (four headings towards the sun) judge a recipe better. Rerunning resumes: a finished fold is kept.

``--by-azimuth`` holds out by the sun's direction instead: the fine-tune sees the frames whose sun azimuth in the
camera (atan2(x, z) of the truth) is at least 135 deg (07 frames 34-130, the sun behind and to the right) and is
judged on those below 115 deg (frames 0-28 and 137-159): whether it reads a sun direction it was never shown, as
it must on another drive. ``--rotate DEG`` fine-tunes with that camera-turn augmentation (yaw within +-DEG) instead
of the model's own. ``--trainable`` says what the fine-tune changes, the rest kept as the synthetic world trained
it (default: the experiment's, ``features``): ``all``, or comma-separated parameter-name prefixes (``features``,
``head``, ``concentration``), ``norm`` (the batch-norm affine parameters) and ``blocks:K`` (the first K
convolutional blocks).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
from pvo_pseudosensors.learning.training import FineTune
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.evaluation import evaluate_predictions
from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn, predict_sequence
from pvo_pseudosensors.sun_bcnn.model import SunTask, trainable_selection
from pvo_tools.experiments.sun_bcnn import (
    FINETUNE_EPOCHS,
    FINETUNE_LEARNING_RATE,
    FINETUNE_TRAINABLE,
    kitti_truth,
    stage_kitti,
    synthetic_mix,
    train_on_kitti,
)
from pvo_tools.paths import data_directory

FRAMES = 160  # the KITTI 07 clip
FOLDS = 4
SEEN_AZIMUTH_DEG = 135.0  # --by-azimuth: fine-tune on suns at least this far round, judge on those below UNSEEN
UNSEEN_AZIMUTH_DEG = 115.0


def folds(data: Path, by_azimuth: bool) -> list[tuple[list[int], list[int]]]:
    """(training frames, held-out frames) of 07 per fold."""
    if by_azimuth:
        sun = kitti_truth(data, "07", np.arange(FRAMES))
        azimuth = np.degrees(np.arctan2(sun[:, 0], sun[:, 2]))
        return [(np.flatnonzero(azimuth >= SEEN_AZIMUTH_DEG).tolist(), np.flatnonzero(azimuth < UNSEEN_AZIMUTH_DEG).tolist())]
    size = FRAMES // FOLDS
    held = [list(range(k * size, (k + 1) * size)) for k in range(FOLDS)]
    return [([f for f in range(FRAMES) if f not in h], h) for h in held]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="the synthetic model to fine-tune (directory or shipped name)")
    parser.add_argument("--learning-rate", type=float, default=FINETUNE_LEARNING_RATE, help="default: the experiment's")
    parser.add_argument("--epochs", type=int, default=FINETUNE_EPOCHS, help="default: the experiment's")
    parser.add_argument("--synthetic", type=int, default=0, help="synthetic images of --corpus mixed into each epoch")
    parser.add_argument("--corpus", type=Path, help="the synthetic corpus for --synthetic (its training split)")
    parser.add_argument("--by-azimuth", action="store_true", help="one fold: held out by the sun's azimuth (above)")
    parser.add_argument("--rotate", type=float, help="the fine-tune's camera-turn augmentation, deg (default: the model's)")
    parser.add_argument(
        "--trainable", default=FINETUNE_TRAINABLE, help=f"what the fine-tune changes (above; default {FINETUNE_TRAINABLE})"
    )
    parser.add_argument(
        "--equalize", action="store_true", help="the fine-tuned network reads every image equalised (training and after)"
    )
    parser.add_argument(
        "--balance-bearing", action="store_true", help="frames repeated by the inverse density of their sun's bearing"
    )
    parser.add_argument("--seed", type=int, default=0, help="the fine-tune's seed (default 0, the experiment's)")
    parser.add_argument("--out", "-o", type=Path, required=True, help="folds' models and crossval.json")
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    args = parser.parse_args()
    if args.synthetic and args.corpus is None:
        parser.error("--synthetic needs --corpus")

    data = data_directory(args.data)
    base = resolve_model(args.model)
    config = load_sun_bcnn(base)[0].config
    if args.rotate is not None:
        config = dataclasses.replace(config, rotate=args.rotate)
    if args.equalize:
        config = dataclasses.replace(config, equalize=True)
    trainable = () if args.trainable == "all" else trainable_selection(args.trainable, config)
    synthetic = synthetic_mix(args.corpus, args.synthetic, config.spec) if args.synthetic else None
    command = (
        f"python scripts/sun_bcnn_kitti_crossval.py --model {args.model} --learning-rate {args.learning_rate} "
        f"--epochs {args.epochs} --synthetic {args.synthetic}{f' --corpus {args.corpus}' if args.corpus else ''}"
        f"{' --by-azimuth' if args.by_azimuth else ''}{f' --rotate {args.rotate:g}' if args.rotate is not None else ''}"
        f" --trainable {args.trainable}{' --balance-bearing' if args.balance_bearing else ''}"
        f"{' --equalize' if args.equalize else ''}{f' --seed {args.seed}' if args.seed else ''}"
        f" -o {args.out}"
    )
    rows, truths, results = [], [], []
    for fold, (kept, held) in enumerate(folds(data, args.by_azimuth)):
        staged = args.out / f"fold{fold}-staged"
        train = stage_kitti(data, "07", kept, staged / "train")
        validation = stage_kitti(data, "07", held, staged / "validation")
        model_dir = args.out / f"fold{fold}"
        if not (model_dir / "done").is_file():
            train_on_kitti(FineTune(SunTask(config), base, trainable), config.spec, train, validation, model_dir, args.epochs,
                           args.learning_rate, lambda line: None, {"train": command}, synthetic,
                           f"KITTI 07, {len(kept)} frames in {kept[0]}-{kept[-1]} ({len(held)} others to validate)",
                           args.balance_bearing, args.seed)  # fmt: skip
            (model_dir / "done").write_text("")
        model, card = load_sun_bcnn(model_dir)
        predictions = predict_sequence(model, card, validation, cache_dir=staged / ".cache")
        truth = kitti_truth(data, "07", np.asarray(held)[predictions.frames])
        figures = evaluate_predictions(predictions.rows(), truth)
        rows.append(predictions.rows())
        truths.append(truth)
        results.append({"frames": held, **figures})
        print(f"fold {fold} ({len(held)} frames, {held[0]}-{held[-1]}): median {figures['vector_median_deg']:6.2f}  "
              f"mean {figures['vector_mean_deg']:6.2f}  ANEES {figures['anees']:6.2f}", flush=True)  # fmt: skip
    pooled = evaluate_predictions(np.vstack(rows), np.vstack(truths))
    count = sum(len(r["frames"]) for r in results)
    print(f"pooled ({count} frames): median {pooled['vector_median_deg']:6.2f}  mean {pooled['vector_mean_deg']:6.2f}  "
          f"ANEES {pooled['anees']:6.2f}", flush=True)  # fmt: skip
    result = {"command": command, "pooled": pooled, "folds": results}
    (args.out / "crossval.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    from pvo_pseudosensors.learning.checkpoint import ModelFileError

    try:
        main()
    except (ModelFileError, ValueError, OSError) as exc:  # a bad model, corpus or count: one line, no traceback
        raise SystemExit(f"{Path(__file__).name}: {exc}") from None
