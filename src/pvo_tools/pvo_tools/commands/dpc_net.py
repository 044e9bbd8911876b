"""`pvo dpc-net predict|correct|calibrate|drives|eval`: DPC-Net's corrections of this project's stereo VO, the two
fused through the fixed-lag smoother, how they are weighed, the long drives that choose it, and the figures
against the truth (`train` is the generic one of :mod:`.models`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register_actions(actions: Any, entry: Any) -> None:
    from ..dpc import (
        HARM_TOLERANCE,
        VO_BIAS_WINDOWS,
        VO_ROTATION_SCALE_GAINS,
        VO_ROTATION_SCALE_WINDOWS,
        VO_TRANSLATION_SCALE_WINDOWS,
    )

    predict = actions.add_parser("predict", help="corrections of a VO trajectory over windows of the model's span")
    predict.set_defaults(handler=run_predict)
    predict.add_argument("sequence", type=Path, help="KITTI-layout sequence directory (stereo)")
    predict.add_argument("--vo", type=Path, required=True, help="the VO trajectory of that sequence (`pvo vo`, KITTI poses)")
    predict.add_argument("--model", type=Path, required=True, help="model directory or a shipped name (dpc_net, dpc_net_clean)")
    predict.add_argument("--out", "-o", type=Path, required=True, help="corrections file (CSV)")
    predict.add_argument("--any-rig", action="store_true", help="use the model even on a sequence of another rig")
    correct = actions.add_parser("correct", help="run the VO, predict the corrections and fuse both (FusionGraph)")
    correct.set_defaults(handler=run_correct)
    correct.add_argument("sequence", type=Path, help="KITTI-layout sequence directory (stereo)")
    correct.add_argument("--model", type=Path, required=True, help="model directory or a shipped name (dpc_net, dpc_net_clean)")
    correct.add_argument("--out", "-o", type=Path, required=True, help="corrected trajectory (KITTI poses; the VO's beside it)")
    correct.add_argument("--rate", type=float, default=10.0, help="frame rate without times.txt (default 10 Hz)")
    correct.add_argument(
        "--method",
        choices=("fusion", "overwrite"),
        default="fusion",
        help="fusion: VO and corrections through the fixed-lag smoother (thesis §6.4.5; default); overwrite: every "
        "window's last pose overwritten by the corrected transform (the authors' shipped code)",
    )
    correct.add_argument("--any-rig", action="store_true", help="use the model even on a sequence of another rig")
    calibrate = actions.add_parser(
        "calibrate", help="the corrected transforms' residual covariance on a corpus's validation split, into the card"
    )
    calibrate.set_defaults(handler=run_calibrate)
    calibrate.add_argument("--model", type=Path, required=True, help="model directory; its model.yaml gets the result")
    calibrate.add_argument(
        "--corpus",
        type=Path,
        required=True,
        action="append",
        help="the corpus whose validation split to use (the model's; repeat to join several, e.g. a corpus and its mirror)",
    )
    calibrate.add_argument("--cache", type=Path, help="decoded-image cache (default CORPUS/.cache)")
    calibrate.add_argument(
        "--vo-spans",
        type=span_list,
        help="candidate spans (frames, comma-separated) over which the VO's covariances are made consistent for the "
        "fusion; the one whose fusion lowers the m-ATE most on the validation split (two-fold) goes into the card",
    )
    calibrate.add_argument(
        "--mirrored",
        action="store_true",
        help="predict every window also through a left-right mirror and average the two corrections (for a model "
        "trained on a corpus and its mirror, `pvo sim mirror`); the card then predicts so everywhere (predict, "
        "correct, the node)",
    )
    calibrate.add_argument(
        "--drives",
        type=Path,
        nargs="+",
        help="long validation drives of the model's rig (sequence directories, or folders of them: `pvo dpc-net drives "
        "OUT`, then OUT/<rig>): the VO span (--vo-spans, default 3,30,100,250), the fused axes and whether the "
        "validation split's mean residual is removed from the corrections are chosen on them — the choice that lowers "
        "the mean translational plus rotational m-ATE most and raises no drive's by --harm-tolerance, else nothing is "
        "fused",
    )
    calibrate.add_argument(
        "--consistent-corrections",
        action="store_true",
        help="with --drives: also try each weighing with the corrections' covariance made consistent over the same "
        "span as the VO's (per axis, on the other drives; spans longer than Δp), so the two chains are weighed by how "
        "far each drifts over it; the card then keeps those scales (calibration.correction_scale)",
    )
    calibrate.add_argument(
        "--harm-tolerance",
        type=percent,
        metavar="PERCENT",
        help="with --drives: how much a weighing may raise one drive's m-ATE (either) and still be chosen (default "
        f"{100 * HARM_TOLERANCE:g} %%, the no-harm bound; 0: it must lower every drive)",
    )
    calibrate.add_argument(
        "--vo-bias-windows",
        type=window_list,
        metavar="N[,N...]",
        help="with --drives: also try each weighing that fuses the translation with the VO's translation bias learned "
        "from the corrections over about N of them, as the fusion does (inputs.correction.vo_bias_windows), once per N "
        f"(default {','.join(f'{w:g}' for w in VO_BIAS_WINDOWS)}; 0: no such candidate); the card then keeps the chosen N "
        "(calibration.vo_bias_windows)",
    )
    calibrate.add_argument(
        "--vo-rotation-scales",
        type=gain_list,
        metavar="G[,G...]",
        help="with --drives: also try each VO-debiased weighing that fuses rotation with the VO's turns rescaled by G "
        "of the scale the corrections teach (inputs.correction.vo_rotation_scale_gain; the scale learned over "
        f"~{VO_ROTATION_SCALE_WINDOWS:g} corrections), once per G (default "
        f"{','.join(f'{g:g}' for g in VO_ROTATION_SCALE_GAINS)}; 0: no such candidate); the card then keeps the chosen "
        "one (calibration.vo_rotation_scale)",
    )
    calibrate.add_argument(
        "--vo-translation-scales",
        type=window_list,
        metavar="N[,N...]",
        help="with --drives: also try each weighing that fuses the translation with the VO's steps rescaled by the scale "
        "the corrections teach over about N of them (inputs.correction.vo_translation_scale_windows) instead of its "
        f"translation bias, once per N (default {','.join(f'{w:g}' for w in VO_TRANSLATION_SCALE_WINDOWS)}; 0: no such "
        "candidate); the card then keeps the chosen N (calibration.vo_translation_scale_windows)",
    )
    drives = actions.add_parser(
        "drives", help="render the long drives a fusion is chosen on (KITTI 03, 04, 10) or tested on (05, 06, 07), each rig"
    )
    drives.set_defaults(handler=run_drives)
    drives.add_argument("out", type=Path, help="output folder: OUT/clean, OUT/lens, OUT/calib (the clean ones, calib.txt x1.03)")
    drives.add_argument("--split", choices=("validation", "test"), default="validation", help="which drives (default validation)")
    drives.add_argument(
        "--frames", type=int, default=1000, help="frames per test drive (default 1000; validation drives: 1000, 1000, 271)"
    )
    drives.add_argument(
        "--world",
        type=int,
        default=0,
        help="0: the drives' own worlds; K > 0: other worlds along the same drives (how far a figure over them moves "
        "with the world alone; give each world its own OUT)",
    )
    drives.add_argument("--data", type=Path, help="the shared data directory (default ../shared/data)")
    drives.add_argument("--jobs", "-j", type=int, default=2, help="sequences rendered in parallel (default 2)")
    drives.add_argument(
        "--rigs", type=rig_list, default=None, help="only these rigs, comma-separated (clean,lens,calib; default all)"
    )
    evaluate = actions.add_parser("eval", help="m-ATE and mean segment errors, corrected vs uncorrected")
    evaluate.set_defaults(handler=run_eval)
    evaluate.add_argument("--gt", type=Path, required=True, help="true poses (KITTI)")
    evaluate.add_argument("--est", type=Path, required=True, help="corrected trajectory (KITTI)")
    evaluate.add_argument("--vo", type=Path, help="the uncorrected VO trajectory, for the comparison")
    evaluate.add_argument("--json", type=Path, help="also write the figures as a run-result record here")


def rig_list(text: str) -> list[str]:
    """``--rigs``: comma-separated rig names (:data:`pvo_tools.dpc.RIGS`)."""
    from ..dpc import RIGS

    rigs = [rig.strip() for rig in text.split(",") if rig.strip()]
    unknown = [rig for rig in rigs if rig not in RIGS]
    if unknown or not rigs:
        raise argparse.ArgumentTypeError(f"unknown rig(s) {', '.join(unknown) or '(none)'}: choose from {', '.join(RIGS)}")
    return rigs


def finite_non_negative(text: str, example: str, what: str) -> float:
    """A finite number >= 0 from a command-line value, else an ``ArgumentTypeError`` naming ``what``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what} (e.g. {example}), got {text!r}") from None
    if not value >= 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{what} must be finite and >= 0, got {text!r}")
    return value


