"""How far HydraNet (and the VO) under- or over-read turns: the least-squares slope of each frame pair's rotation error
on its true rotation, per axis (x, y = yaw about the optical y axis, z), through 0 (−0.1: turns read 10 % short).

    pvo hydranet predict runs/dpc/vlong/clean/10a --model hydranet -o /tmp/10a.csv
    python scripts/hydranet_turn_slope.py pair runs/dpc/vlong/clean/10a /tmp/10a.csv      # HydraNet and this VO on one drive
    python scripts/hydranet_turn_slope.py corpus --model hydranet --corpus data/corpus-hydra-lv --corpus data/corpus-hydra-lvb
    python scripts/hydranet_turn_slope.py kitti ../shared/data/kitti/poses 00 02 08 09 03 04 10   # degrees turned each way

`corpus`: the gain per axis that best scales the model's rotation vectors onto the truth over the urban validation pairs,
and the yaw gain by how much the pair turns. `kitti`: each drive's net turn and the degrees it turns either way.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.lie import so3_log
from pvo_core.readers.sidecars import read_rotation_predictions_csv
from pvo_core.trajectory import read_kitti_poses
from scipy.spatial.transform import Rotation


def slopes(true: np.ndarray, error: np.ndarray) -> np.ndarray:
    return np.array([(true[:, i] @ error[:, i]) / max(float(true[:, i] @ true[:, i]), 1e-18) for i in range(3)])


def pair(args: argparse.Namespace) -> None:
    from pvo_tools.dpc import vo_run

    rows = read_rotation_predictions_csv(args.predictions)
    truth = read_kitti_poses(args.sequence / "poses.txt")
    if rows[:, :2].max() >= len(truth):
        raise ValueError(f"{args.predictions} names frame {int(rows[:, :2].max())}; {args.sequence} has {len(truth)} poses")
    vo = vo_run(args.sequence)[0].poses
    true, hydranet, odometry = [], [], []
    for row in rows:
        a, b = int(row[0]), int(row[1])
        rotation = (np.linalg.inv(truth[b]) @ truth[a])[:3, :3]
        predicted = Rotation.from_quat(row[[3, 4, 5, 2]]).as_matrix()
        measured = (np.linalg.inv(vo[b]) @ vo[a])[:3, :3]
        true.append(so3_log(rotation))
        hydranet.append(so3_log(predicted @ rotation.T))
        odometry.append(so3_log(measured @ rotation.T))
    true_array = np.asarray(true)
    for name, errors in (("HydraNet", np.asarray(hydranet)), ("VO", np.asarray(odometry))):
        rms = np.degrees(np.sqrt((errors**2).mean(axis=0)))
        print(
            f"{name:8s} slope (x y z) {np.round(slopes(true_array, errors), 4)}, rms error {np.round(rms, 4)} deg, "
            f"summed error {np.round(np.degrees(errors.sum(axis=0)), 2)} deg over {len(errors)} pairs"
        )


def corpus(args: argparse.Namespace) -> None:
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.hydranet.estimator import resolve_model
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence

    model, card = load_hydranet(resolve_model(args.model))
    true, predicted = [], []
    for path in args.corpus:
        for item in read_corpus_manifest(path).split("validation"):
            if item.preset != "urban":
                continue
            predictions = predict_sequence(model, card, item.root)
            truth = read_kitti_poses(item.root / "poses.txt")
            for q, a, b in zip(predictions.quaternions, predictions.earlier, predictions.frames, strict=True):
                true.append(so3_log((np.linalg.inv(truth[b]) @ truth[a])[:3, :3]))
                predicted.append(Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_rotvec())
    y, p = np.asarray(true), np.asarray(predicted)
    print(f"{len(y)} urban validation pairs: gain per axis {np.round((y * p).sum(0) / (p * p).sum(0), 4)}")
    turn = np.degrees(np.abs(y[:, 1]))
    for low, high in ((0, 0.5), (0.5, 1), (1, 2), (2, 180)):
        keep = (turn >= low) & (turn < high)
        if keep.any():
            gain = (y[keep, 1] @ p[keep, 1]) / (p[keep, 1] @ p[keep, 1])
            print(f"  |yaw| {low}-{high} deg: {keep.sum()} pairs, yaw gain {gain:.3f}")


def kitti(args: argparse.Namespace) -> None:
    for drive in args.drives:
        poses = read_kitti_poses(args.poses / f"{drive}.txt")
        yaw = np.array([so3_log((np.linalg.inv(poses[i + 1]) @ poses[i])[:3, :3])[1] for i in range(len(poses) - 1)])
        print(
            f"{drive}: net {np.degrees(yaw.sum()):+.0f} deg; {np.degrees(yaw[yaw > 0].sum()):.0f} deg one way, "
            f"{np.degrees(-yaw[yaw < 0].sum()):.0f} deg the other"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    one = sub.add_parser("pair", help="one sequence and its `pvo hydranet predict` CSV")
    one.add_argument("sequence", type=Path)
    one.add_argument("predictions", type=Path)
    one.set_defaults(run=pair)
    many = sub.add_parser("corpus", help="a model over corpora's urban validation pairs")
    many.add_argument("--model", default="hydranet")
    many.add_argument("--corpus", type=Path, action="append", required=True)
    many.set_defaults(run=corpus)
    drives = sub.add_parser("kitti", help="KITTI pose files: degrees turned each way")
    drives.add_argument("poses", type=Path)
    drives.add_argument("drives", nargs="+")
    drives.set_defaults(run=kitti)
    args = parser.parse_args()
    for path in (getattr(args, "predictions", None), getattr(args, "sequence", None)):
        if path is not None and not path.exists():
            raise SystemExit(f"{path}: no such file or directory")
    if args.what == "pair" and not (args.sequence / "poses.txt").is_file():
        raise SystemExit(f"{args.sequence}: no poses.txt (the truth the errors are measured against)")
    try:
        args.run(args)
    except (OSError, ValueError) as error:  # a bad CSV, a missing pose file, a corpus without a manifest
        raise SystemExit(f"hydranet_turn_slope.py {args.what}: {error}") from None


if __name__ == "__main__":
    main()
