"""Metrics against independent results shipped in ../shared/data (exact to the printed digits)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io
from pvo_core.lie import se3_exp
from pvo_core.trajectory import read_kitti_poses, read_kitti_poses_indexed

from pvo_core import metrics


def viso2s(pvo_data: Path, drive: str) -> tuple[np.ndarray, np.ndarray]:
    mat = scipy.io.loadmat(pvo_data / f"kitti/viso2s-vo/baseline/{drive}.mat")
    return np.moveaxis(mat["poses_gt"], 2, 0), np.moveaxis(mat["poses_est"], 2, 0)


@pytest.mark.parametrize(
    ("sequence", "t_err", "r_err"),
    [("09", 2.884112511407129, 0.24905618674615418), ("10", 3.297839536933298, 0.3045899519453301)],
)
def test_kitti_odom_eval_examples_7dof(pvo_data: Path, sequence: str, t_err: float, r_err: float) -> None:
    gt = read_kitti_poses(pvo_data / f"kitti/poses/{sequence}.txt")
    frames, est = read_kitti_poses_indexed(
        pvo_data / f"kitti/reference-results/kitti-odom-eval-examples/example_0/{sequence}.txt"
    )
    t, r = metrics.devkit_score(metrics.kitti_odom_eval(gt, frames, est, "sim3"))
    assert t == pytest.approx(t_err, abs=1e-12)
    assert 100 * r == pytest.approx(r_err, abs=1e-12)


@pytest.mark.parametrize("sequence", ["00", "05", "07"])
@pytest.mark.parametrize("method", ["IMLS", "orb2"])
def test_devkit_rows_match_reference_errors(pvo_data: Path, sequence: str, method: str) -> None:
    root = pvo_data / "kitti/reference-results" / method
    gt = read_kitti_poses(pvo_data / f"kitti/poses/{sequence}.txt")
    est = read_kitti_poses(root / f"{sequence}.txt")
    reference = np.loadtxt(root / f"errors/{sequence}.txt")
    rows = metrics.devkit_segment_errors(gt, est).as_rows()
    assert rows.shape == (reference.shape[0], 5)
    assert np.array_equal(rows[:, [0, 3]], reference[:, [0, 3]])
    assert np.allclose(rows[:, [1, 2, 4]], reference[:, [1, 2, 4]], rtol=1e-9, atol=1e-13)


def test_viso2s_sequence00_reference_numbers(pvo_data: Path) -> None:
    gt, est = viso2s(pvo_data, "2011_10_03_drive_0027")
    traj = metrics.mean_trajectory_errors(gt, est)
    assert round(traj.mean_translation, 3) == 27.914
    assert round(np.degrees(traj.mean_rotation), 4) == 6.2539
    thesis = metrics.thesis_segment_errors(gt, est)
    assert round(thesis.translation_percent, 4) == 1.9634
    assert round(thesis.rotation_deg_per_m, 7) == 0.0080716
    t, r = metrics.devkit_score(metrics.devkit_segment_errors(gt, est))
    assert round(t, 4) == 1.9454
    assert round(r, 7) == 0.0081763


def test_viso2s_sequence05_reference_numbers(pvo_data: Path) -> None:
    gt, est = viso2s(pvo_data, "2011_09_30_drive_0018")
    traj = metrics.mean_trajectory_errors(gt, est)
    assert round(traj.mean_translation, 3) == 23.718
    assert round(np.degrees(traj.mean_rotation), 4) == 8.1047
    thesis = metrics.thesis_segment_errors(gt, est)
    assert round(thesis.translation_percent, 4) == 1.7909
    t, _ = metrics.devkit_score(metrics.devkit_segment_errors(gt, est))
    assert round(t, 4) == 1.7873


def test_alignment_recovers_a_similarity() -> None:
    rng = np.random.default_rng(0)
    gt = np.array([se3_exp(np.concatenate([rng.normal(size=3) * 10, rng.normal(size=3)])) for _ in range(30)])
    transform = se3_exp(np.array([3.0, -1.0, 2.0, 0.1, -0.3, 0.2]))
    est = np.linalg.inv(transform) @ gt
    est[:, :3, 3] /= 1.7
    aligned = metrics.align_trajectory(gt, est, "sim3")
    assert np.abs(metrics.absolute_trajectory_error(gt, aligned)).max() < 1e-9
    rigid = metrics.align_trajectory(gt, np.linalg.inv(transform) @ gt, "se3")
    assert np.abs(metrics.absolute_trajectory_error(gt, rigid)).max() < 1e-9
    with pytest.raises(ValueError, match="unknown alignment"):
        metrics.align_trajectory(gt, est, "sim2")


def test_rpe_and_nees_on_known_errors() -> None:
    steps = [se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))] * 10
    gt = np.array([np.linalg.matrix_power(steps[0], k) for k in range(11)])
    est = gt.copy()
    est[5:, 0, 3] += 0.1  # one 10 cm jump between frames 4 and 5
    t, r = metrics.relative_pose_errors(gt, est)
    assert np.allclose(t, [0, 0, 0, 0, 0.1, 0, 0, 0, 0, 0])
    assert np.allclose(r, 0)
    errors = np.array([[1.0, 0.0], [0.0, 2.0]])
    covs = np.array([np.eye(2), 4 * np.eye(2)])
    assert np.allclose(metrics.nees(errors, covs), [1.0, 1.0])
    assert metrics.anees(errors, covs) == pytest.approx(0.5)


def test_bad_trajectories_are_refused() -> None:
    gt = np.tile(np.eye(4), (5, 1, 1))
    with pytest.raises(ValueError, match="equal length"):
        metrics.devkit_segment_errors(gt, gt[:4])
    bad = gt.copy()
    bad[2, 0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        metrics.mean_trajectory_errors(gt, bad)


def test_shared_error_covariance_recovers_the_common_noise() -> None:
    rng = np.random.default_rng(3)
    common_cov = np.diag([4.0, 1.0, 0.25])
    common = rng.multivariate_normal(np.zeros(3), common_cov, 20000)
    a = common + rng.normal(size=(20000, 3)) * 2.0
    b = common + rng.normal(size=(20000, 3)) * 3.0
    assert np.allclose(metrics.shared_error_covariance(a, b), common_cov, atol=0.15)
