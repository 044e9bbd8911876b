"""The learned sun fused with its covariance times S, on long drives of a corpus's validation split (never its test
split): how much the fusion should trust Sun-BCNN, measured where a choice may be made.

    python scripts/sun_bcnn_fusion_weight.py --corpus data/corpus-sun --preset urban -o runs/sun51/val-urban
    python scripts/sun_bcnn_fusion_weight.py --corpus data/corpus-sun --preset urban --lens -0.3 0.2 0.01 \
        -o runs/sun51/val-urban-lens

With --drives it takes rendered drives as they are (the 48 long validation drives of `pvo dpc-net drives
runs/dpc/vlong`: KITTI 03, 04, 10 windows and their mirror images, clean, through the thesis's lens and with
calib.txt's focal length 3 % long — rigs whose VO drifts; OUT only labels the output):

    python scripts/sun_bcnn_fusion_weight.py --drives runs/dpc/vlong/calib/* --scales 1 --biases 0.5:0.03 \
        -o runs/sun53/calib

Otherwise it renders the first --sequences validation sequences of --preset with --frames frames into OUT (resumes; with --lens
through that uncalibrated lens, as `pvo experiment sun-bcnn --fusion-lens`), runs the VO and the model on each, and
fuses them as experiment 4 does (VO covariances calibrated on the other drives, a sun reading every 10th frame) with the
model's covariance times each of --scales, then (at scale 1) with each of --biases as the fusion's offset state of the
learned sun (SIGMA:WALK, rad and rad/√s: `inputs.sun.bias_sigma` and `inputs.sun.bias_walk_sigma`, the same for
zenith and azimuth). Prints per drive the online ARMSE (translation m, rotation rad) of the VO alone and with each
setting, then the mean change against the VO alone per setting (online, then smoothed).

    python scripts/sun_bcnn_fusion_weight.py --corpus data/corpus-sun --preset planetary --scales 1 \
        --biases 0.1:0.002,0.25:0.01 -o runs/sun52/val-planetary

With --write-card SIGMA:WALK it renders and fuses nothing: it records that offset state in --model's card
(`calibration.fusion`, read by `pvo experiment sun-bcnn` and `pvo demo`) with --chosen-by (how it was chosen) as the
card's `commands.fusion`.
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
    parser.add_argument("--biases", default="", help="offset states SIGMA:WALK (rad, rad/√s), comma-separated")
    parser.add_argument("--write-card", metavar="SIGMA:WALK", help="record this offset state in --model's card, then stop")
    parser.add_argument("--chosen-by", default="", help="with --write-card: the commands and rule that chose it")
    parser.add_argument(
        "--drives",
        type=Path,
        nargs="+",
        help="rendered validation drives to use as they are (e.g. runs/dpc/vlong/calib/*, `pvo dpc-net drives`), "
        "instead of rendering --corpus's; each drive's VO is calibrated on the others given",
    )
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("-o", "--out", type=Path, help="folder of the rendered drives (required but with --write-card)")
    args = parser.parse_args()
    try:
        scales = [float(v) for v in args.scales.split(",")]
    except ValueError:
        scales = []
    if not scales or min(scales) <= 0.0:
        sys.exit(f"sun_bcnn_fusion_weight.py: --scales {args.scales!r}: give positive numbers, comma-separated")
    try:
        biases = [tuple(float(v) for v in item.split(":")) for item in args.biases.split(",") if item]
    except ValueError:
        biases = [()]
    if any(len(b) != 2 or min(b) <= 0.0 for b in biases):
        sys.exit(f"sun_bcnn_fusion_weight.py: --biases {args.biases!r}: give SIGMA:WALK positive pairs, comma-separated")
    if args.drives is not None and len(args.drives) < 2:
        sys.exit("sun_bcnn_fusion_weight.py: --drives: at least 2 (each drive's VO is calibrated on the others)")
    if args.drives is not None and args.lens:
        sys.exit("sun_bcnn_fusion_weight.py: --lens renders drives through a lens; --drives takes rendered ones as they are")
    if args.sequences < 2:
        sys.exit(
            f"sun_bcnn_fusion_weight.py: --sequences {args.sequences}: at least 2 (each drive's VO is calibrated on the others)"
        )

    if args.write_card:
        write_card(args.model, args.write_card, args.chosen_by)
        return
    if args.out is None:
        parser.error("the following arguments are required: -o/--out")
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
        if args.drives is not None:
            folders = [Path(d) for d in args.drives]
            missing = [str(d) for d in folders if not (d / "poses.txt").is_file() or not (d / "sun.csv").is_file()]
            if missing:
                raise ValueError(f"not a rendered drive (poses.txt and sun.csv): {', '.join(missing)}")
        else:
            folders = render_fusion_sequences(
                args.corpus, args.sequences, args.frames, args.out, args.jobs, print, lens, args.preset, split="validation"
            )
    except (ValueError, OSError, ModelFileError) as exc:
        sys.exit(f"sun_bcnn_fusion_weight.py: {exc}")
    inputs = [fusion_inputs(folder, model, card, 25) for folder in folders]
    sequences = [seq for seq, _ in inputs]
    settings = [(scale, None) for scale in scales] + [(1.0, bias) for bias in biases]
    alone = fusion_experiment(sequences, [[] for _ in sequences], rows=("Without Sun",))  # the same for every setting
    for scale, bias in settings:  # experiment 4's fusion, its Sun-BCNN row with the covariance scaled or an offset state
        label = f"x{scale:g}" if bias is None else f"bias {bias[0]:g}:{bias[1]:g}"
        fusion = None if bias is None else {"inputs.sun.bias_sigma": (bias[0],) * 2, "inputs.sun.bias_walk_sigma": (bias[1],) * 2}
        scaled = [[SunMeasurement(m.stamp, m.direction, m.covariance * scale) for m in learned] for _, learned in inputs]
        learned_only = fusion_experiment(sequences, scaled, rows=("Sun-BCNN",), learned_fusion=fusion)
        table = {name: {**alone[name], **learned_only[name]} for name in alone}
        for name, rows in table.items():
            vo, fused = rows["Without Sun"]["online"], rows["Sun-BCNN"]["online"]
            print(
                f"{args.out} {name} {label}: VO {vo['trans']:.3f} m {vo['rot']:.4f} rad, "
                f"fused {fused['trans']:.3f} m {fused['rot']:.4f} rad",
                flush=True,
            )
        change = fusion_changes(table)["Sun-BCNN"]
        online, smoothed = change["online"], change["smoothed"]
        print(
            f"{args.out} {label}: mean change trans {100 * online['trans']:+.1f} % rot {100 * online['rot']:+.1f} % "
            f"(smoothed {100 * smoothed['trans']:+.1f} % / {100 * smoothed['rot']:+.1f} %)",
            flush=True,
        )


def write_card(model: str, setting: str, chosen_by: str) -> None:
    """Record the offset state SIGMA:WALK (rad, rad/√s; zenith and azimuth alike) in the model's card."""
    from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card
    from pvo_pseudosensors.learning.checkpoint import write_card as write
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model

    try:
        sigma, walk = (float(v) for v in setting.split(":"))
    except ValueError:
        sigma = walk = -1.0
    if min(sigma, walk) <= 0.0:
        sys.exit(f"sun_bcnn_fusion_weight.py: --write-card {setting!r}: give SIGMA:WALK, two positive numbers")
    if not chosen_by:
        sys.exit("sun_bcnn_fusion_weight.py: --write-card needs --chosen-by (the commands and rule that chose it)")
    try:
        directory = resolve_model(model)
        card = read_card(directory)
    except (ModelFileError, OSError) as exc:
        sys.exit(f"sun_bcnn_fusion_weight.py: {exc}")
    card.calibration = {
        **(card.calibration or {}),
        "fusion": {"inputs.sun.bias_sigma": [sigma, sigma], "inputs.sun.bias_walk_sigma": [walk, walk]},
    }
    card.commands = {**card.commands, "fusion": chosen_by}
    print(f"{write(directory, card)}: calibration.fusion = offset state σ {sigma:g} rad, walk {walk:g} rad/√s")


if __name__ == "__main__":
    main()