def percent(text: str) -> float:
    """``--harm-tolerance 5``: a finite percentage >= 0."""
    return finite_non_negative(text, "5", "a percentage")


def window_list(text: str) -> list[float]:
    """``--vo-bias-windows 10,30,100``: finite numbers of corrections >= 0, comma-separated."""
    return [finite_non_negative(item, "30", "a number of corrections") for item in text.split(",")]


def gain_list(text: str) -> list[float]:
    """``--vo-rotation-scales 0.5,1``: gains in (0, 1] (0: none), comma-separated."""
    gains = [finite_non_negative(item, "0.5", "a gain") for item in text.split(",")]
    if any(g > 1.0 for g in gains):
        raise argparse.ArgumentTypeError(f"gains must be in (0, 1] (0: none), got {text!r}")
    return gains


def span_list(text: str) -> list[int]:
    """``--vo-spans 3,9,15``: positive frame counts, comma-separated."""
    try:
        spans = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected frame counts separated by commas (e.g. 3,9,30), got {text!r}") from None
    if min(spans) < 1:
        raise argparse.ArgumentTypeError(f"VO spans must be positive frame counts, got {text!r}")
    return spans


def _warn(lines: list[str], model: Path) -> None:
    for line in lines:
        print(f"pvo dpc-net: warning: {model}: {line}", file=sys.stderr)


