"""`pvo dpc-net predict|correct|eval`: DPC-Net's corrections of this project's stereo VO, the two fused through
the fixed-lag smoother, and the figures against the truth (`train` is the generic one of :mod:`.models`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register_actions(actions: Any, entry: Any) -> None:
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
    calibrate.add_argument("--corpus", type=Path, required=True, help="the corpus whose validation split to use (the model's)")
    calibrate.add_argument("--cache", type=Path, help="decoded-image cache (default CORPUS/.cache)")
    calibrate.add_argument(
        "--vo-spans",
        type=span_list,
        help="candidate spans (frames, comma-separated) over which the VO's covariances are made consistent for the "
        "fusion; the one whose fusion lowers the m-ATE most on the validation split (two-fold) goes into the card",
    )
    evaluate = actions.add_parser("eval", help="m-ATE and mean segment errors, corrected vs uncorrected")
    evaluate.set_defaults(handler=run_eval)
    evaluate.add_argument("--gt", type=Path, required=True, help="true poses (KITTI)")
    evaluate.add_argument("--est", type=Path, required=True, help="corrected trajectory (KITTI)")
    evaluate.add_argument("--vo", type=Path, help="the uncorrected VO trajectory, for the comparison")
    evaluate.add_argument("--json", type=Path, help="also write the figures as a run-result record here")


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
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net

    from ..dpc import card_vo_calibration, correct_sequence

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
    print(f"{args.out}: {len(result.vo)} poses, {how}{weighed}; the VO alone in {vo_file}")
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    import numpy as np
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.data import DPCWindows, vo_signature
    from pvo_pseudosensors.dpc_net.infer import AXES, load_dpc_net, residual_covariance
    from pvo_pseudosensors.learning.checkpoint import write_card
    from pvo_pseudosensors.learning.data import Source

    from ..dpc import rig_sequences

    model, card = load_dpc_net(args.model)
    config = DPCNetConfig.from_card(card)
    manifest = read_corpus_manifest(args.corpus)
    sources = [Source(s.root, s.name, "validation") for s in rig_sequences(manifest, card)]
    if not sources:
        raise ValueError(f"{manifest.path}: no validation sequence of the model's rig")
    print(
        f"pvo dpc-net calibrate: {len(sources)} validation sequences of the model's rig (the VO runs once per sequence, "
        "then is cached) ...",
        file=sys.stderr,
        flush=True,
    )
    windows = DPCWindows(sources, config, args.cache or manifest.path.parent / ".cache", (config.test_delta,))
    covariance, figures = residual_covariance(model, card, windows)
    if card.input.get("rig"):  # calibrated for this VO
        card.input["rig"]["vo"] = vo_signature()
    card.calibration["residual_covariance"] = covariance.tolist()
    card.calibration["residual"] = figures | {"corpus": str(args.corpus), "sequences": len(sources)}
    write_card(args.model, card)
    print(
        f"{args.model}: {int(figures['windows'])} validation windows of {len(sources)} sequences; mean error translation "
        f"{figures['translation_error_m_before']:.4f} -> {figures['translation_error_m_after']:.4f} m, rotation "
        f"{figures['rotation_error_deg_before']:.4f} -> {figures['rotation_error_deg_after']:.4f} deg; residual "
        f"standard deviations (x y z rx ry rz) {np.sqrt(np.diag(covariance)).round(5).tolist()}; corrected axes (fused): "
        + (" ".join(axis for axis in AXES if figures[f"corrected_{axis}"]) or "none")
    )
    if args.vo_spans:
        from ..dpc import choose_vo_span

        validation = rig_sequences(manifest, card)
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
