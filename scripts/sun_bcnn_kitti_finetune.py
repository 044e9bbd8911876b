"""A Sun-BCNN fine-tune on KITTI 07 with other settings than `pvo experiment sun-bcnn`'s (learning rate, epochs),
judged where the experiment judges its own: the median vector error on 07's validation frames 128-159 (never 06).

    python scripts/sun_bcnn_kitti_finetune.py --model runs/sun8/more-bn --learning-rate 1e-3 --epochs 40 \\
        -o runs/sun9/ft-lr1e-3 --compare sun_bcnn_kitti

Stages 07 frames 0-127 (training) and 128-159 (validation) as the experiment does, fine-tunes with the experiment's
own `train_on_kitti` (batch 16, patience 6, cosine schedule), then prints one line per model — the fine-tune and
each ``--compare`` model — with the median and mean vector error and the ANEES on the validation frames, each model
in the MC mode its card names (tau as calibrated; the fine-tune is not calibrated here, so its ANEES is uncalibrated).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pvo_pseudosensors.learning.training import FineTune
from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn
from pvo_pseudosensors.sun_bcnn.model import SunTask, trainable_selection
from pvo_tools.experiments.sun_bcnn import (
    FINETUNE_EPOCHS,
    FINETUNE_LEARNING_RATE,
    FINETUNE_TRAINABLE,
    KITTI_TRAIN_FRAMES,
    KITTI_VALIDATION_FRAMES,
    kitti_figures,
    stage_kitti,
    train_on_kitti,
)
from pvo_tools.paths import data_directory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="the synthetic model to fine-tune (directory or shipped name)")
    parser.add_argument(
        "--learning-rate",
        type=float,
        default=FINETUNE_LEARNING_RATE,
        help=f"default {FINETUNE_LEARNING_RATE:g} (the experiment's)",
    )
    parser.add_argument("--epochs", type=int, default=FINETUNE_EPOCHS, help=f"default {FINETUNE_EPOCHS}, the experiment's")
    parser.add_argument(
        "--trainable",
        default=FINETUNE_TRAINABLE,
        help=f"what the fine-tune changes: all, or parts (features, head, norm, blocks:K; default {FINETUNE_TRAINABLE})",
    )
    parser.add_argument("--out", "-o", type=Path, required=True, help="the fine-tuned model's directory")
    parser.add_argument("--compare", nargs="*", default=[], help="other models judged on the same frames")
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    args = parser.parse_args()

    data = data_directory(args.data)
    base = resolve_model(args.model)
    staged = args.out.parent / f"{args.out.name}-staged"
    train = stage_kitti(data, "07", KITTI_TRAIN_FRAMES, staged / "kitti07-train")
    validation = stage_kitti(data, "07", KITTI_VALIDATION_FRAMES, staged / "kitti07-validation")
    config = load_sun_bcnn(base)[0].config
    command = f"python scripts/sun_bcnn_kitti_finetune.py --model {args.model} --learning-rate {args.learning_rate} "
    command += f"--epochs {args.epochs} --trainable {args.trainable} -o {args.out}"
    trainable = () if args.trainable == "all" else trainable_selection(args.trainable, config)
    train_on_kitti(FineTune(SunTask(config), base, trainable), config.spec, train, validation, args.out, args.epochs,
                   args.learning_rate, print, {"train": command})  # fmt: skip
    for name in [str(args.out), *args.compare]:
        figures = kitti_figures(name, validation, data, "07", KITTI_VALIDATION_FRAMES, staged / ".cache")
        print(
            f"{name:<40} 07 frames 128-159: median {figures['vector_median_deg']:6.2f}  "
            f"mean {figures['vector_mean_deg']:6.2f}  ANEES {figures['anees']:5.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
