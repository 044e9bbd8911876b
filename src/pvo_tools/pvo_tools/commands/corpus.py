"""`pvo sim corpus OUT`: render a training corpus of many varied sequences with :mod:`pvo_sim.corpus`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pvo_sim.corpus import CorpusConfig, render_corpus

from ..progress import CountProgress
from .sim import parse_size


def register(sub: Any) -> None:
    corpus = sub.add_parser(
        "sim-corpus",
        prog="pvo sim corpus",
        description="Render N varied sequences (place, date, time of day, path, speed, preset, appearance, camera, "
        "degradations drawn per sequence) into OUT/<sequence>/ with OUT/manifest.yaml (configurations, splits, hashes). "
        "Re-running resumes: complete sequences are kept.",
    )
    corpus.set_defaults(handler=run)
    corpus.add_argument("out", type=Path, help="corpus directory (e.g. data/corpus)")
    corpus.add_argument("--sequences", type=int, default=20, help="number of sequences (default 20)")
    corpus.add_argument("--frames", type=int, default=200, help="stereo frames per sequence (default 200)")
    corpus.add_argument("--size", default="620x188", help="image size WxH (default 620x188)")
    corpus.add_argument("--presets", default="urban,planetary", help="comma-separated presets (default urban,planetary)")
    corpus.add_argument("--seed", type=int, default=0, help="corpus seed: sequence i is drawn from (seed, i) (default 0)")
    corpus.add_argument("--jobs", "-j", type=int, default=1, help="sequences rendered in parallel processes (default 1)")
    corpus.add_argument("--colour", action="store_true", help="colour images (image_2/image_3)")
    corpus.add_argument("--split", default="0.7,0.15,0.15", help="train,validation,test shares (default 0.7,0.15,0.15)")
    corpus.add_argument(
        "--supersample",
        type=int,
        default=1,
        help="render N times larger and average down (1-4; default 1: the models read the corpus at half size or "
        "less, which integrates pixel areas anyway; pvo sim's default 2 costs a third of the rate)",
    )
    corpus.add_argument(
        "--sky",
        choices=("gradient", "sun"),
        default="gradient",
        help="every sequence's sky: gradient (one for every sun; default) or sun (the CIE standard skies, brightest "
        "about the sun); the draws are the same either way",
    )
    corpus.add_argument("--quiet", "-q", action="store_true", help="no progress output")
    corpus.add_argument(
        "--dry-run",
        action="store_true",
        help="render nothing: say how many sequences OUT keeps and would render, and which the latest renderer "
        "revision draws differently from the one before (e.g. to check a model card's corpus command)",
    )
    corpus.add_argument(
        "--lens-distortion",
        type=float,
        nargs="+",
        default=[],
        metavar="K",
        help="one lens for every sequence: plumb-bob k1 [k2 k3] (DPC-Net's rig: -0.3 0.2 0.01)",
    )
    for name, what in (("focal", "focal length"), ("baseline", "stereo baseline")):
        corpus.add_argument(
            f"--calib-{name}-scale",
            type=float,
            default=1.0,
            metavar="S",
            help=f"one wrong calibration for every sequence: calib.txt written with the {what} times S (images unchanged; "
            f"DPC-Net's Table 6.1 rig, e.g. --calib-{name}-scale 1.03)",
        )
    shares = corpus.add_argument_group(
        "degradations (the share of sequences drawn with each; every sequence draws each one on its own)"
    )
    defaults = CorpusConfig()
    for name, what in DEGRADATION_SHARES.items():
        shares.add_argument(
            "--" + name.replace("_", "-"),
            type=float,
            default=getattr(defaults, name),
            metavar="F",
            help=f"share of sequences {what} (default {getattr(defaults, name):g})",
        )
    kitti = corpus.add_argument_group("real vehicle motion (each sequence drives a window of a KITTI drive)")
    kitti.add_argument(
        "--kitti-poses", type=Path, help="directory of KITTI odometry pose files NN.txt (e.g. ../shared/data/kitti/poses)"
    )
    kitti.add_argument("--kitti-train", default="00,02,08,09", help="drives for the train split (default 00,02,08,09)")
    kitti.add_argument("--kitti-validation", default="04,10", help="drives for the validation split (default 04,10)")
    kitti.add_argument("--kitti-test", default="05,06,07", help="drives for the test split (default 05,06,07)")
    kitti.add_argument(
        "--kitti-turning",
        action="store_true",
        help="draw windows in proportion to how much the vehicle turns in them (default: uniformly)",
    )
    kitti.add_argument(
        "--kitti-level-frames",
        type=int,
        default=0,
        metavar="N",
        help="level each window over N frames of its drive around it, so that short windows pitch against the flat "
        "ground as long drives do (e.g. 1000, the long drives' length; default 0: each window on itself)",
    )
    _range_option(
        kitti,
        "--kitti-speed-scale",
        (1.0, 1.0),
        "replay each window's drive faster or slower by a factor drawn uniformly from [LO, HI], 0.02 <= LO <= "
        "HI <= 4 (e.g. 1 1.6: KITTI's urban drives rarely exceed 15 m/s; 0.02 1: down to a standstill, which they "
        "rarely reach; default 1 1: as driven)",
    )
    _range_option(
        corpus,
        "--vehicle-speed",
        (0.0, 0.0),
        "moving vehicles drive at their own speed, drawn per sequence uniformly from [LO, HI] m/s (each vehicle "
        "within +-30 %%), past a stopped or crawling camera too (e.g. 5 15 with --kitti-speed-scale 0.02 1; default "
        "0 0: each vehicle replays the camera's own path in the oncoming lane, at its speed of another moment)",
    )
    _range_option(
        corpus,
        "--urban-pitch",
        (0.0, 0.0),
        "pitch each urban sequence's cameras down by an angle drawn uniformly from [LO, HI] degrees (planetary "
        "ones are drawn in [0, 25]; default 0 0: level)",
    )


def _range_option(group: Any, flag: str, default: tuple[float, float], help: str) -> None:
    """An option of two numbers LO HI, a range each sequence draws from."""
    group.add_argument(flag, type=float, nargs=2, default=default, metavar=("LO", "HI"), help=help)


# CorpusConfig's per-sequence degradation shares, each a `pvo sim corpus` option of the same name
DEGRADATION_SHARES = {
    "overcast": "under an overcast sky (no shadows)",
    "motion_blur": "with motion blur",
    "exposure_changes": "with exposure changes",
    "moving_vehicles": "with moving vehicles (urban)",
    "texture_poor": "with texture-poor walls (urban)",
    "wrong_calibration": "whose calib.txt is a little wrong",
    "radial_distortion": "seen through a radially distorted lens (k1 drawn in [-0.3, 0.2])",
    "jpeg": "JPEG-compressed",
}


def _drives(text: str) -> tuple[str, ...]:
    return tuple(part.strip() for part in text.split(",") if part.strip())


def run(args: argparse.Namespace) -> int:
    width, height = parse_size(args.size)
    try:
        split = tuple(float(v) for v in args.split.split(","))
    except ValueError:
        raise ValueError(f"--split {args.split!r} must be three numbers, e.g. 0.7,0.15,0.15") from None
    if len(split) != 3:
        raise ValueError(f"--split {args.split!r} must be three numbers, e.g. 0.7,0.15,0.15")
    config = CorpusConfig(
        sequences=args.sequences,
        frames=args.frames,
        width=width,
        height=height,
        presets=tuple(p.strip() for p in args.presets.split(",") if p.strip()),
        seed=args.seed,
        colour=args.colour,
        split=split,  # type: ignore[arg-type]
        supersample=args.supersample,
        kitti_poses=str(args.kitti_poses or ""),
        kitti_train=_drives(args.kitti_train),
        kitti_validation=_drives(args.kitti_validation),
        kitti_test=_drives(args.kitti_test),
        kitti_turning=args.kitti_turning,
        sky=args.sky,
        kitti_level_frames=args.kitti_level_frames,
        kitti_speed_scale=tuple(args.kitti_speed_scale),  # type: ignore[arg-type]
        urban_pitch=tuple(args.urban_pitch),  # type: ignore[arg-type]
        vehicle_speed=tuple(args.vehicle_speed),  # type: ignore[arg-type]
        lens_distortion=tuple(args.lens_distortion),
        calib_focal_scale=args.calib_focal_scale,
        calib_baseline_scale=args.calib_baseline_scale,
        **{name: getattr(args, name) for name in DEGRADATION_SHARES},
    )
    if args.dry_run:
        from pvo_sim.corpus import plan_corpus
        from pvo_sim.render import RENDERER_REVISION

        planned = plan_corpus(config, args.out)
        latest = sorted(name for name, revision in planned.revisions.items() if revision == RENDERER_REVISION)
        print(
            f"{args.out}: {len(planned.revisions)} sequence(s) planned, {len(planned.kept)} kept, "
            f"{len(planned.to_render)} to render ({len(planned.to_render) * config.frames} stereo frames); "
            f"{len(latest)} whose world renderer revision {RENDERER_REVISION} changed"
            + (f": {' '.join(latest)}" if latest else "")
        )
        return 0
    progress = CountProgress("pvo sim corpus (frames)", args.quiet)
    result = render_corpus(config, args.out, jobs=args.jobs, progress=progress)
    progress.close()
    print(
        f"{result.out}: {len(result.rendered)} sequence(s) rendered, {len(result.kept)} kept; "
        f"{result.frames_rendered} stereo frames in {result.seconds:.1f} s ({result.frames_per_second:.2f} stereo frames/s, "
        f"{args.jobs} job(s)); manifest {result.out / 'manifest.yaml'}"
    )
    return 0
