"""`pvo dpc-net predict|correct|eval`: DPC-Net's corrections of this project's stereo VO, the two fused through
the fixed-lag smoother, and the figures against the truth (`train` is the generic one of :mod:`.models`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register_actions(actions: Any, entry: Any) -> None:
    predict = actions.add_parser("predict", help="corrections of a VO trajectory over windows of the model's span")
    predict.set_defaults(handler=run_predict)
    predict.add_argument("sequence", type=Path, help="KITTI-layout sequence directory (stereo)")
    predict.add_argument("--vo", type=Path, required=True, help="the VO trajectory of that sequence (`pvo vo`, KITTI poses)")
    predict.add_argument("--model", type=Path, required=True, help="model directory")
    predict.add_argument("--out", "-o", type=Path, required=True, help="corrections file (CSV)")
    correct = actions.add_parser("correct", help="run the VO, predict the corrections and fuse both (FusionGraph)")
    correct.set_defaults(handler=run_correct)
    correct.add_argument("sequence", type=Path, help="KITTI-layout sequence directory (stereo)")
    correct.add_argument("--model", type=Path, required=True, help="model directory")
    correct.add_argument("--out", "-o", type=Path, required=True, help="corrected trajectory (KITTI poses; the VO's beside it)")
    correct.add_argument("--rate", type=float, default=10.0, help="frame rate without times.txt (default 10 Hz)")
    evaluate = actions.add_parser("eval", help="m-ATE and mean segment errors, corrected vs uncorrected")
    evaluate.set_defaults(handler=run_eval)
    evaluate.add_argument("--gt", type=Path, required=True, help="true poses (KITTI)")
    evaluate.add_argument("--est", type=Path, required=True, help="corrected trajectory (KITTI)")
    evaluate.add_argument("--vo", type=Path, help="the uncorrected VO trajectory, for the comparison")
    evaluate.add_argument("--json", type=Path, help="also write the figures as a run-result record here")


def run_predict(args: argparse.Namespace) -> int:
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections

    model, card = load_dpc_net(args.model)
    corrections = predict_corrections(model, card, args.sequence, read_kitti_poses(args.vo))
    path = corrections.write_csv(args.out)
    print(f"{path}: {len(corrections.first)} corrections over {card.hyperparameters['test_delta']}-frame windows")
    return 0


def run_correct(args: argparse.Namespace) -> int:
    import numpy as np
    from pvo_core.readers import KittiSequence
    from pvo_core.trajectory import write_kitti_poses
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections

    from pvo_fusion import FusionGraph, RelativeMeasurement, ordered_events, run_offline
    from pvo_fusion.config import from_flat

    model, card = load_dpc_net(args.model)
    sequence = KittiSequence(args.sequence, rate_hz=None if (args.sequence / "times.txt").is_file() else args.rate)
    run = run_sequence(sequence, VOConfig())
    corrections = predict_corrections(model, card, args.sequence, run.poses)
    stamps = 1_000_000_000 + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
    relative = run.relative()
    vo = [
        RelativeMeasurement(int(stamps[k + 1]), int(stamps[k]), relative["transforms"][k], relative["covariances"][k])
        for k in range(len(stamps) - 1)
    ]
    others = [
        ("correction", RelativeMeasurement(int(stamps[b]), int(stamps[a]), t, c))
        for a, b, t, c in zip(corrections.first, corrections.last, corrections.transforms, corrections.covariances, strict=True)
    ]
    graph = FusionGraph(from_flat({"prior.source": "given"}))
    graph.set_initial_pose(np.eye(4))
    fused = run_offline(graph, stamps, ordered_events(vo, others))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_kitti_poses(args.out, fused.poses)
    vo_file = args.out.with_name(args.out.stem + "_vo.txt")
    write_kitti_poses(vo_file, run.poses)
    accepted = fused.counts.get("correction.accepted", 0)
    print(f"{args.out}: {len(stamps)} poses, {accepted} of {len(others)} corrections fused; the VO alone in {vo_file}")
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
