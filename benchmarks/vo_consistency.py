"""Covariance consistency of the stereo VO on the real KITTI 06 clip, with the ground truth's own noise.

Per-frame errors against KITTI ground truth contain the ground truth's error. The thesis's viso2-s run
on the same drive is an independent estimator; the component its errors share with ours is the ground
truth's, so E[e_ours e_viso2s^T] estimates the ground-truth noise covariance Sigma_gt. The script prints
ANEES (per dof) with Sigma_vo alone and with Sigma_vo + Sigma_gt, for the default and calibrated R.

    source scripts/env.sh && python benchmarks/vo_consistency.py
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from pvo_core.readers import KittiSequence, read_viso2s_sequence
from pvo_frontend.vo import StereoVO, from_flat

from pvo_core import metrics

DATA = Path(os.environ.get("PVO_DATA_DIR", Path(__file__).resolve().parents[1].parent / "shared" / "data"))


def main() -> None:
    root = DATA / "kitti/sequences/06"
    sequence = KittiSequence(root, rate_hz=10.0, poses_file=root / "poses_frames000-050.txt")
    n = len(sequence)
    viso = read_viso2s_sequence(DATA, "06", project_rotations=False)
    viso_gt, viso_est = viso.ground_truth[:n], viso.vo_poses[:n]
    viso_errors = metrics.relative_motion_errors(viso_gt, np.linalg.inv(viso_est[1:]) @ viso_est[:-1])
    images = [sequence.load_pair(i) for i in range(n)]
    print(f"{'pixel sigma (u, v, d)':<24} {'ANEES':>7} {'+GT noise':>10} {'median':>7}  rotation-error correlation with viso2-s")
    for sigma in ([1.0, 1.0, 2.0], [2.0, 2.0, 4.0]):
        vo = StereoVO(sequence.camera(), from_flat({"solver.pixel_sigma": sigma}))
        results = [vo.process(*images[i], float(sequence.stamps[i])) for i in range(n)]
        transforms = np.array([r.transform for r in results[1:]])
        covariances = np.array([r.covariance for r in results[1:]])
        errors = metrics.relative_motion_errors(sequence.poses, transforms)
        gt_noise = metrics.shared_error_covariance(errors, viso_errors)
        nees = metrics.nees(errors, covariances) / 6
        corr = [np.corrcoef(errors[:, k], viso_errors[:, k])[0, 1] for k in range(3, 6)]
        print(
            f"{sigma!s:<24} {nees.mean():7.2f} {metrics.anees(errors, covariances + gt_noise):10.2f} {np.median(nees):7.2f}  "
            + " ".join(f"{c:.2f}" for c in corr)
        )
        sd = np.sqrt(np.diag(gt_noise))
        print(f"{'':<24} ground-truth noise per frame: {1e3 * sd[:3].round(4)} mm, {(np.degrees(sd[3:]) * 1e3).round(1)} mdeg")


if __name__ == "__main__":
    main()
