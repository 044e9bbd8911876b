"""`pvo vo SEQUENCE_DIR -o TRAJ`: the stereo VO on a KITTI-layout sequence, without ROS; `pvo vo calibrate`: the
VO's covariance calibrated on a corpus split, recorded in a file of its own (`pvo_frontend.vo_calibration`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from pvo_core.readers import KittiSequence
from pvo_core.trajectory import write_kitti_poses
from pvo_frontend.offline import run_sequence, summarise
from pvo_frontend.vo import VOConfig, from_flat

from ..overrides import parse_overrides
from ..progress import Progress


def add_sequence_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sequence_dir", type=Path, help="KITTI odometry sequence directory (image_0/1, calib.txt)")
    parser.add_argument("--poses", type=Path, help="ground-truth poses for the summary (default SEQUENCE_DIR/poses.txt)")
    parser.add_argument("--rate", type=float, help="frame rate (Hz) when there is no times.txt (default 10)")


def register(sub: Any) -> None:
    vo = sub.add_parser("vo", help="run the stereo VO on a KITTI sequence directory (no ROS)")
    vo.set_defaults(handler=run)
    add_sequence_arguments(vo)
    vo.add_argument("--out", "-o", type=Path, required=True, help="trajectory file to write (KITTI pose format)")
    vo.add_argument("--times", type=Path, help="frame times file (default SEQUENCE_DIR/times.txt)")
    vo.add_argument("--colour", action="store_true", help="use image_2/image_3 and P2/P3")
    vo.add_argument("--start", type=int, default=0, help="first frame (position in the sequence)")
    vo.add_argument("--count", type=int, help="number of frames (default: all)")
    vo.add_argument(
        "--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter, e.g. -p solver.loss=huber (repeatable)"
    )
    vo.add_argument("--params-file", type=Path, help="ROS-style YAML with stereo_vo parameters (e.g. config/stereo_vo.yaml)")
    vo.add_argument(
        "--probe",
        metavar="MODEL",
        help="PROBE noise model: a directory from `pvo probe train` or probe_kitti (= -p probe.model=MODEL)",
    )
    vo.add_argument("--relative", type=Path, help="also write per-frame motions and covariances (.npz) for `pvo eval --relative`")
    vo.add_argument("--quiet", "-q", action="store_true", help="no progress output")
    register_calibrate(sub)


def register_calibrate(sub: Any) -> None:
    cal = sub.add_parser(
        "vo-calibrate",
        prog="pvo vo calibrate",
        help="(pvo vo calibrate) the VO's per-axis covariance scales on a corpus split, recorded for the fusion",
        description="Run the VO (its defaults, or the settings given) over one preset's sequences (--preset, default "
        "urban) of a corpus split and "
        "record the per-axis variance scales that make its frame-to-frame covariances consistent there, with the "
        "VO's settings, as a calibration file (the shipped one: src/pvo_frontend/calibration/default_vo.yaml; `pvo demo "
        "--vo-calibration` takes another). Then, with those scales, how consistent the VO is by the size of its own "
        "sigma (mean e^2/sigma^2 per axis in bins of sigma over its 90th percentile; 1 = consistent). A PROBE model's "
        "VO is calibrated into its card: `pvo probe calibrate`.",
    )
    cal.set_defaults(handler=run_calibrate)
    cal.add_argument("--corpus", type=Path, required=True, help="a `pvo sim corpus` directory")
    cal.add_argument("--split", default="validation", choices=("train", "validation"), help="default validation")
    cal.add_argument("--preset", default="urban", help="the corpus preset to calibrate on (default urban)")
    cal.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter (not probe.model)")
    cal.add_argument("--params-file", type=Path, help="ROS-style YAML with stereo_vo parameters")
    out = cal.add_mutually_exclusive_group(required=True)
    out.add_argument("--out", "-o", type=Path, help="calibration file to write (its other fields kept)")
    out.add_argument("--dry-run", action="store_true", help="print the scales, write nothing")


def open_sequence(
    sequence_dir: Path,
    rate: float | None,
    times: Path | None,
    colour: bool,
    start: int,
    count: int | None,
    poses: Path | None = None,
) -> KittiSequence:
    """The sequence with 10 Hz stamps when neither a rate nor a times file is given."""
    rate_hz = rate if (rate is not None or times is not None or (sequence_dir / "times.txt").is_file()) else 10.0
    return KittiSequence(
        sequence_dir, colour=colour, times_file=times, rate_hz=rate_hz, poses_file=poses, start=start, count=count
    )


def frame_imu(sequence_dir: Path, sequence: KittiSequence) -> np.ndarray | None:
    """The IMU reading at each frame from ``SEQUENCE_DIR/imu.csv`` when there is one (`pvo sim` writes it)."""
    from pvo_core.readers import imu_at_stamps, read_imu_csv

    path = Path(sequence_dir) / "imu.csv"
    if not path.is_file():
        return None
    try:
        return imu_at_stamps(read_imu_csv(path), np.asarray(sequence.stamps, dtype=float))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def vo_config(items: list[str] | None, params_file: Path | None = None) -> VOConfig:
    """The VO's settings from a ``stereo_vo`` params file and ``NAME=VALUE`` items (those win). The file is the
    node's: its own settings (frames, path publishing, overload) mean nothing offline and are left out; any other
    unknown name is an error."""
    from pvo_frontend.stereo_vo_settings import node_setting_names

    node_only = node_setting_names()
    from_file = {k: v for k, v in parse_overrides(None, params_file, node="stereo_vo").items() if k not in node_only}
    return from_flat({**from_file, **parse_overrides(items)})


def run(args: argparse.Namespace) -> int:
    config = vo_config([*(args.param or []), *([f"probe.model={args.probe}"] if args.probe else [])], args.params_file)
    sequence = open_sequence(args.sequence_dir, args.rate, args.times, args.colour, args.start, args.count, args.poses)
    bar = None if args.quiet else Progress(len(sequence), "vo")
    vo_run = run_sequence(sequence, config, progress=bar.update if bar else None, imu=frame_imu(args.sequence_dir, sequence))
    if bar:
        bar.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_kitti_poses(args.out, vo_run.poses)
    if args.relative is not None:
        np.savez(args.relative, **vo_run.relative())
    summary = summarise(vo_run, sequence.poses)
    print(
        f"wrote {args.out}: {len(vo_run.poses)} poses, {summary['lost']} lost frame(s), "
        f"median {summary['median_ms']:.1f} ms/frame"
    )
    if sequence.poses is not None:
        print(
            f"against {args.poses or 'poses.txt'}: end drift {summary['end_drift_percent']:.3f} % of {summary['path_m']:.1f} m, "
            f"ATE mean {summary['ate_mean_m']:.3f} m, ANEES {summary['anees']:.2f}"
        )
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    """`pvo vo calibrate`: parse, call `pvo_tools.vo_calibration.calibrate_vo_on_corpus`, print, record."""
    import shlex

    from pvo_frontend.vo_calibration import write_vo_calibration

    from ..errors import PvoError
    from ..vo_calibration import calibrate_and_report, calibration_entry

    config = vo_config(args.param, args.params_file)
    if config.probe.model:
        raise PvoError(
            f"probe.model={config.probe.model}: a PROBE model's VO is calibrated into its card: pvo probe calibrate "
            f"--model {config.probe.model} --corpus {args.corpus}"
        )
    result = calibrate_and_report(args.corpus, config, args.split, args.preset, "the VO's ")
    if args.dry_run:
        return 0
    command = shlex.join(["pvo", "vo", "calibrate", *args.argv[1:]])
    entry = calibration_entry(result, config, args.corpus, args.split, args.preset, command)
    print(f"wrote {write_vo_calibration(args.out, entry)} (vo_calibration)")
    return 0