def run_predict(args: argparse.Namespace) -> int:
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections
    from pvo_pseudosensors.dpc_net.rig import check_rig

    model, card = load_dpc_net(resolve_model(str(args.model)))  # a directory or a shipped name
    _warn(check_rig(card.input.get("rig"), args.sequence, args.any_rig), args.model)
    corrections = predict_corrections(model, card, args.sequence, read_kitti_poses(args.vo))
    path = corrections.write_csv(args.out)
    print(f"{path}: {len(corrections.first)} corrections over {card.hyperparameters['test_delta']}-frame windows")
    return 0


def run_correct(args: argparse.Namespace) -> int:
    from pvo_core.trajectory import write_kitti_poses
    from pvo_fusion.graph import GATED_WARNING_SECONDS
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net

    from ..dpc import card_vo_calibration, card_vo_fusion, correct_sequence, describe_vo_fusion

    model, card = load_dpc_net(resolve_model(str(args.model)))  # a directory or a shipped name
    vo_calibration = card_vo_calibration(card)
    result = correct_sequence(
        args.sequence, model, card, args.method, vo_calibration, rate_hz=args.rate, allow_any_rig=args.any_rig
    )
    _warn(result.warnings, args.model)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_kitti_poses(args.out, result.corrected)
    vo_file = args.out.with_name(args.out.stem + "_vo.txt")
    write_kitti_poses(vo_file, result.vo)
    count = len(result.corrections.first)
    how = f"{result.accepted} of {count} corrections fused" if args.method == "fusion" else f"{count} poses overwritten"
    weighed = (
        f"; VO covariances scaled by the card's calibration over {card.calibration.get('vo_span')} frames"
        if vo_calibration is not None and args.method == "fusion"
        else ""
    )
    debias = describe_vo_fusion(card_vo_fusion(card))
    if args.method == "fusion" and debias:
        weighed += f"; {debias}"
    print(f"{args.out}: {len(result.vo)} poses, {how}{weighed}; the VO alone in {vo_file}")
    if result.gated_for_s >= GATED_WARNING_SECONDS:
        _warn(
            [
                f"the fusion's gate took none of the corrections for {result.gated_for_s:.1f} s on end: the VO and the "
                "corrections disagreed for good there (a model for another rig, or a VO that lost its way)"
            ],
            args.model,
        )
    if args.method == "fusion" and card.calibration.get("fused_axes") == []:
        _warn(["its calibration on validation drives fuses no axis (no weighing was acceptable there): the VO alone"], args.model)
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    import numpy as np
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.data import DPCWindows
    from pvo_pseudosensors.dpc_net.infer import AXES, load_dpc_net, residual_covariance
    from pvo_pseudosensors.learning.checkpoint import write_card
    from pvo_pseudosensors.learning.data import Source

    from ..dpc import HARM_TOLERANCE, VO_BIAS_WINDOWS, VO_ROTATION_SCALE_GAINS, VO_TRANSLATION_SCALE_WINDOWS, rig_sequences

    drive_options = {
        "--consistent-corrections": args.consistent_corrections,
        "--harm-tolerance": args.harm_tolerance is not None,
        "--vo-bias-windows": args.vo_bias_windows is not None,
        "--vo-rotation-scales": args.vo_rotation_scales is not None,
        "--vo-translation-scales": args.vo_translation_scales is not None,
    }
    if not args.drives and any(drive_options.values()):
        given = next(name for name, on in drive_options.items() if on)
        raise ValueError(f"{given} weighs the corrections on long validation drives: give them with --drives")
    if args.harm_tolerance is None:
        args.harm_tolerance = 100 * HARM_TOLERANCE
    if args.vo_bias_windows is None:
        args.vo_bias_windows = list(VO_BIAS_WINDOWS)
    if args.vo_rotation_scales is None:
        args.vo_rotation_scales = list(VO_ROTATION_SCALE_GAINS)
    if args.vo_translation_scales is None:
        args.vo_translation_scales = list(VO_TRANSLATION_SCALE_WINDOWS)
    model, card = load_dpc_net(args.model)
    config = DPCNetConfig.from_card(card)
    manifests = [read_corpus_manifest(corpus) for corpus in args.corpus]
    validation = [s for manifest in manifests for s in rig_sequences(manifest, card)]
    sources = [Source(s.root, s.name, "validation") for s in validation]
    if not sources:
        raise ValueError(f"{', '.join(str(m.path) for m in manifests)}: no validation sequence of the model's rig")
    print(
        f"pvo dpc-net calibrate: {len(sources)} validation sequences of the model's rig (the VO runs once per sequence, "
        "then is cached) ...",
        file=sys.stderr,
        flush=True,
    )
    windows = DPCWindows(sources, config, args.cache or manifests[0].path.parent / ".cache", (config.test_delta,))
    card.calibration["mirrored"] = bool(args.mirrored)  # the inference mode the residual (and all below) is made in
    covariance, figures = residual_covariance(model, card, windows)
    for stale in (
        "fused_axes",
        "remove_mean",
        "drive_calibration",
        "vo_span",
        "vo_scale",
        "vo_static_covariance",
        "vo_span_changes",
        "correction_scale",
        "vo_bias_windows",
        "vo_rotation_scale",
        "vo_translation_scale_windows",
    ):
        card.calibration.pop(stale, None)  # a new residual: what was chosen with the old one goes
    card.calibration["residual_covariance"] = covariance.tolist()
    corpus = str(args.corpus[0]) if len(args.corpus) == 1 else [str(c) for c in args.corpus]
    card.calibration["residual"] = figures | {"corpus": corpus, "sequences": len(sources)}
    write_card(args.model, card)
    print(
        f"{args.model}: {int(figures['windows'])} validation windows of {len(sources)} sequences"
        f"{', each also predicted through the mirror' if args.mirrored else ''}; mean error translation "
        f"{figures['translation_error_m_before']:.4f} -> {figures['translation_error_m_after']:.4f} m, rotation "
        f"{figures['rotation_error_deg_before']:.4f} -> {figures['rotation_error_deg_after']:.4f} deg; residual "
        f"standard deviations (x y z rx ry rz) {np.sqrt(np.diag(covariance)).round(5).tolist()}; corrected axes (fused): "
        + (" ".join(axis for axis in AXES if figures[f"corrected_{axis}"]) or "none")
    )
    if args.drives:
        return calibrate_on_drives(args, model, card)
    if args.vo_spans:
        from ..dpc import choose_vo_span

        print(
            f"choosing the VO span among {args.vo_spans} on {len(validation)} validation sequences ...",
            file=sys.stderr,
            flush=True,
        )
        choice = choose_vo_span(model, card, validation, args.vo_spans)
        card.calibration["vo_span"] = choice.span
        card.calibration["vo_scale"] = [float(v) for v in choice.vo_calibration.scale]
        card.calibration["vo_static_covariance"] = np.asarray(choice.vo_calibration.static_covariance).tolist()
        card.calibration["vo_span_changes"] = {str(s): [round(t, 4), round(r, 4)] for s, (t, r) in choice.changes.items()}
        write_card(args.model, card)
        for span, (trans, rot) in choice.changes.items():
            print(f"  VO span {span:3d} frames: fused m-ATE {100 * trans:+.1f} % translation, {100 * rot:+.1f} % rotation")
        how = "two-fold" if choice.folds == 2 else "in sample: one sequence"
        print(f"{args.model}: VO span {choice.span} frames ({choice.sequences} validation sequences, {how})")
    return 0


