"""`pvo probe train SEQUENCE_DIR... -o MODEL` and `pvo probe eval SEQUENCE_DIR --model MODEL`: PROBE's learned
per-feature noise for the stereo VO (thesis ch. 4, app. A)."""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import PvoError
from .vo import frame_imu, open_sequence, vo_config


def register(sub: Any) -> None:
    probe = sub.add_parser("probe", help="PROBE: learned per-feature noise for the stereo VO (train, eval)")
    actions = probe.add_subparsers(dest="action", required=True, metavar="ACTION")
    train = actions.add_parser("train", help="train a PROBE model on KITTI-layout sequences (with their poses, or by EM)")
    train.set_defaults(handler=run_train)
    train.add_argument(
        "sequences",
        type=Path,
        nargs="+",
        metavar="SEQUENCE",
        help="KITTI-layout sequence directories (the VO's own tracks), or raw-derived KLT track files (*.mat)",
    )
    train.add_argument(
        "--track-images", type=Path, help="left images (KITTI image_0 layout) for the image predictors of *.mat tracks"
    )
    train.add_argument("--frames", help="frames A:B of *.mat tracks (default: all)")
    train.add_argument("--out", "-o", type=Path, required=True, help="model directory to write (model.npz + model.yaml)")
    train.add_argument("--kind", choices=("gk", "knn"), default="gk", help="PROBE-GK (default) or the isotropic k-NN PROBE")
    train.add_argument("--em", action="store_true", help="train without ground truth by expectation maximisation (GK)")
    train.add_argument("--em-iterations", type=int, default=5, help="EM iterations (default 5)")
    train.add_argument(
        "--poses", type=Path, action="append", help="poses file per sequence, in order (default SEQUENCE_DIR/poses.txt)"
    )
    train.add_argument("--rate", type=float, help="frame rate (Hz) when there is no times.txt (default 10)")
    train.add_argument("--start", type=int, default=0, help="first frame of every sequence")
    train.add_argument("--count", type=int, help="frames per sequence (default: all)")
    train.add_argument("--no-image", action="store_true", help="track predictors only (no image predictors)")
    train.add_argument("--imu", action="store_true", help="IMU predictors too (SEQUENCE_DIR/imu.csv, or the .mat's IMU)")
    train.add_argument("--patch", type=int, default=32, help="patch side for the image predictors (px, default 32)")
    train.add_argument(
        "--radius", type=float, default=0.25, help="GK kernel support in normalised predictor units (default 0.25)"
    )
    train.add_argument("--neighbours", type=int, default=8, help="GK: stored errors per query (default 8)")
    train.add_argument(
        "--prior",
        choices=("fitted", "nominal"),
        default="fitted",
        help="GK prior: the training errors' static Student-t (fitted, default) or --prior-samples of (1, 1, 2) px (nominal)",
    )
    train.add_argument("--prior-dof", type=float, default=3.0, help="GK fitted prior: its Student-t dof (default 3)")
    train.add_argument("--prior-samples", type=float, help="GK nominal prior: its weight in virtual samples (default 3)")
    train.add_argument(
        "--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter for the runs that collect the tracks"
    )
    train.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    cal = actions.add_parser(
        "calibrate",
        help="the VO with a PROBE model over a corpus split: the per-axis covariance scales that make it consistent, "
        "recorded in the model card for the fusion",
    )
    cal.set_defaults(handler=run_calibrate)
    cal.add_argument("--model", required=True, help="PROBE model directory (its model.yaml gets vo_calibration)")
    cal.add_argument("--corpus", type=Path, required=True, help="a `pvo sim corpus` directory")
    cal.add_argument("--split", default="validation", choices=("train", "validation"), help="default validation")
    cal.add_argument("--preset", default="urban", help="the corpus preset to calibrate on (default urban)")
    cal.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter")
    cal.add_argument("--dry-run", action="store_true", help="print the scales, leave the card as it is")
    ev = actions.add_parser("eval", help="the VO with and without a PROBE model on a sequence with poses")
    ev.set_defaults(handler=run_eval)
    ev.add_argument("sequence", type=Path, metavar="SEQUENCE_DIR", help="KITTI-layout sequence directory with poses")
    ev.add_argument("--model", required=True, help="PROBE model directory or probe_kitti")
    ev.add_argument("--poses", type=Path, help="ground-truth poses (default SEQUENCE_DIR/poses.txt)")
    ev.add_argument("--rate", type=float, help="frame rate (Hz) when there is no times.txt (default 10)")
    ev.add_argument("--start", type=int, default=0, help="first frame")
    ev.add_argument("--count", type=int, help="number of frames (default: all)")
    ev.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter (both runs)")
    ev.add_argument("--out", "-o", type=Path, help="write metrics.json here")


