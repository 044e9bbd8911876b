"""Metrics against independent results shipped in ../shared/data (exact to the printed digits)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.lie import se3_exp
from pvo_core.readers import read_viso2s
from pvo_core.trajectory import read_kitti_poses, read_kitti_poses_indexed

from pvo_core import metrics


def viso2s(pvo_data: Path, drive: str) -> tuple[np.ndarray, np.ndarray]:
    run = read_viso2s(pvo_data / f"kitti/viso2s-vo/baseline/{drive}.mat", project_rotations=False)
    return run.ground_truth, run.vo_poses


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


def test_armse_is_the_mean_of_the_cumulative_rmse() -> None:
    errors = np.array([1.0, 2.0, 3.0, 4.0])
    expected_curve = [1.0, np.sqrt(2.5), np.sqrt(14 / 3), np.sqrt(7.5)]
    np.testing.assert_allclose(metrics.crmse(errors), expected_curve)
    gt = np.repeat(np.eye(4)[None], 4, axis=0)
    est = gt.copy()
    est[:, 0, 3] = errors  # east error only
    est[:, 2, 3] = 1.0  # and 1 m up, invisible in the EN plane
    figures = metrics.armse(gt, est)
    assert figures["trans_en"] == pytest.approx(np.mean(expected_curve))
    assert figures["trans"] == pytest.approx(np.mean(metrics.crmse(np.sqrt(errors**2 + 1.0))))
    assert figures["rot"] == 0.0


def test_pose_anees_is_one_for_errors_drawn_from_the_covariances() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    sigma = np.diag([0.1, 0.2, 0.3, 0.01, 0.02, 0.03]) ** 2
    gt = np.array([se3_exp(np.concatenate([rng.normal(size=3) * 5, rng.normal(size=3)])) for _ in range(n)])
    xi = rng.multivariate_normal(np.zeros(6), sigma, size=n)
    est = np.array([np.linalg.inv(se3_exp(x)) @ g for x, g in zip(xi, gt, strict=True)])  # Log(T_gt T_est^-1) = xi
    covariances = np.broadcast_to(sigma, (n, 6, 6)).copy()
    covariances[5] = np.nan  # a frame whose covariance was not queried is skipped
    assert metrics.pose_anees(gt, est, covariances) == pytest.approx(1.0, abs=0.05)
    with pytest.raises(ValueError, match="one 6x6 covariance per pose"):
        metrics.pose_anees(gt, est, covariances[:-1])


def test_relative_change_and_averaging_of_figures() -> None:
    assert metrics.mean_relative_change([0.5, 3.0], [1.0, 2.0]) == pytest.approx(0.0)
    assert metrics.average_figures([{"a": 1.0, "b": 2.0}, {"a": 3.0}]) == {"a": 2.0, "b": 2.0}
    with pytest.raises(ValueError, match="no runs"):
        metrics.average_figures([])
    a = np.repeat(np.eye(4)[None], 3, axis=0)
    b = a.copy()
    b[1, :3, 3] = [3.0, 4.0, 0.0]
    b[2] = np.nan
    assert metrics.max_position_difference(a, b) == 5.0
    assert metrics.count_finite_poses(b) == 2
    assert metrics.latency_summary([1.0, 2.0, 3.0])["median_ms"] == 2.0


def test_rotation_drift_splits_a_shared_bias_from_alternating_noise() -> None:
    from pvo_core.lie import so3_exp

    rng = np.random.default_rng(0)
    truth = np.array([so3_exp(np.array([0.0, yaw, 0.0])) for yaw in rng.uniform(-0.05, 0.05, 400)])
    bias = np.array([1e-4, -2e-4, 5e-5])
    noise = np.array([3e-4, 0.0, 0.0])
    # every pair erred by the bias and, alternately, by plus and minus the noise: the mean is the bias exactly
    estimate = np.array([c @ so3_exp(bias + (1 if k % 2 else -1) * noise) for k, c in enumerate(truth)])
    drift = metrics.rotation_drift(truth, estimate)
    assert drift.pairs == 400
    np.testing.assert_allclose(drift.bias, bias, atol=2e-9)
    np.testing.assert_allclose(drift.spread, np.abs(noise), atol=2e-9)
    np.testing.assert_allclose(drift.integrated_bias, 400 * bias, atol=1e-6)
    np.testing.assert_allclose(drift.integrated_spread, 20 * np.abs(noise), atol=1e-6)
    assert drift.turn_gain == pytest.approx(0.0, abs=0.02)  # the yaw error does not follow the turns


def test_rotation_drift_reads_a_turn_gain() -> None:
    from pvo_core.lie import so3_exp

    yaws = np.linspace(-0.06, 0.06, 101)
    truth = np.array([so3_exp(np.array([0.0, y, 0.0])) for y in yaws])
    short = np.array([so3_exp(np.array([0.0, 0.98 * y, 0.0])) for y in yaws])  # every turn read 2 % short
    drift = metrics.rotation_drift(truth, short)
    assert drift.turn_gain == pytest.approx(-0.02, abs=1e-9)
    np.testing.assert_allclose(drift.bias, [0.0, 0.0, 0.0], atol=1e-15)  # turns both ways: no mean
    with pytest.raises(ValueError, match=r"\(N, 3, 3\)"):
        metrics.rotation_drift(truth[:1], short[:1])


def test_the_thesis_vo_drifts_in_yaw_more_than_its_pairs_scatter(pvo_data: Path) -> None:
    # viso2-s on KITTI 05: a yaw bias of ~-5 mdeg per pair, which over the drive's 2760 pairs adds up to several
    # times what its pairs' scatter would as a random walk
    ground_truth, vo = viso2s(pvo_data, "2011_09_30_drive_0018")
    relative = lambda poses: np.einsum("kji,kjl->kil", poses[:-1, :3, :3], poses[1:, :3, :3])  # noqa: E731
    drift = metrics.rotation_drift(relative(ground_truth), relative(vo))
    assert np.degrees(drift.bias[1]) == pytest.approx(-0.00514, abs=2e-4)
    assert abs(drift.integrated_bias[1]) > 3 * drift.integrated_spread[1]
