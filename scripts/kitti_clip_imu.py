"""A KITTI stereo clip with the drive's IMU beside it: a directory that links the clip's images, calibration and
poses and adds ``imu.csv`` (``t,wx,wy,wz,fx,fy,fz``, camera frame, t = frame / rate) made from the raw-derived
drive's angular rate and specific force, so `pvo vo` / `pvo probe eval` run PROBE with its IMU predictors on it.

    python scripts/kitti_clip_imu.py ../shared/data/kitti/raw-derived/2011_09_30_drive_0020_sync_KLT.mat \\
        ../shared/data/kitti/sequences/06 runs/kitti06-imu

Odometry frame k is raw frame k for 06 and 07 (``../shared/data/SOURCES.md``); ``--first`` shifts that.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.readers import read_klt_tracks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tracks", type=Path, help="raw-derived *_KLT.mat of the clip's drive")
    parser.add_argument("clip", type=Path, help="KITTI-layout clip directory (image_0, image_1, calibration, poses)")
    parser.add_argument("out", type=Path, help="directory to write (links to the clip's files and imu.csv)")
    parser.add_argument("--first", type=int, default=0, help="raw frame of the clip's frame 0 (default 0)")
    parser.add_argument("--rate", type=float, default=10.0, help="frame rate (Hz, default 10)")
    args = parser.parse_args()

    from scipy.io import loadmat

    try:
        tracks = read_klt_tracks(args.tracks)
    except ValueError as exc:  # DataFormatError: a missing or unreadable file, one line naming it
        raise SystemExit(f"kitti_clip_imu: {exc}") from None
    if not (args.clip / "image_0").is_dir():
        raise SystemExit(f"{args.clip}: no image_0 directory (not a KITTI-layout clip)")
    frames = len(list((args.clip / "image_0").glob("*.png")))
    if frames == 0:
        raise SystemExit(f"{args.clip}/image_0: no images")
    if args.first + frames > len(tracks):
        raise SystemExit(f"{args.tracks.name}: {len(tracks)} frames, the clip needs {args.first + frames}")
    c_c_v = np.asarray(loadmat(str(args.tracks))["C_c_v"], dtype=float)  # vehicle -> camera
    rows = slice(args.first, args.first + frames)
    angular = tracks.angular_rate[rows] @ c_c_v.T
    force = tracks.specific_force[rows] @ c_c_v.T
    args.out.mkdir(parents=True, exist_ok=True)
    for item in args.clip.iterdir():
        link = args.out / item.name
        if not link.exists():
            link.symlink_to(item.resolve())
    t = np.arange(frames) / args.rate
    table = np.column_stack([t, angular, force])
    lines = ["t,wx,wy,wz,fx,fy,fz", *(",".join(f"{v:.9g}" for v in row) for row in table)]
    (args.out / "imu.csv").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}: {frames} frames, imu.csv from {args.tracks.name} frames {args.first}-{args.first + frames - 1}")


if __name__ == "__main__":
    main()