def run_train(args: argparse.Namespace) -> int:
    from pvo_frontend.probe.gk import GKConfig
    from pvo_frontend.probe.predictors import PredictorConfig
    from pvo_frontend.probe.sequences import collect, train_on_sequences

    def say(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    poses = args.poses or []
    if poses and len(poses) != len(args.sequences):
        raise ValueError(f"{len(poses)} --poses files for {len(args.sequences)} sequences (give one per sequence, in order)")
    config = vo_config(args.param)
    predictors = PredictorConfig(patch=args.patch, image=not args.no_image, imu=args.imu)
    if args.prior_samples is not None and args.prior != "nominal":
        raise ValueError(
            "--prior-samples weighs the nominal prior: give --prior nominal with it (a fitted prior has prior-dof + 2)"
        )
    gk = GKConfig(
        radius=args.radius,
        max_neighbours=args.neighbours,
        prior=args.prior,
        prior_dof=args.prior_dof,
        prior_samples=args.prior_samples,
    )
    data, cameras = [], {}
    for index, directory in enumerate(args.sequences):
        if directory.suffix == ".mat":
            tracked, camera = _tracks_data(directory, predictors, args.frames, args.track_images, say)
            cameras[tracked.name] = camera
            data.append(tracked)
            continue
        sequence = open_sequence(directory, args.rate, None, False, args.start, args.count, poses[index] if poses else None)
        if sequence.poses is None and not args.em:
            raise ValueError(f"{directory}: no poses.txt (give --poses, or --em to train without ground truth)")
        say(f"collecting tracks from {directory} ({len(sequence)} frames) ...")
        imu = frame_imu(directory, sequence)
        if args.imu and imu is None:
            raise ValueError(f"{directory}: --imu needs an imu.csv (t,wx,wy,wz,fx,fy,fz)")
        collected = collect(sequence, config, predictors, name=str(directory), imu=imu)
        cameras[collected.name] = sequence.camera()
        data.append(collected)
    command = "pvo " + shlex.join(getattr(args, "argv", sys.argv[1:]))
    record = {"sequences": [str(d) for d in args.sequences], "command": command, "ground_truth": not args.em}
    model = train_on_sequences(
        data,
        lambda d: cameras[d.name],
        predictors,
        kind=args.kind,
        em=args.em,
        em_iterations=args.em_iterations,
        gk=gk,
        nominal_sigma=tuple(config.solver.pixel_sigma),
        say=say,
        training=record,
    )
    model.save(args.out)
    samples = len(model.estimator.errors)
    print(f"wrote {args.out}: PROBE {args.kind}, {samples} stored samples, predictors {', '.join(predictors.names)}")
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    """`pvo probe calibrate`: parse, call `pvo_tools.vo_calibration.calibrate_vo_on_corpus`, print, record."""

    from pvo_frontend.probe.model import resolve_model, write_vo_calibration

    from ..vo_calibration import calibrate_and_report, calibration_entry

    model = resolve_model(args.model)
    if not args.dry_run and Path(args.model) != model:
        # a shipped name resolves to the installed copy, which the next build replaces: write the source's card
        raise PvoError(
            f"{args.model}: a shipped model's name; give its directory (src/pvo_frontend/models/{args.model}) "
            "to record in its card"
        )
    base = vo_config(args.param)
    config = replace(base, probe=replace(base.probe, model=str(model)))
    result = calibrate_and_report(args.corpus, config, args.split, args.preset, f"{model}: the VO's ")
    if args.dry_run:
        return 0
    command = " ".join(
        [
            "pvo probe calibrate",
            f"--model {args.model}",
            f"--corpus {args.corpus}",
            f"--split {args.split}",
            f"--preset {args.preset}",
            *(f"-p {p}" for p in args.param or []),
        ]
    )
    entry = calibration_entry(result, config, args.corpus, args.split, args.preset, command)
    print(f"wrote {write_vo_calibration(model, entry)} (vo_calibration)")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from pvo_frontend.offline import run_sequence, summarise

    from pvo_core import metrics

    base = vo_config(args.param)
    with_probe = replace(base, probe=replace(base.probe, model=args.model))
    sequence = open_sequence(args.sequence, args.rate, None, False, args.start, args.count, args.poses)
    if sequence.poses is None:
        raise ValueError(f"{args.sequence}: no poses to evaluate against (give --poses)")
    rows: dict[str, dict[str, float]] = {}
    imu = frame_imu(args.sequence, sequence)
    for label, config in (("VO", base), ("VO + PROBE", with_probe)):
        run = run_sequence(sequence, config, imu=imu)
        summary = summarise(run, sequence.poses)
        figures = metrics.armse(sequence.poses, run.poses)
        rows[label] = {
            "end_drift_percent": summary["end_drift_percent"],
            "ate_mean_m": summary["ate_mean_m"],
            "armse_trans_m": figures["trans"],
            "armse_rot_rad": figures["rot"],
            "median_ms": summary["median_ms"],
            "lost": summary["lost"],
        }
    print(f"{args.sequence} ({len(sequence)} frames), model {args.model}")
    print(f"{'':<12}{'end drift %':>12}{'ATE mean m':>12}{'ARMSE m':>10}{'ARMSE rad':>11}{'ms/frame':>10}{'lost':>6}")
    for label, r in rows.items():
        print(
            f"{label:<12}{r['end_drift_percent']:>12.3f}{r['ate_mean_m']:>12.3f}{r['armse_trans_m']:>10.3f}"
            f"{r['armse_rot_rad']:>11.5f}{r['median_ms']:>10.1f}{r['lost']:>6.0f}"
        )
    if args.out is not None:
        from pvo_core.results import RunResult

        figures_flat = {f"{label}.{k}": float(v) for label, r in rows.items() for k, v in r.items()}
        path = RunResult("probe/eval", str(args.sequence), figures=figures_flat, inputs={"model": str(args.model)}).write(
            args.out
        )
        print(f"wrote {path}")
    return 0


def _tracks_data(path: Path, predictors: Any, frames: str | None, images: Path | None, say: Any) -> tuple[Any, Any]:
    """Frame pairs of raw-derived KLT tracks (with their true motions) as training data."""
    from pvo_core.imageio import read_image
    from pvo_core.readers import read_klt_tracks
    from pvo_frontend.probe.evaluation import track_pairs
    from pvo_frontend.probe.sequences import SequenceData

    tracks = read_klt_tracks(path)
    first, last = 1, len(tracks)
    if frames:
        try:
            a, b = (int(v) for v in frames.split(":"))
        except ValueError:
            raise ValueError(f"--frames {frames!r} must be A:B, e.g. 1:160") from None
        first, last = max(1, a), min(len(tracks), b)
    if predictors.image and images is None:
        raise ValueError(f"{path}: the image predictors need --track-images (or give --no-image)")

    def image_of(k: int) -> Any:
        assert images is not None
        file = images / f"{k:06d}.png"
        if not file.is_file():
            raise ValueError(f"{file}: no image for frame {k} of {path.name} (limit --frames)")
        image = read_image(file)
        return image if image.ndim == 2 else image.mean(axis=2).astype("uint8")

    say(f"collecting tracks from {path} (frames {first}-{last - 1}) ...")
    pairs, motions, _ = track_pairs(tracks, predictors, range(first, last), image_of if predictors.image else None)
    return SequenceData(str(path), pairs, motions, motions), tracks.camera
