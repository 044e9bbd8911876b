"""`pvo eval --gt GT --est EST`: trajectory metrics, PNG plots and the run-result record (metrics.json)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    ev = sub.add_parser("eval", help="evaluate a trajectory against ground truth (table, plots, metrics.json)")
    ev.set_defaults(handler=run)
    ev.add_argument("--gt", type=Path, required=True, help="ground-truth poses (KITTI format)")
    ev.add_argument(
        "--est", type=Path, required=True, help="estimated poses (KITTI format, optionally with a frame-number column)"
    )
    ev.add_argument(
        "--align", choices=["none", "se3", "sim3"], default="none", help="align the estimate first (Umeyama on positions)"
    )
    ev.add_argument("--gt-start", type=int, default=0, help="ground-truth frame of the estimate's first pose (default 0)")
    ev.add_argument("--relative", type=Path, help="per-frame motions and covariances from `pvo vo --relative` -> NEES/ANEES")
    ev.add_argument("--out", "-o", type=Path, help="directory for metrics.json and the PNG plots")


def run(args: argparse.Namespace) -> int:
    from ..evaluation import run_eval

    run_eval(args.gt, args.est, args.align, args.out, args.gt_start, args.relative)
    return 0
