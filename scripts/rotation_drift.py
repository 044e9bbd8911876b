"""Frame-pair rotation errors split into the slow part every pair shares (a drift) and the rest, per estimator:
the thesis's viso2-s VO and its published VO + HydraNet fusion on KITTI, and this project's VO and HydraNet on any
drive with ground truth (`pvo_core.metrics.rotation_drift`).

    python scripts/rotation_drift.py --thesis 00 02 05
    python scripts/rotation_drift.py --drive runs/s67/fusion-sequences/05-clean \
        --vo runs/s69/vo/05-clean.txt --hydranet runs/s69/vo/hydra-05-clean.csv

Bias and spread are millidegrees per pair about the camera's x y z (pitch, yaw, roll); n·bias and √n·spread are
degrees, what each part adds up to over the drive; "turn gain" is the slope of the yaw error on the true yaw. A
second sensor fused with a VO removes the VO's slow part only as far as its own slow part is smaller.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
from pvo_core.readers import read_viso2s_sequence
from pvo_core.readers.viso2s import SEQUENCE_DRIVES
from pvo_core.trajectory import read_kitti_poses
from scipy.io import loadmat
from scipy.spatial.transform import Rotation

from pvo_core import metrics


def pair_rotations(poses: np.ndarray) -> np.ndarray:
    """C_{k-1,k} (N-1, 3, 3) of poses T_w,k (N, 4, 4)."""
    return np.einsum("kji,kjl->kil", poses[:-1, :3, :3], poses[1:, :3, :3])


def row(label: str, drift: metrics.RotationDrift) -> str:
    mdeg = lambda v: " ".join(f"{1000 * np.degrees(x):+6.1f}" for x in v)  # noqa: E731
    deg = lambda v: " ".join(f"{np.degrees(x):+6.2f}" for x in v)  # noqa: E731
    return (
        f"| {label} | {drift.pairs} | {1000 * np.degrees(drift.mean_angle):.1f} | {mdeg(drift.bias)} | "
        f"{mdeg(drift.spread)} | {deg(drift.integrated_bias)} | {deg(drift.integrated_spread)} | {drift.turn_gain:+.3f} |"
    )


def hydranet_rotations(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(frames (N,), C_{k-1,k} (N, 3, 3)) of a `pvo hydranet predict` CSV (its quaternions are C_k,k-1)."""
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    frames = np.array([int(r["frame"]) for r in rows])
    if np.any(np.array([int(r["frame_prev"]) for r in rows]) != frames - 1):
        raise SystemExit(f"{path}: not consecutive frame pairs")
    quaternions = np.array([[float(r[k]) for k in ("qx", "qy", "qz", "qw")] for r in rows])
    return frames, np.transpose(Rotation.from_quat(quaternions).as_matrix(), (0, 2, 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"), help="data directory (default ../shared/data)")
    parser.add_argument("--thesis", nargs="*", default=[], metavar="SEQ", help="KITTI sequences of the thesis's viso2-s runs")
    parser.add_argument("--drive", type=Path, action="append", default=[], help="a sequence directory with poses.txt")
    parser.add_argument("--vo", type=Path, action="append", default=[], help="the VO's poses on each --drive (KITTI format)")
    parser.add_argument("--hydranet", type=Path, action="append", default=[], help="HydraNet's CSV on each --drive")
    args = parser.parse_args()
    header = "| estimator | pairs | mean error (mdeg) | bias x y z (mdeg/pair) | spread x y z | n·bias (deg) "
    print(header + "| √n·spread (deg) | turn gain |")
    print("|---|---|---|---|---|---|---|---|")
    for sequence in args.thesis:
        run = read_viso2s_sequence(args.data, sequence)
        truth = pair_rotations(run.ground_truth)
        print(row(f"{sequence} viso2-s (thesis)", metrics.rotation_drift(truth, pair_rotations(run.vo_poses))))
        for variant in ("SO3_fused", "SO3_fused_single"):
            path = args.data / "kitti" / "viso2s-vo" / "hydranet-fused" / f"{variant}_{SEQUENCE_DRIVES[sequence]}.mat"
            if path.is_file():
                fused = np.moveaxis(loadmat(str(path))["poses_est"], 2, 0)
                print(row(f"{sequence} {variant} (thesis)", metrics.rotation_drift(truth, pair_rotations(fused))))
    for k, drive in enumerate(args.drive):
        truth_poses = read_kitti_poses(drive / "poses.txt")
        truth = pair_rotations(truth_poses)
        if k < len(args.vo):
            vo = read_kitti_poses(args.vo[k])
            print(row(f"{drive.name} VO", metrics.rotation_drift(truth, pair_rotations(vo))))
        if k < len(args.hydranet):
            frames, predicted = hydranet_rotations(args.hydranet[k])
            print(row(f"{drive.name} HydraNet", metrics.rotation_drift(truth[frames - 1], predicted)))


if __name__ == "__main__":
    main()
