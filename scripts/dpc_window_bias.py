"""DPC-Net's per-window mean error on long drives, the VO's against the corrected transforms' (stop 36's diagnosis of
Table 6.1: a lateral bias the corrections carry on the test drives turns the fused trajectory when yaw is left to the
VO).

    python scripts/dpc_window_bias.py runs/dpc/calibvo-lv3m runs/dpc/vlong/calib/{03,04,10a,10b} runs/dpc/sequences/calib/*

Per drive: the windows (the card's Δp), and the mean left error log(T_gt T^-1) of the VO and of the corrected transform
(the card's mean removal applied when it chose it) in x (lateral, m), z (forward, m) and yaw (deg, about the optical y).
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
    for root in args.drives:
        truth = read_kitti_poses(root / "poses.txt")
        vo = vo_run(root)[0].poses
        corrections = predict_corrections(model, card, root, vo)
        errors_vo, errors_corrected = [], []
        for a, b, corrected in zip(corrections.first, corrections.last, corrections.transforms, strict=True):
            true = np.linalg.inv(truth[b]) @ truth[a]
            errors_vo.append(se3_log(true @ np.linalg.inv(np.linalg.inv(vo[b]) @ vo[a])))
            errors_corrected.append(se3_log(true @ np.linalg.inv(corrected)))

        def means(errors: list[np.ndarray]) -> str:
            e = np.asarray(errors)
            return f"x {e[:, 0].mean():+.4f} m, z {e[:, 2].mean():+.4f} m, yaw {np.degrees(e[:, 4].mean()):+.4f} deg"

        print(f"{root}: {len(errors_vo)} windows; mean error VO {means(errors_vo)} | corrected {means(errors_corrected)}")


if __name__ == "__main__":
    main()
