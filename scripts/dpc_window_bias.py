"""DPC-Net's per-window mean error on long drives, the VO's against the corrected transforms' (stop 36's diagnosis of
Table 6.1: a lateral bias the corrections carry on the test drives turns the fused trajectory when yaw is left to the
VO).

    python scripts/dpc_window_bias.py runs/dpc/calibvo-lv3m runs/dpc/vlong/calib/{03,04,10a,10b} runs/dpc/sequences/calib/*

Per drive: the windows (the card's Δp), and the mean left error log(T_gt T^-1) of the VO and of the corrected transform
(the card's mean removal applied when it chose it) in x (lateral, m), z (forward, m) and yaw (deg, about the optical y);
the yaw the drive turns in all (deg; + right) and the lateral error's least-squares slope on each window's true yaw
(m per deg turned, through 0), per drive and over all drives: a lateral error that follows the turns biases a drive
that mostly turns one way.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.lie import se3_log
from pvo_core.trajectory import read_kitti_poses


def main() -> None:
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections
    from pvo_tools.dpc import vo_run

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("drives", type=Path, nargs="+")
    args = parser.parse_args()
    model, card = load_dpc_net(args.model)
    pooled: dict[str, list[np.ndarray]] = {"yaw": [], "vo": [], "corrected": []}

    def slope(yaw: np.ndarray, lateral: np.ndarray) -> float:
        return float(yaw @ lateral / max(float(yaw @ yaw), 1e-12))

    for root in args.drives:
        truth = read_kitti_poses(root / "poses.txt")
        vo = vo_run(root)[0].poses
        corrections = predict_corrections(model, card, root, vo)
        errors_vo, errors_corrected, yaws = [], [], []
        for a, b, corrected in zip(corrections.first, corrections.last, corrections.transforms, strict=True):
            true = np.linalg.inv(truth[b]) @ truth[a]
            yaws.append(-np.degrees(se3_log(true)[4]))  # T_b,a: the camera turned by minus its yaw about optical y
            errors_vo.append(se3_log(true @ np.linalg.inv(np.linalg.inv(vo[b]) @ vo[a])))
            errors_corrected.append(se3_log(true @ np.linalg.inv(corrected)))

        def means(errors: list[np.ndarray]) -> str:
            e = np.asarray(errors)
            return f"x {e[:, 0].mean():+.4f} m, z {e[:, 2].mean():+.4f} m, yaw {np.degrees(e[:, 4].mean()):+.4f} deg"

        yaw = np.asarray(yaws)
        vo_x, corrected_x = np.asarray(errors_vo)[:, 0], np.asarray(errors_corrected)[:, 0]
        for key, values in (("yaw", yaw), ("vo", vo_x), ("corrected", corrected_x)):
            pooled[key].append(values)
        print(
            f"{root}: {len(errors_vo)} windows, turns {yaw.sum():+.0f} deg; mean error VO {means(errors_vo)} | corrected "
            f"{means(errors_corrected)}; lateral error per deg turned VO {slope(yaw, vo_x):+.5f}, corrected "
            f"{slope(yaw, corrected_x):+.5f} m"
        )
    yaw, vo_x, corrected_x = (np.concatenate(pooled[k]) for k in ("yaw", "vo", "corrected"))
    print(
        f"all {len(yaw)} windows: lateral error per deg turned VO {slope(yaw, vo_x):+.5f}, corrected "
        f"{slope(yaw, corrected_x):+.5f} m; "
        f"on straight windows (|yaw| < 0.5 deg) mean VO {vo_x[abs(yaw) < 0.5].mean():+.4f}, corrected "
        f"{corrected_x[abs(yaw) < 0.5].mean():+.4f} m"
    )


if __name__ == "__main__":
    main()
