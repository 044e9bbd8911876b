"""`pvo sim mirror SOURCE OUT`: a corpus or one stereo sequence mirrored left-right (:mod:`pvo_sim.mirror`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..progress import CountProgress


def register(sub: Any) -> None:
    mirror = sub.add_parser(
        "sim-mirror",
        prog="pvo sim mirror",
        description="Mirror a corpus (a folder with manifest.yaml) or one KITTI-layout stereo sequence left-right: the "
        "images flipped with left and right swapped, the poses of the mirrored rig's left camera, the sun's x negated. "
        "Every right turn becomes a left turn; a corpus keeps its splits. Re-running a corpus resumes.",
    )
    mirror.set_defaults(handler=run)
    mirror.add_argument("source", type=Path, help="corpus directory or sequence directory")
    mirror.add_argument("out", type=Path, help="output directory (a new corpus, or the mirrored sequence)")
    mirror.add_argument("--overwrite", action="store_true", help="replace an existing mirrored sequence")
    mirror.add_argument("--quiet", "-q", action="store_true", help="no progress output")


def run(args: argparse.Namespace) -> int:
    from pvo_sim.mirror import mirror_corpus, mirror_sequence

    if not args.source.is_dir():
        raise ValueError(f"{args.source}: no such corpus or sequence directory")
    if (args.source / "manifest.yaml").is_file():
        progress = CountProgress("pvo sim mirror (sequences)", args.quiet)
        done = mirror_corpus(args.source, args.out, progress)
        progress.close()
        print(f"{args.out}: {len(done)} sequence(s) mirrored now; manifest {args.out / 'manifest.yaml'}")
        return 0
    out = mirror_sequence(args.source, args.out, overwrite=args.overwrite)
    frames = len((out / "poses.txt").read_text().splitlines())
    print(f"{out}: {frames} stereo frames mirrored left-right")
    return 0
