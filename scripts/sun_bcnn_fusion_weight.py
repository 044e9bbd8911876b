"""The learned sun fused with its covariance times S, on long drives of a corpus's validation split (never its test
split): how much the fusion should trust Sun-BCNN, measured where a choice may be made.

    python scripts/sun_bcnn_fusion_weight.py --corpus data/corpus-sun --preset urban -o runs/sun51/val-urban
    python scripts/sun_bcnn_fusion_weight.py --corpus data/corpus-sun --preset urban --lens -0.3 0.2 0.01 \
        -o runs/sun51/val-urban-lens

Renders the first --sequences validation sequences of --preset with --frames frames into OUT (resumes; with --lens
through that uncalibrated lens, as `pvo experiment sun-bcnn --fusion-lens`), runs the VO and the model on each, and
fuses them as experiment 4 does (VO covariances calibrated on the other drives, a sun reading every 10th frame) with the
model's covariance times each of --scales. Prints per drive the online ARMSE (translation m, rotation rad) of the VO
alone and at each scale, then the mean change against the VO alone per scale.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--corpus", type=Path, default=Path("data/corpus-sun"))
    parser.add_argument("--model", default="sun_bcnn", help="model directory or shipped name (default sun_bcnn)")
    parser.add_argument("--preset", help="urban or planetary (default: the first validation sequences of any)")
    parser.add_argument("--sequences", type=int, default=5)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--lens", type=float, nargs="+", default=(), metavar="K", help="plumb-bob k1 [k2 k3]")
    parser.add_argument("--scales", default="1,3,10,30,100", help="covariance scales, comma-separated")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("-o", "--out", type=Path, required=True, help="folder of the rendered drives")
    args = parser.parse_args()
    try:
        scales = [float(v) for v in args.scales.split(",")]
    except ValueError:
        scales = []
    if not scales or min(scales) <= 0.0:
        sys.exit(f"sun_bcnn_fusion_weight.py: --scales {args.scales!r}: give positive numbers, comma-separated")
    if args.sequences < 2:
        sys.exit(
            f"sun_bcnn_fusion_weight.py: --sequences {args.sequences}: at least 2 (each drive's VO is calibrated on the others)"
        )

    import torch
    from pvo_pseudosensors.learning.checkpoint import ModelFileError
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn
    from pvo_tools.experiments.sun_bcnn import (
        fusion_changes,
        fusion_experiment,
        fusion_inputs,
        parse_lens,
        render_fusion_sequences,
    )

    from pvo_fusion import SunMeasurement

    torch.set_num_threads(2)
    try:
        lens = parse_lens(args.lens)
        model, card = load_sun_bcnn(resolve_model(args.model))
        folders = render_fusion_sequences(
            args.corpus, args.sequences, args.frames, args.out, args.jobs, print, lens, args.preset, split="validation"
        )
    except (ValueError, OSError, ModelFileError) as exc:
        sys.exit(f"sun_bcnn_fusion_weight.py: {exc}")
    inputs = [fusion_inputs(folder, model, card, 25) for folder in folders]
    sequences = [seq for seq, _ in inputs]
    for scale in scales:  # experiment 4's fusion, its Sun-BCNN row with the covariance scaled
        scaled = [[SunMeasurement(m.stamp, m.direction, m.covariance * scale) for m in learned] for _, learned in inputs]
        table = fusion_experiment(sequences, scaled, rows=("Without Sun", "Sun-BCNN"))
        for name, rows in table.items():
            alone, fused = rows["Without Sun"]["online"], rows["Sun-BCNN"]["online"]
            print(
                f"{args.out} {name} x{scale:g}: VO {alone['trans']:.3f} m {alone['rot']:.4f} rad, "
                f"fused {fused['trans']:.3f} m {fused['rot']:.4f} rad",
                flush=True,
            )
        change = fusion_changes(table)["Sun-BCNN"]["online"]
        print(f"{args.out} scale {scale:g}: mean change trans {100 * change['trans']:+.1f} % rot {100 * change['rot']:+.1f} %")


if __name__ == "__main__":
    main()
