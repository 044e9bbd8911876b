"""PROBE-GK training on the thesis's synthetic point world: with ground truth the model learns the true
per-feature error covariances; EM raises the likelihood; the estimators keep Table 4.1's ordering."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from pvo_frontend.probe.evaluation import ESTIMATORS, KNN_ROW, fixed_solver, run_estimator, synthetic_experiment
from pvo_frontend.probe.gk import GKConfig
from pvo_frontend.probe.synthetic import PREDICTORS, PointWorldConfig, simulate
from pvo_frontend.probe.training import reprojection_errors, train_expectation_maximisation, train_with_ground_truth
from pvo_frontend.vo.solver import RobustLoss

WORLD = PointWorldConfig()


def test_ground_truth_errors_vanish_without_noise() -> None:
    quiet = replace(WORLD, sigma_top=0.0, sigma_bottom=0.0, outlier_fraction=0.0)
    run = simulate(quiet, 2.0, seed=3)
    for pair, motion in zip(run.pairs, run.motions, strict=True):
        assert len(pair) > 50
        np.testing.assert_allclose(reprojection_errors(quiet.camera, motion, pair), 0.0, atol=1e-7)


def test_gk_gt_learns_the_true_error_covariance_per_image_row_within_20_percent() -> None:
    clean = replace(WORLD, outlier_fraction=0.0)
    train = simulate(clean, 30.0, seed=1)
    test = simulate(clean, 20.0, seed=2)
    model = train_with_ground_truth(clean.camera, train.pairs, train.motions, PREDICTORS, GKConfig(max_neighbours=256))
    rows = np.concatenate([p.predictors[:, 0] for p in test.pairs])
    errors = np.vstack([reprojection_errors(clean.camera, m, p) for p, m in zip(test.pairs, test.motions, strict=True)])
    noise = model.noise(rows[:, None])
    predicted = noise.covariance  # the Student-t's covariance
    edges = np.quantile(rows, [0.0, 0.25, 0.5, 0.75, 1.0])
    for low, high in itertools.pairwise(edges):
        band = (rows >= low) & (rows < high)
        assert band.sum() > 1000
        true = np.cov(errors[band].T)
        said = predicted[band].mean(axis=0)
        np.testing.assert_allclose(np.diag(said), np.diag(true), rtol=0.2, err_msg=f"rows {low:.0f}-{high:.0f}")
    # the variance grows down the image, as the world's noise does
    top, bottom = predicted[rows < edges[1], 0, 0].mean(), predicted[rows > edges[3], 0, 0].mean()
    assert bottom > 2.0 * top


def test_em_raises_the_likelihood_every_iteration() -> None:
    train = simulate(WORLD, 10.0, seed=4)
    static = fixed_solver(WORLD.camera, (2.0, 2.0, 2.8), RobustLoss("student_t", 5.0))
    lines: list[str] = []
    result = train_expectation_maximisation(
        WORLD.camera, train.pairs, run_estimator(train.pairs, static), PREDICTORS, GKConfig(), iterations=4, say=lines.append
    )
    history = np.array(result.log_likelihood)
    assert len(history) == 5 and len(lines) == 5
    assert np.all(np.diff(history) >= -1e-6 * np.abs(history[:-1]))
    assert history[-1] > history[0]
    # the EM motions end closer to the truth than the M-estimator's they started from
    start = run_estimator(train.pairs, static)
    before = np.mean([np.linalg.norm(s[:3, 3] - m[:3, 3]) for s, m in zip(start, train.motions, strict=True)])
    after = np.mean([np.linalg.norm(t[:3, 3] - m[:3, 3]) for t, m in zip(result.transforms, train.motions, strict=True)])
    assert after < before


def test_table_4_1_ordering_on_a_short_traverse() -> None:
    table = synthetic_experiment(train_seconds=15.0, test_seconds=30.0, em_iterations=3)
    assert set(table.armse) == {*ESTIMATORS, KNN_ROW}
    trans = {name: table.armse[name]["trans"] for name in ESTIMATORS}
    assert trans["PROBE-GK-GT"] < trans["Static M-estimator"] < trans["Fixed covariance"]
    assert table.change("PROBE-GK-GT") < -0.5  # at least 50 % better than the fixed covariance
    assert trans["PROBE-GK-EM"] < trans["Static M-estimator"]
    assert trans["PROBE-GK-EM"] == pytest.approx(trans["PROBE-GK-GT"], rel=0.3)


def test_a_traverse_solved_in_segments_is_each_frame_by_its_segments_solver() -> None:
    """`per_frame_table` (Table 4.1 with the predictors each frame has): one segment is the plain table; the pairs
    split in two with the same solvers give the same trajectories; a segment of other solvers changes only what
    comes after its first frame; a pair count that does not match the poses is one line."""
    from pvo_frontend.probe.evaluation import estimator_solvers, per_frame_table

    train, test = simulate(WORLD, 10.0, seed=1), simulate(WORLD, 6.0, seed=2)
    solvers, log_likelihood = estimator_solvers(
        WORLD.camera, train.pairs, train.motions, WORLD.camera, PREDICTORS, em_iterations=2
    )
    whole = per_frame_table([(test.pairs, solvers)], test.poses, log_likelihood)
    assert set(whole.armse) == {*ESTIMATORS, KNN_ROW} and whole.em_log_likelihood == log_likelihood
    static = run_estimator(test.pairs, solvers["Static M-estimator"])
    np.testing.assert_allclose(whole.trajectories["Static M-estimator"][1], test.poses[0] @ np.linalg.inv(static[0]))
    split = per_frame_table([(test.pairs[:20], solvers), (test.pairs[20:], solvers)], test.poses)
    for name in whole.armse:
        np.testing.assert_allclose(split.trajectories[name], whole.trajectories[name])
    fixed = {name: solvers["Fixed covariance"] for name in solvers}
    mixed = per_frame_table([(test.pairs[:20], solvers), (test.pairs[20:], fixed)], test.poses)
    gk_whole, gk_mixed = whole.trajectories["PROBE-GK-GT"], mixed.trajectories["PROBE-GK-GT"]
    np.testing.assert_allclose(gk_mixed[:21], gk_whole[:21])
    assert not np.allclose(gk_mixed[21:], gk_whole[21:])
    with pytest.raises(ValueError, match="20 frame pairs in the segments for"):
        per_frame_table([(test.pairs[:20], solvers)], test.poses)
