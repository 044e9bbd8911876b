"""The stereo VO with other settings against its defaults, on rendered drives and on real KITTI stereo KLT tracks.

    # the README's noise-model table: the sixteen validation drives of each rig (`pvo dpc-net drives runs/dpc/vlong`)
    python scripts/vo_settings_on_drives.py -p solver.noise_model=stereo --drives runs/dpc/vlong --rigs clean,calib,lens
    # and on the real raw-derived KLT tracks (frames 0-499 of three KITTI raw drives: RANSAC and solver on the tracks)
    python scripts/vo_settings_on_drives.py -p solver.noise_model=stereo --klt-tracks ../shared/data/kitti/raw-derived

Per drive: m-ATE (translation m, rotation deg) and thesis segment errors of both VOs against poses.txt, and the
heading error at the end (deg, about the camera's y axis); then the mean relative change per rig. Drives run in
``--jobs`` processes (the VO is deterministic: the same settings give the same figures).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pvo_core.lie import so3_log
from pvo_core.metrics import mean_trajectory_errors, thesis_segment_errors
from pvo_core.readers import KittiSequence, read_klt_tracks
from pvo_frontend.offline import run_sequence
from pvo_frontend.vo import from_flat
from pvo_frontend.vo.config import default_feature_covariance
from pvo_frontend.vo.pipeline import estimate_motion

NAMES = ("m-ATE t", "m-ATE r", "seg t", "seg r")


def figures(truth: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """m-ATE (m, deg), segment errors (%, deg/m) and the end heading error (deg) of camera-to-world ``poses``."""
    trajectory, segments = mean_trajectory_errors(truth, poses), thesis_segment_errors(truth, poses)
    heading = np.degrees(so3_log(poses[-1, :3, :3].T @ truth[-1, :3, :3])[1])
    return np.array(
        [
            trajectory.mean_translation,
            np.degrees(trajectory.mean_rotation),
            100 * np.nanmean(segments.translation),
            np.degrees(np.nanmean(segments.rotation)),
            heading,
        ]
    )


def drive(folder: Path, overrides: dict[str, Any]) -> tuple[str, np.ndarray, np.ndarray]:
    sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
    truth = sequence.poses
    runs = [run_sequence(sequence, from_flat(values)) for values in ({}, overrides)]
    return f"{folder.parent.name}/{folder.name}", *(figures(truth, truth[0] @ run.poses) for run in runs)


def tracks(path: Path, overrides: dict[str, Any]) -> tuple[str, np.ndarray, np.ndarray]:
    """The VO's RANSAC and solver on the drive's given stereo tracks (no images), chained."""
    data = read_klt_tracks(path)
    out = []
    for values in ({}, overrides):
        config = from_flat(values)
        covariance = default_feature_covariance(config.solver)
        rng = np.random.default_rng(config.ransac.seed)
        poses, last = [data.poses[0]], np.eye(4)
        for k in range(1, len(data)):
            ref, cur, _ = data.pair(k)
            estimate = estimate_motion(
                data.camera, ref, cur, np.broadcast_to(covariance, (len(ref), 3, 3)), config, rng, prediction=last
            )
            last = estimate.solve.transform if estimate.solve is not None else last  # T_cur,ref; constant velocity if lost
            poses.append(poses[-1] @ np.linalg.inv(last))
        out.append(figures(data.poses, np.array(poses)))
    return f"klt/{path.stem.removesuffix('_sync_KLT')}", *out


def run_job(job: tuple[str, Path], overrides: dict[str, Any]) -> tuple[str, np.ndarray, np.ndarray]:
    kind, path = job
    return drive(path, overrides) if kind == "drive" else tracks(path, overrides)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--param", "-p", action="append", default=[], metavar="NAME=VALUE", help="the VO setting to compare")
    parser.add_argument("--drives", type=Path, help="OUT of `pvo dpc-net drives` (OUT/<rig>/<drive>)")
    parser.add_argument("--rigs", default="clean", help="rigs under --drives, comma-separated (default clean)")
    parser.add_argument("--klt-tracks", type=Path, help="a folder of raw-derived *_KLT.mat tracks")
    parser.add_argument("--jobs", "-j", type=int, default=2)
    args = parser.parse_args()
    overrides = {}
    for item in args.param:
        name, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"-p {item!r}: expected NAME=VALUE")
        overrides[name] = yaml.safe_load(text)
    from_flat(overrides)  # a bad setting fails here, in one line, before any run
    jobs: list[tuple[str, Path]] = []
    for rig in args.rigs.split(",") if args.drives else []:
        folders = sorted(p for p in (args.drives / rig).glob("*") if (p / "poses.txt").is_file())
        if not folders:
            raise SystemExit(f"{args.drives / rig}: no drive")
        jobs += [("drive", folder) for folder in folders]
    jobs += [("tracks", path) for path in sorted(args.klt_tracks.glob("*_KLT.mat"))] if args.klt_tracks else []
    if not jobs:
        raise SystemExit("nothing to run: give --drives and/or --klt-tracks")
    print(f"default VO against {overrides}: m-ATE t (m) r (deg), segments t (%) r (deg/m), end heading error (deg)")
    groups: dict[str, list[np.ndarray]] = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        for name, default, other in pool.map(partial(run_job, overrides=overrides), jobs):
            groups.setdefault(name.split("/")[0], []).append(other[:4] / default[:4] - 1.0)
            print(f"{name:16s} {' '.join(f'{v:8.4g}' for v in default)} | {' '.join(f'{v:8.4g}' for v in other)}", flush=True)
    for group, changes in groups.items():
        mean = 100 * np.mean(changes, axis=0)
        print(f"{group} ({len(changes)}): mean change " + ", ".join(f"{n} {v:+.1f} %" for n, v in zip(NAMES, mean, strict=True)))


if __name__ == "__main__":
    main()
