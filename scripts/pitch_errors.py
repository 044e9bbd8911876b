"""Errors binned by the camera's pitch against the synthetic world's flat ground (stop 33's diagnosis: short corpus
windows levelled on themselves never pitch beyond +-3 deg, long drives do).

    # DPC-Net: per Δp-window yaw error of the VO and of the corrected transform (by pitch, by speed, by yaw rate,
    # and its slope on the yaw turned: a focal length written 3 % long shortens every turn by ~3 %),
    # four lens validation drives
    python scripts/pitch_errors.py dpc --model runs/dpc/lensvo runs/dpc/vlong/lens/{10a,10b,04,03}
    # HydraNet: per-pair angular error of `pvo hydranet predict` output, pairs turning < 0.5 deg
    python scripts/pitch_errors.py hydranet runs/dpc/vlong/clean/10a runs/dpc/hydra-10a.csv
    # a corpus's training frames: how often they pitch beyond +-3 deg, how fast they go
    python scripts/pitch_errors.py corpus data/corpus-dpc-lens150lv

A sequence's pitch is taken against the mean up direction of its poses.txt, as `pvo_sim.paths.kitti_path` levels a
drive rendered on its own; a corpus's against the world (its `sim.yaml` replayed through `camera_trajectory`).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray
from pvo_core.trajectory import read_kitti_poses

Array = NDArray[np.float64]
BINS = ((-20, -6), (-6, -3), (-3, 0), (0, 3), (3, 6), (6, 20))
SPEED_BINS = ((0, 5), (5, 10), (10, 15), (15, 40))  # m/s
TURN_BINS = ((-60, -10), (-10, -3), (-3, 3), (3, 10), (10, 60))  # deg/s, the true yaw rate (optical y down: + turns right)
FRAME_RATE_HZ = 10.0  # KITTI's and every corpus's


def sequence_pitch(poses: Array) -> Array:
    """Per camera (N, 4, 4 camera-to-first poses): the optical axis above the plane normal to the mean up, deg."""
    up = -poses[:, :3, 1].mean(axis=0)
    up /= np.linalg.norm(up)
    return np.degrees(np.arcsin(poses[:, :3, 2] @ up))


def dpc(model_dir: Path, drives: list[Path]) -> None:
    from pvo_core.lie import se3_log
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections
    from pvo_tools.dpc import vo_run

    model, card = load_dpc_net(model_dir)
    rows = []
    for root in drives:
        truth = read_kitti_poses(root / "poses.txt")
        vo = vo_run(root)[0].poses
        corrections = predict_corrections(model, card, root, vo)
        pitch = sequence_pitch(truth)
        for a, b, corrected in zip(corrections.first, corrections.last, corrections.transforms, strict=True):
            true = np.linalg.inv(truth[b]) @ truth[a]
            estimate = np.linalg.inv(vo[b]) @ vo[a]
            yaw_vo = se3_log(true @ np.linalg.inv(estimate))[4]  # ROS order x y z rx ry rz: ry is yaw (optical y down)
            yaw_corrected = se3_log(true @ np.linalg.inv(corrected))[4]
            speed = np.linalg.norm(true[:3, 3]) * FRAME_RATE_HZ / (b - a)
            yaw_true = np.degrees(se3_log(true)[4])
            turn = yaw_true * FRAME_RATE_HZ / (b - a)
            rows.append((pitch[a], np.degrees(yaw_vo), np.degrees(yaw_corrected), speed, turn, yaw_true))
    table = np.asarray(rows)
    for column, unit, bins in ((0, "pitch", BINS), (3, "speed", SPEED_BINS), (4, "turn", TURN_BINS)):
        for lo, hi in bins:
            inside = table[(table[:, column] >= lo) & (table[:, column] < hi)]
            if len(inside):
                vo_err, corrected = inside[:, 1], inside[:, 2]
                label = {
                    "pitch": f"pitch [{lo:+d},{hi:+d}) deg",
                    "speed": f"speed [{lo:d},{hi:d}) m/s",
                    "turn": f"yaw rate [{lo:+d},{hi:+d}) deg/s",
                }[unit]
                print(
                    f"{label}, {len(inside):4d} windows: yaw error VO mean {vo_err.mean():+.4f} rms "
                    f"{np.sqrt(np.mean(vo_err**2)):.4f} | corrected mean {corrected.mean():+.4f} rms "
                    f"{np.sqrt(np.mean(corrected**2)):.4f} deg"
                )
    # a focal length written too long shortens every turn by the same fraction: the yaw error's slope on the true yaw
    yaw_true = table[:, 5]
    for name, column in (("VO", 1), ("corrected", 2)):
        slope = float(yaw_true @ table[:, column] / (yaw_true @ yaw_true))
        print(f"yaw error per degree turned, {name} (least squares through 0): {slope:+.5f}")


def hydranet(root: Path, predictions: Path, turning_below_deg: float = 0.5) -> None:
    from scipy.spatial.transform import Rotation

    truth = read_kitti_poses(root / "poses.txt")
    pitch = sequence_pitch(truth)
    rows = []
    for row in np.loadtxt(predictions, delimiter=",", skiprows=1, ndmin=2):
        a, b = int(row[0]), int(row[1])
        qw, qx, qy, qz = row[2:6]
        predicted = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()  # C_k,k-1
        true = (np.linalg.inv(truth[b]) @ truth[a])[:3, :3]
        error = np.degrees(np.linalg.norm(Rotation.from_matrix(predicted @ true.T).as_rotvec()))
        turn = np.degrees(np.linalg.norm(Rotation.from_matrix(true).as_rotvec()))
        rows.append((pitch[a], error, turn))
    table = np.asarray(rows)
    gentle = table[table[:, 2] < turning_below_deg]
    for lo, hi in ((-20, -3), (-3, 3), (3, 20)):
        inside = gentle[(gentle[:, 0] >= lo) & (gentle[:, 0] < hi)]
        if len(inside):
            print(
                f"pitch [{lo:+d},{hi:+d}) deg, {len(inside):4d} pairs turning < {turning_below_deg:g} deg: mean angular "
                f"error {inside[:, 1].mean():.4f} deg (mean true rotation {inside[:, 2].mean():.3f} deg)"
            )


def corpus(root: Path, split: str) -> None:
    from pvo_sim.render import SimConfig, camera_trajectory

    manifest = yaml.safe_load((root / "manifest.yaml").read_text())
    fields = {f.name for f in dataclasses.fields(SimConfig)}
    pitches, speeds = [], []
    for name in manifest["splits"][split]:
        values = yaml.safe_load((root / name / "sim.yaml").read_text())["config"]
        config = SimConfig(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in fields and k != "degradations"}
        )
        cameras = camera_trajectory(config)
        pitches.append(np.degrees(np.arcsin(cameras[:, 2, 2])))  # ENU: z up
        speeds.append(np.linalg.norm(np.diff(cameras[:, :3, 3], axis=0), axis=1) * FRAME_RATE_HZ)
    p = np.concatenate(pitches)
    v = np.concatenate(speeds)
    print(
        f"{root} ({split}, {len(pitches)} sequences, {len(p)} frames): pitch p1 {np.percentile(p, 1):+.2f}, median "
        f"{np.median(p):+.2f}, p99 {np.percentile(p, 99):+.2f} deg; beyond -3 deg {np.mean(p < -3):.3f}, beyond +3 deg "
        f"{np.mean(p > 3):.3f}, beyond +-3 deg {np.mean(np.abs(p) > 3):.3f}; speed median {np.median(v):.1f}, p90 "
        f"{np.percentile(v, 90):.1f} m/s, above 10 m/s {np.mean(v > 10):.3f}, above 15 m/s {np.mean(v > 15):.3f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    kinds = parser.add_subparsers(dest="kind", required=True)
    a = kinds.add_parser("dpc", help="DPC-Net's per-window yaw error, VO vs corrected, by pitch and by speed")
    a.add_argument("--model", type=Path, required=True)
    a.add_argument("drives", type=Path, nargs="+")
    b = kinds.add_parser("hydranet", help="HydraNet's per-pair angular error from its predictions CSV")
    b.add_argument("sequence", type=Path)
    b.add_argument("predictions", type=Path)
    c = kinds.add_parser("corpus", help="how often a corpus's frames pitch beyond +-3 deg")
    c.add_argument("corpus", type=Path)
    c.add_argument("--split", default="train", choices=("train", "validation", "test"))
    args = parser.parse_args()
    if args.kind == "dpc":
        dpc(args.model, args.drives)
    elif args.kind == "hydranet":
        hydranet(args.sequence, args.predictions)
    else:
        corpus(args.corpus, args.split)


if __name__ == "__main__":
    main()