def drive_folders(paths: list[Path]) -> list[Path]:
    """Sequence directories (with poses.txt) named by ``paths``: each one itself, or the sequences inside it."""
    roots: list[Path] = []
    for path in paths:
        if (path / "poses.txt").is_file():
            roots.append(path)
            continue
        inside = sorted(p for p in path.iterdir() if (p / "poses.txt").is_file()) if path.is_dir() else []
        if not inside:
            raise ValueError(f"{path}: not a sequence with poses.txt nor a folder of them")
        roots.extend(inside)
    return roots


def calibrate_on_drives(args: argparse.Namespace, model: Any, card: Any) -> int:
    """`calibrate --drives`: the VO span and the fused axes chosen on long validation drives, into the card."""
    import numpy as np
    from pvo_pseudosensors.learning.checkpoint import write_card

    from ..dpc import DRIVE_SPANS, VO_ROTATION_SCALE_WINDOWS, choose_fusion, describe_nearest

    roots = drive_folders(args.drives)
    spans = args.vo_spans or list(DRIVE_SPANS)
    print(
        f"choosing the fusion (VO spans {spans} x fused axes) on {len(roots)} validation drives "
        f"({', '.join(r.name for r in roots)}) ...",
        file=sys.stderr,
        flush=True,
    )
    tolerance = args.harm_tolerance / 100.0
    choice = choose_fusion(
        model,
        card,
        roots,
        spans,
        say=lambda line: print(line, file=sys.stderr, flush=True),
        harm_tolerance=tolerance,
        consistent_corrections=args.consistent_corrections,
        vo_bias_windows=args.vo_bias_windows,
        vo_rotation_scale_gains=args.vo_rotation_scales,
        vo_translation_scale_windows=args.vo_translation_scales,
    )
    over_span = choice.correction_scale is not None
    chosen = (
        f"span {choice.span}, axes {' '.join(choice.axes)}"
        + (", mean removed" if choice.remove_mean else "")
        + (", corrections over the span" if over_span else "")
        + (f", VO debiased over {choice.vo_bias_windows:g}" if choice.vo_bias_windows else "")
        + (f", turns rescaled x{choice.vo_rotation_scale_gain:g}" if choice.vo_rotation_scale_gain else "")
        + (f", steps rescaled over {choice.vo_translation_scale_windows:g}" if choice.vo_translation_scale_windows else "")
        if choice.axes
        else None
    )
    card.calibration["fused_axes"] = choice.axes
    card.calibration["remove_mean"] = choice.remove_mean
    card.calibration.pop("correction_scale", None)
    if over_span:
        card.calibration["correction_scale"] = choice.correction_scale
    card.calibration.pop("vo_bias_windows", None)
    if choice.vo_bias_windows:
        card.calibration["vo_bias_windows"] = choice.vo_bias_windows
    card.calibration.pop("vo_rotation_scale", None)
    if choice.vo_rotation_scale_gain:
        card.calibration["vo_rotation_scale"] = {"windows": VO_ROTATION_SCALE_WINDOWS, "gain": choice.vo_rotation_scale_gain}
    card.calibration.pop("vo_translation_scale_windows", None)
    if choice.vo_translation_scale_windows:
        card.calibration["vo_translation_scale_windows"] = choice.vo_translation_scale_windows
    card.calibration["drive_calibration"] = {
        "drives": [str(r) for r in roots],
        "rule": (
            "lowers the mean translational and rotational m-ATE and raises no drive's by the harm tolerance or more; "
            "the lowest mean sum"
        ),
        "harm_tolerance": tolerance,
        "chosen": chosen,
        "candidates": choice.candidates,
    }
    if choice.vo_calibration is not None:
        card.calibration["vo_span"] = choice.span
        card.calibration["vo_scale"] = [float(v) for v in choice.vo_calibration.scale]
        card.calibration["vo_static_covariance"] = np.asarray(choice.vo_calibration.static_covariance).tolist()
    write_card(args.model, card)
    if chosen is None:
        bound = "lowered every drive's m-ATE" if tolerance == 0.0 else f"kept every drive's m-ATE within +{100 * tolerance:g} %"
        print(f"{args.model}: no choice {bound} while lowering the mean: nothing is fused (the VO alone)")
        nearest = describe_nearest(choice.candidates)
        if nearest is not None:
            print(f"  {nearest}")
    else:
        mean = 100 * np.asarray(
            next(
                c["mean"]
                for c in choice.candidates.values()
                if c["span"] == choice.span
                and c["axes"] == choice.axes
                and c["remove_mean"] == choice.remove_mean
                and c.get("corrections_over_span", False) == over_span
                and c.get("vo_bias_windows", 0.0) == choice.vo_bias_windows
                and c.get("vo_rotation_scale_gain", 0.0) == choice.vo_rotation_scale_gain
                and c.get("vo_translation_scale_windows", 0.0) == choice.vo_translation_scale_windows
            )
        )
        print(
            f"{args.model}: fused axes {' '.join(choice.axes)}"
            + (" (the validation mean error removed)" if choice.remove_mean else "")
            + (", the corrections' covariance made consistent over the span too" if over_span else "")
            + (
                f", the VO's translation bias learned from about {choice.vo_bias_windows:g} corrections"
                if choice.vo_bias_windows
                else ""
            )
            + (
                f", its turns rescaled by {choice.vo_rotation_scale_gain:g} of the scale they teach"
                if choice.vo_rotation_scale_gain
                else ""
            )
            + (
                f", its steps rescaled by the scale about {choice.vo_translation_scale_windows:g} corrections teach"
                if choice.vo_translation_scale_windows
                else ""
            )
            + f", VO span {choice.span} frames ({len(roots)} validation "
            f"drives; m-ATE {mean[0]:+.1f} % translation, {mean[1]:+.1f} % rotation)"
        )
    return 0


