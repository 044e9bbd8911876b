"""Per drive, the mean rotation error per frame pair (millidegrees, about the camera's x y z) of a HydraNet model and
of the VO on the long validation drives: what of their errors a drive's pairs share.

    python scripts/hydranet_drive_offsets.py src/pvo_pseudosensors/models/hydranet runs/dpc/vlong

A mean that flips sign with the drive's mirror image follows the turns (a turn read short); one that does not is an
offset of the sensor. The VO's runs and the flow come from the caches of `scripts/hydranet_validation_drives.py`
(made there if missing).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydranet_validation_drives import vo_of
from pvo_core.lie import so3_log
from pvo_core.readers import KittiSequence
from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError
from scipy.spatial.transform import Rotation


def mean_errors(predicted: np.ndarray, odometry: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean rotation-vector error (deg) of HydraNet's C_later,earlier (N, 3, 3) and the VO's (N, 3, 3) against truth's."""
    hydranet = [so3_log(p @ t.T) for p, t in zip(predicted, truth, strict=True)]
    vo = [so3_log(o @ t.T) for o, t in zip(odometry, truth, strict=True)]
    return np.degrees(np.mean(hydranet, axis=0)), np.degrees(np.mean(vo, axis=0))


def load_model(path: Path) -> tuple[Any, Any]:
    """The HydraNet model and card at ``path``; a missing or broken model is one line."""
    try:
        return load_hydranet(path)
    except ModelFileError as error:
        raise SystemExit(str(error)) from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("drives", type=Path, help="OUT of `pvo dpc-net drives`")
    parser.add_argument("--cache", type=Path, default=Path("runs/hydranet-validation-drives/cache"), help="flow cache")
    parser.add_argument("--vo-cache", type=Path, default=Path("runs/hydranet-validation-drives/vo"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, card = load_model(args.model)
    drives = sorted(p for p in args.drives.glob("*/*") if (p / "poses.txt").is_file())
    if not drives:
        raise SystemExit(f"{args.drives}: no drive (render them with `pvo dpc-net drives {args.drives} --split validation`)")
    rows = []
    for folder in drives:
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        vo_poses, _ = vo_of(folder, sequence, args.vo_cache)
        truth = sequence.poses
        predictions = predict_sequence(model, card, folder, cache_dir=args.cache)
        pairs = list(zip(predictions.earlier, predictions.frames, strict=True))
        true = np.array([(np.linalg.inv(truth[b]) @ truth[a])[:3, :3] for a, b in pairs])
        odometry = np.array([(np.linalg.inv(vo_poses[b]) @ vo_poses[a])[:3, :3] for a, b in pairs])
        wxyz = np.asarray(predictions.quaternions)
        predicted = Rotation.from_quat(wxyz[:, [1, 2, 3, 0]]).as_matrix()
        hydranet, vo = mean_errors(predicted, odometry, true)
        rows.append((hydranet, vo))
        name = f"{folder.parent.name}/{folder.name}"
        print(f"{name:12s} HydraNet {np.round(1000 * hydranet, 1)}  VO {np.round(1000 * vo, 1)} mdeg per pair", flush=True)
    means = 1000 * np.array(rows)
    print(f"over {len(rows)} drives, mean: HydraNet {np.round(means[:, 0].mean(0), 1)}, VO {np.round(means[:, 1].mean(0), 1)}")
    print(f"over {len(rows)} drives, std:  HydraNet {np.round(means[:, 0].std(0), 1)}, VO {np.round(means[:, 1].std(0), 1)}")


if __name__ == "__main__":
    main()
