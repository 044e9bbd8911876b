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

import numpy as np


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
        if not scales or min(scales) <= 0.0 or args.sequences < 2:
            raise ValueError
    except ValueError:
        sys.exit(f"sun_bcnn_fusion_weight.py: --scales {args.scales!r} must be positive numbers and --sequences at least 2")

    import torch
    from pvo_pseudosensors.learning.checkpoint import ModelFileError
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn
    from pvo_tools.experiments.sun_bcnn import fusion_inputs, parse_lens, render_fusion_sequences
    from pvo_tools.experiments.sun_sim import SUN_EVERY, calibration_input, experiment_config, run_fusion, sequence_vo

    from pvo_core import metrics
    from pvo_fusion import SunMeasurement, calibrate_vo

    torch.set_num_threads(2)
    try:
        lens = parse_lens(args.lens)
        model, card = load_sun_bcnn(resolve_model(args.model))
        folders = render_fusion_sequences(
            args.corpus, args.sequences, args.frames, args.out, args.jobs, print, lens, args.preset, split="validation"
        )
    except (ValueError, OSError, ModelFileError) as exc:
        sys.exit(f"sun_bcnn_fusion_weight.py: {exc}")
    config = experiment_config()
    inputs = [fusion_inputs(folder, model, card, 25) for folder in folders]
    sequences = [seq for seq, _ in inputs]
    changes = {scale: {"trans": [], "rot": []} for scale in scales}
    for i, (seq, learned) in enumerate(inputs):
        calibration = calibrate_vo((calibration_input(s) for j, s in enumerate(sequences) if j != i), SUN_EVERY)
        vo = sequence_vo(seq, calibration)
        alone = metrics.armse(seq.ground_truth, run_fusion(seq, vo, None, config).online_poses)
        line = f"{args.out} {seq.name}: VO {alone['trans']:.3f} m {alone['rot']:.4f} rad"
        for scale in scales:
            sun = [SunMeasurement(m.stamp, m.direction, m.covariance * scale) for m in learned]
            fused = metrics.armse(seq.ground_truth, run_fusion(seq, vo, sun, config).online_poses)
            for key in ("trans", "rot"):
                changes[scale][key].append(fused[key] / alone[key] - 1.0)
            line += f" | x{scale:g} {fused['trans']:.3f} {fused['rot']:.4f}"
        print(line, flush=True)
    for scale in scales:
        print(
            f"{args.out} scale {scale:g}: mean change trans {100 * np.mean(changes[scale]['trans']):+.1f} % "
            f"rot {100 * np.mean(changes[scale]['rot']):+.1f} %",
            flush=True,
        )


if __name__ == "__main__":
    main()