def run_drives(args: argparse.Namespace) -> int:
    from ..dpc import RIGS, TEST_DRIVES, VALIDATION_DRIVES, in_world, render_drives
    from ..paths import data_directory

    if args.frames < 100:
        raise ValueError(f"--frames must be >= 100 (segment errors need 100 m and more), got {args.frames}")
    drives = in_world(VALIDATION_DRIVES if args.split == "validation" else TEST_DRIVES, args.world)
    folders = render_drives(
        drives,
        args.data or data_directory(),
        args.out,
        args.frames,
        args.jobs,
        lambda line: print(line, file=sys.stderr),
        args.rigs or RIGS,
    )
    for rig, paths in folders.items():
        print(f"{rig}: " + " ".join(str(p) for p in paths))
    return 0


def run_eval(args: argparse.Namespace) -> int:
    import numpy as np
    from pvo_core.results import RunResult
    from pvo_core.trajectory import read_kitti_poses

    from pvo_core import metrics

    truth = read_kitti_poses(args.gt)
    rows = {"corrected": read_kitti_poses(args.est)} | ({"VO": read_kitti_poses(args.vo)} if args.vo else {})
    figures: dict[str, float] = {}
    print(f"{'trajectory':<12}{'m-ATE trans (m)':>17}{'m-ATE rot (deg)':>17}{'seg trans (%)':>15}{'seg rot (deg/m)':>17}")
    for name, poses in rows.items():
        if len(poses) != len(truth):
            raise ValueError(f"{name}: {len(poses)} poses for the {len(truth)} of {args.gt}")
        trajectory = metrics.mean_trajectory_errors(truth, poses)
        segments = metrics.thesis_segment_errors(truth, poses)
        values = {
            "m_ate_trans": trajectory.mean_translation,
            "m_ate_rot_deg": float(np.degrees(trajectory.rotation.mean())),
            "seg_trans_percent": segments.translation_percent,
            "seg_rot_deg_per_m": segments.rotation_deg_per_m,
        }
        figures.update({f"{name}.{k}": v for k, v in values.items()})
        print(
            f"{name:<12}{values['m_ate_trans']:>17.3f}{values['m_ate_rot_deg']:>17.3f}{values['seg_trans_percent']:>15.3f}"
            f"{values['seg_rot_deg_per_m']:>17.5f}"
        )
    if args.json:
        RunResult("eval", f"dpc-net {args.est.name}", figures=figures, inputs={"gt": str(args.gt), "est": str(args.est)}).write(
            args.json
        )
    return 0
