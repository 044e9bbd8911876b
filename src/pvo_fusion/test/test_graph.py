"""FusionGraph behaviour: exactness without aiding sensors, fusion gains, covariance, timing rules, bad input."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
from pvo_core.lie import se3_adjoint, se3_exp, se3_inverse, se3_log, so3_exp, so3_log
from pvo_fusion.factors import zenith_azimuth
from pvo_fusion.sun_reference import FixedSunReference, TabulatedSunReference

from pvo_fusion import FusionConfig, FusionGraph, RelativeMeasurement, SunMeasurement
from pvo_fusion.config import flatten, from_flat

SUN_MAP = np.array([0.3, -0.8, 0.52]) / np.linalg.norm([0.3, -0.8, 0.52])
STEP_NS = 100_000_000
T0 = 5_000_000_000


def truth_trajectory(n: int) -> np.ndarray:
    """Camera poses T_map,cam: forward 1 m/frame along z with a slow turn about the camera y axis."""
    poses = [np.eye(4)]
    step = se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.01, 0.0]))  # T_k-1,k in the camera frame
    for _ in range(n - 1):
        poses.append(poses[-1] @ step)
    return np.array(poses)


VO_COV = np.diag([4e-4, 4e-4, 1e-3, 4e-6, 4e-6, 4e-6])  # ROS order [rho; phi]


def vo_stream(truth: np.ndarray, rng: np.random.Generator | None, covariance: np.ndarray = VO_COV) -> list[RelativeMeasurement]:
    """T_k,k-1 with left-perturbation noise drawn from ``covariance`` (no noise when rng is None)."""
    out = []
    chol = np.linalg.cholesky(covariance)
    for k in range(1, len(truth)):
        t = se3_inverse(truth[k]) @ truth[k - 1]
        if rng is not None:
            t = se3_exp(chol @ rng.normal(size=6)) @ t
        out.append(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, t, covariance.copy()))
    return out


def sun_at(truth: np.ndarray, k: int, noise_deg: float = 0.0, rng: np.random.Generator | None = None) -> SunMeasurement:
    s = truth[k][:3, :3].T @ SUN_MAP
    if noise_deg and rng is not None:
        s = s + np.radians(noise_deg) * rng.normal(size=3)
        s /= np.linalg.norm(s)
    sigma = np.radians(max(noise_deg, 0.5))
    zen = zenith_azimuth(s)[0]
    return SunMeasurement(T0 + k * STEP_NS, s, np.diag([sigma**2, sigma**2 / np.sin(zen) ** 2]))


def run(graph: FusionGraph, vo: list[RelativeMeasurement], suns: dict[int, SunMeasurement] | None = None) -> np.ndarray:
    suns = suns or {}
    poses: dict[int, np.ndarray] = {}
    for m in vo:
        graph.add_vo(m)
        if m.stamp in suns:
            graph.add_sun(suns[m.stamp])
        poses.update({p.stamp: p.pose for p in graph.drain_finished()})
    poses.update({p.stamp: p.pose for p in graph.trajectory()})
    return np.array([poses[s] for s in sorted(poses)])


def compose(vo: list[RelativeMeasurement], first: np.ndarray) -> np.ndarray:
    poses = [first]
    for m in vo:
        poses.append(poses[-1] @ se3_inverse(m.transform))
    return np.array(poses)


def rotation_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean([np.sum(so3_log(x[:3, :3] @ y[:3, :3].T) ** 2) for x, y in zip(a, b, strict=True)])))


@pytest.mark.parametrize("smoother", ["incremental", "batch"])
def test_without_aiding_sensors_the_fusion_reproduces_the_vo_exactly(smoother: str) -> None:
    truth = truth_trajectory(400)
    vo = vo_stream(truth, np.random.default_rng(1))
    graph = FusionGraph(from_flat({"solver.smoother": smoother}))
    fused = run(graph, vo)
    np.testing.assert_allclose(fused, compose(vo, np.eye(4)), atol=1e-9)
    assert graph.counts["vo.accepted"] == 399
    assert graph.window_size == int(graph.config.window.lag) + 1  # the newest state and `lag` frames behind it


def test_sun_switched_off_reproduces_the_vo_and_counts_the_measurements() -> None:
    truth = truth_trajectory(120)
    vo = vo_stream(truth, np.random.default_rng(2))
    suns = {T0 + k * STEP_NS: sun_at(truth, k) for k in range(0, 120, 10)}
    graph = FusionGraph(from_flat({"inputs.sun.enabled": False}), FixedSunReference(SUN_MAP))
    fused = run(graph, vo, suns)
    np.testing.assert_allclose(fused, compose(vo, np.eye(4)), atol=1e-9)
    assert graph.counts["sun.disabled"] == 11  # frame 0's sun is not fed by `run`


def test_sun_measurements_cut_rotation_drift() -> None:
    truth = truth_trajectory(600)
    rng = np.random.default_rng(3)
    vo = vo_stream(truth, rng, VO_COV * np.array([1, 1, 1, 25, 25, 25])[:, None])
    suns = {T0 + k * STEP_NS: sun_at(truth, k, 2.0, rng) for k in range(10, 600, 10)}
    vo_only = compose(vo, np.eye(4))
    fused = run(FusionGraph(FusionConfig(), FixedSunReference(SUN_MAP)), vo, suns)
    before, after = rotation_rms(vo_only, truth), rotation_rms(fused, truth)
    assert after < 0.5 * before, (before, after)
    # The sun does not see rotation about its own axis: the error left is mostly along SUN_MAP.
    residual = np.array([so3_log(f[:3, :3] @ t[:3, :3].T) for f, t in zip(fused, truth, strict=True)])
    along = residual @ SUN_MAP
    assert np.sqrt(np.mean(np.sum(residual**2, axis=1) - along**2)) < 0.6 * np.sqrt(np.mean(along**2)) + 0.01


def biased_suns(truth: np.ndarray, offset: np.ndarray, noise: float, sigma: float, rng: np.random.Generator) -> dict:
    """Sun readings every 10th frame whose (zenith, azimuth) carry one ``offset`` (rad) for the whole drive plus white
    ``noise`` (rad), each published with a per-reading-consistent covariance ``sigma``² (offset included)."""
    from pvo_core.sun import zenith_azimuth_to_vector

    suns = {}
    for k in range(10, len(truth), 10):
        za = zenith_azimuth(truth[k][:3, :3].T @ SUN_MAP) + offset + noise * rng.normal(size=2)
        s = np.asarray(zenith_azimuth_to_vector(za[0], za[1]))
        suns[T0 + k * STEP_NS] = SunMeasurement(T0 + k * STEP_NS, s, np.diag([sigma**2, sigma**2 / np.sin(za[0]) ** 2]))
    return suns


BIAS = {"inputs.sun.bias_sigma": (0.3, 0.3), "inputs.sun.bias_walk_sigma": (0.003, 0.003)}
GOOD_VO = VO_COV * np.array([1, 1, 1, 0.04, 0.04, 0.04])[:, None]  # σ 4e-4 rad per frame drawn, VO_COV stated


def error_across_the_sun(fused: np.ndarray, truth: np.ndarray) -> float:
    """RMS rotation error (rad) without its part about the sun's axis, which no sun reading observes."""
    residual = np.array([so3_log(f[:3, :3] @ t[:3, :3].T) for f, t in zip(fused, truth, strict=True)])
    residual -= np.outer(residual @ SUN_MAP, SUN_MAP)
    return float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))


def drifting_vo(truth: np.ndarray, yaw_per_frame: float, rng: np.random.Generator) -> list[RelativeMeasurement]:
    """VO drawn from GOOD_VO with a yaw error per frame its stated covariance (VO_COV) does not carry."""
    drift = se3_exp(np.array([0.0, 0.0, 0.0, 0.0, yaw_per_frame, 0.0]))
    return [RelativeMeasurement(m.stamp, m.reference_stamp, drift @ m.transform, VO_COV) for m in vo_stream(truth, rng, GOOD_VO)]


def test_a_sun_bias_state_absorbs_a_drive_long_offset_instead_of_rotating_a_good_vo() -> None:
    truth = truth_trajectory(600)
    rng = np.random.default_rng(12)
    vo = drifting_vo(truth, 0.0, rng)
    suns = biased_suns(truth, np.array([0.1, 0.15]), 0.03, 0.1, rng)  # offsets of 1-1.5 σ, as Sun-BCNN's drives
    reference = FixedSunReference(SUN_MAP)
    vo_error = error_across_the_sun(compose(vo, np.eye(4)), truth)
    independent = error_across_the_sun(run(FusionGraph(FusionConfig(), reference), vo, suns), truth)
    graph = FusionGraph(from_flat(BIAS), reference)
    with_bias = error_across_the_sun(run(graph, vo, suns), truth)
    # measured: VO 0.006 rad, independent readings 0.106, with the bias state 0.006 (incremental)
    assert independent > 5 * vo_error, (vo_error, independent)  # the offset, taken as noise, turns the estimate
    assert with_bias < 1.2 * vo_error, (vo_error, with_bias)
    assert graph.factor_counts["sun"] == len(suns) and graph.factor_counts["sun_bias_prior"] == 1  # one chain


def test_a_sun_bias_state_still_takes_out_the_drift_of_a_drifting_vo() -> None:
    truth = truth_trajectory(600)
    rng = np.random.default_rng(12)
    vo = drifting_vo(truth, 3e-4, rng)  # 0.18 rad of yaw by the end
    suns = biased_suns(truth, np.array([0.1, 0.15]), 0.03, 0.1, rng)
    reference = FixedSunReference(SUN_MAP)
    vo_error = error_across_the_sun(compose(vo, np.eye(4)), truth)
    independent = error_across_the_sun(run(FusionGraph(FusionConfig(), reference), vo, suns), truth)
    with_bias = error_across_the_sun(run(FusionGraph(from_flat(BIAS), reference), vo, suns), truth)
    # measured: VO 0.060 rad, independent readings 0.117 (the offset again), with the bias state 0.032
    assert with_bias < 0.6 * vo_error, (vo_error, with_bias)
    assert with_bias < 0.5 * independent, (independent, with_bias)


def test_sun_offsets_marginals_from_the_bayes_tree_equal_the_dense_qr_and_old_offsets_leave_with_their_states() -> None:
    truth = truth_trajectory(160)
    rng = np.random.default_rng(9)
    vo = drifting_vo(truth, 1e-4, rng)
    suns = biased_suns(truth, np.array([0.05, -0.1]), 0.03, 0.1, rng)
    graph = FusionGraph(from_flat({**BIAS, "window.lag": 40.0, "solver.relinearize_threshold": 0.0}), FixedSunReference(SUN_MAP))
    compared = 0
    for k, m in enumerate(vo, 1):
        graph.add_vo(m)
        if m.stamp in suns:
            graph.add_sun(suns[m.stamp])
        if k % 25 == 0 and k % 10 == 5:
            offsets = [key for key, _ in graph._sun_bias]
            # the readings of the 40-frame window: older offsets were marginalised with their states
            assert len(offsets) == len([r for r in range(10, k + 1, 10) if r >= k - 40])
            keys = [graph._keys[graph.newest_stamp], offsets[-1], offsets[0]]
            dense = graph._dense_joint_covariance(keys)
            assert dense.shape == (10, 10)
            np.testing.assert_allclose(graph._joint_covariance(keys), dense, rtol=0.0, atol=1e-9 * np.abs(dense).max())
            compared += 1
    assert compared == 3 and graph.factor_counts["sun"] == 15


def test_sun_bias_settings_are_checked() -> None:
    for values, words in (
        ({"inputs.sun.bias_sigma": (0.1,)}, "inputs.sun.bias_sigma needs 2 values"),
        ({"inputs.sun.bias_sigma": (0.1, -0.1)}, "inputs.sun.bias_sigma needs 2 values >= 0"),
        ({"inputs.sun.bias_sigma": (0.1, 0.1)}, "all four > 0 for a bias state"),
        ({"inputs.sun.bias_sigma": (0.1, 0.0), "inputs.sun.bias_walk_sigma": (0.1, 0.1)}, "all four > 0"),
        ({"inputs.sun.bias_walk_sigma": (0.1, 0.1, 0.1)}, "inputs.sun.bias_walk_sigma needs 2 values"),
    ):
        with pytest.raises(ValueError, match=words):
            from_flat(values)


def test_marginal_covariance_of_a_vo_chain_matches_first_order_propagation() -> None:
    truth = truth_trajectory(8)
    vo = vo_stream(truth, None)
    graph = FusionGraph(from_flat({"window.lag": 50.0}))
    prior_sigmas = np.array([1e-3] * 3 + [1e-4] * 3)  # ROS order: translation, rotation
    pose_cov = np.diag(prior_sigmas**2)
    for m in vo:
        graph.add_vo(m)
        # Left perturbation in the map frame (as the stereo_vo node accumulates it):
        # T_map,k = T_map,k-1 T_k,k-1^-1; a left perturbation eps of T_k,k-1 moves T_map,k by -Ad(T_map,k) eps.
        pose_k = graph.pose()
        adjoint = se3_adjoint(pose_k)
        pose_cov = pose_cov + adjoint @ m.covariance @ adjoint.T
        np.testing.assert_allclose(graph.covariance(), pose_cov, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize(("threshold", "tolerance"), [(0.0, 1e-9), (1e-3, 3e-5)])
def test_bayes_tree_marginals_equal_the_dense_qr_of_the_window(threshold: float, tolerance: float) -> None:
    """iSAM2's Bayes tree is linearised where it last relinearised, the dense QR at the current estimate.
    Five frames after a sun measurement the two points coincide (threshold 0) or nearly so; right after
    one they differ by the sun's correction and the marginals by first order in it (measured 1.6e-3)."""
    truth = truth_trajectory(160)
    rng = np.random.default_rng(8)
    vo = vo_stream(truth, rng)
    config = from_flat({"window.lag": 40.0, "solver.relinearize_threshold": threshold})
    graph = FusionGraph(config, FixedSunReference(SUN_MAP))
    compared = 0
    for k, m in enumerate(vo, 1):
        graph.add_vo(m)
        if k % 10 == 0:
            graph.add_sun(sun_at(truth, k, 5.0, rng))
        if k % 25 == 0 and k % 10 == 5:  # the newest state with the oldest live one, marginalisation under way
            stamps = [s.stamp for s in graph.window()]
            keys = [graph._keys[stamps[-1]], graph._keys[stamps[0]]]
            dense = graph._dense_joint_covariance(keys)
            np.testing.assert_allclose(graph._joint_covariance(keys), dense, rtol=0.0, atol=tolerance * np.abs(dense).max())
            compared += 1
    assert compared == 3 and graph.factor_counts["sun"] == 15


def test_measurements_ahead_of_the_vo_are_buffered_and_attached() -> None:
    truth = truth_trajectory(40)
    vo = vo_stream(truth, np.random.default_rng(4))
    graph = FusionGraph(FusionConfig(), FixedSunReference(SUN_MAP))
    graph.add_vo(vo[0])
    early = sun_at(truth, 5)
    assert graph.add_sun(early) == "buffered"
    assert graph.pending() == 1
    for m in vo[1:5]:
        graph.add_vo(m)
    assert graph.counts["sun.accepted"] == 1 and graph.pending() == 0
    assert graph.factor_counts["sun"] == 1


def test_stamp_tolerance_attaches_near_stamps_and_drops_unmatched_ones() -> None:
    truth = truth_trajectory(30)
    vo = vo_stream(truth, None)
    graph = FusionGraph(from_flat({"stamp_tolerance": 0.002, "window.lag": 10.0}), FixedSunReference(SUN_MAP))
    for m in vo[:20]:
        graph.add_vo(m)
    near = sun_at(truth, 15)
    shifted = SunMeasurement(near.stamp + 1_500_000, near.direction, near.covariance)
    assert graph.add_sun(shifted) == "accepted"
    between = SunMeasurement(near.stamp + 50_000_000, near.direction, near.covariance)
    assert graph.add_sun(between) == "dropped.no_state_at_stamp"
    old = sun_at(truth, 2)
    assert graph.add_sun(old) == "dropped.older_than_window"
    assert graph.counts["sun.dropped.older_than_window"] == 1


def test_out_of_order_and_duplicate_vo_are_rejected_without_touching_the_estimate() -> None:
    truth = truth_trajectory(20)
    vo = vo_stream(truth, np.random.default_rng(5))
    graph = FusionGraph()
    for m in vo[:10]:
        graph.add_vo(m)
    before = graph.pose().copy()
    assert graph.add_vo(vo[9]) == "rejected.duplicate_stamp"
    assert graph.add_vo(vo[4]) == "rejected.duplicate_stamp"
    between = RelativeMeasurement(vo[4].stamp + STEP_NS // 2, vo[4].reference_stamp, vo[4].transform, VO_COV)
    assert graph.add_vo(between) == "rejected.out_of_order"
    np.testing.assert_array_equal(graph.pose(), before)


@pytest.mark.parametrize(
    "covariance, reason",
    [
        (np.full((6, 6), np.nan), "rejected.non_finite_covariance"),
        (-np.eye(6), "rejected.covariance_not_positive_definite"),
        (np.diag([1, 1, 1, 1, 1, 0.0]), "rejected.covariance_not_positive_definite"),
    ],
)
def test_bad_vo_covariance_is_rejected_and_counted(covariance: np.ndarray, reason: str) -> None:
    truth = truth_trajectory(5)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    graph.add_vo(vo[0])
    before = graph.pose().copy()
    bad = RelativeMeasurement(vo[1].stamp, vo[1].reference_stamp, vo[1].transform, covariance)
    assert graph.add_vo(bad) == reason
    assert graph.counts[f"vo.{reason}"] == 1
    np.testing.assert_array_equal(graph.pose(), before)
    assert graph.add_vo(vo[1]) == "accepted"


def test_nan_pose_is_rejected() -> None:
    truth = truth_trajectory(3)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    bad = RelativeMeasurement(vo[0].stamp, vo[0].reference_stamp, np.full((4, 4), np.nan), VO_COV)
    assert graph.add_vo(bad) == "rejected.non_finite_pose"
    assert not graph.started


def test_bad_sun_measurements_are_rejected_with_reasons() -> None:
    truth = truth_trajectory(30)
    graph = FusionGraph(FusionConfig(), FixedSunReference(SUN_MAP))
    for m in vo_stream(truth, None):
        graph.add_vo(m)
    good = sun_at(truth, 25)
    before = graph.pose().copy()
    assert graph.add_sun(SunMeasurement(good.stamp, 2.0 * good.direction, good.covariance)) == "rejected.direction_not_unit"
    assert graph.add_sun(SunMeasurement(good.stamp, good.direction * np.nan, good.covariance)) == "rejected.non_finite_direction"
    assert (
        graph.add_sun(SunMeasurement(good.stamp, good.direction, -good.covariance)) == "rejected.covariance_not_positive_definite"
    )
    assert (
        graph.add_sun(SunMeasurement(good.stamp, good.direction, np.full((2, 2), np.nan)))
        == "rejected.covariance_not_positive_definite"
    )
    np.testing.assert_array_equal(graph.pose(), before)
    # A wildly wrong sun (90 degrees off) fails the Mahalanobis gate.
    wrong = np.cross(good.direction, [0.0, 1.0, 0.0])
    wrong /= np.linalg.norm(wrong)
    assert graph.add_sun(SunMeasurement(good.stamp, wrong, good.covariance)) == "gated"
    np.testing.assert_array_equal(graph.pose(), before)
    assert graph.counts["sun.gated"] == 1


def test_with_a_sun_offset_state_bad_late_and_wild_readings_are_handled_as_without_it() -> None:
    truth = truth_trajectory(60)
    rng = np.random.default_rng(13)
    graph = FusionGraph(from_flat(BIAS), FixedSunReference(SUN_MAP))
    for m in vo_stream(truth, None):
        graph.add_vo(m)
    good = sun_at(truth, 55)
    assert graph.add_sun(SunMeasurement(good.stamp, good.direction * np.nan, good.covariance)) == "rejected.non_finite_direction"
    assert graph.factor_counts["sun"] == 0 and not graph._sun_bias  # nothing fused, no offset state made
    for k in (50, 30, 40):  # the 30 arrives after the 50: the offset walks back over the same interval
        assert graph.add_sun(sun_at(truth, k, 1.0, rng)) == "accepted"
    assert [stamp for _, stamp in graph._sun_bias] == [T0 + k * STEP_NS for k in (50, 30, 40)]
    wrong = np.cross(good.direction, [0.0, 1.0, 0.0])
    wrong /= np.linalg.norm(wrong)  # 90 degrees off: beyond what the offset's prior and walk allow, gated
    assert graph.add_sun(SunMeasurement(good.stamp, wrong, good.covariance)) == "gated"
    assert graph.factor_counts["sun"] == 3 and graph.factor_counts["sun_bias_prior"] == 1
    fused = np.array([p.pose for p in graph.trajectory()])
    assert np.all(np.isfinite(fused)) and rotation_rms(fused, truth[-len(fused) :]) < 0.01


def test_sun_without_a_gps_origin_is_rejected_not_fused() -> None:
    truth = truth_trajectory(12)
    graph = FusionGraph()  # reference: ephemeris, and no origin set
    for m in vo_stream(truth, None):
        graph.add_vo(m)
    assert graph.add_sun(sun_at(truth, 10)) == "rejected.no_gps_origin"
    assert graph.factor_counts["sun"] == 0


def fed_graph(frames: int, fed: int, config: FusionConfig | None = None) -> tuple[np.ndarray, list, FusionGraph]:
    """A noiseless drive of ``frames`` frames and a graph fed its first ``fed`` VO motions."""
    truth = truth_trajectory(frames)
    vo = vo_stream(truth, None)
    graph = FusionGraph(config)
    for m in vo[:fed]:
        graph.add_vo(m)
    return truth, vo, graph


def test_vo_gaps_and_lost_frames_are_bridged_by_the_motion_model() -> None:
    truth, vo, graph = fed_graph(60, 10)
    before = graph.covariance()
    # frame 11 never arrives: frame 12 refers to it, a gap of two frame intervals
    assert graph.add_vo(vo[11]) == "accepted"
    assert graph.counts["vo.gap"] == 1
    # bridged under constant velocity from frame 10: continuous (the truth moves at a nearly constant
    # velocity) and the covariance grows by the motion model over two frames, not by lost_variance
    np.testing.assert_allclose(graph.pose()[:3, 3], truth[12][:3, 3], atol=0.5)
    growth = np.diag(graph.covariance() - before)
    sigma = np.array(FusionGraph().config.inputs.vo.gap_sigma) * 0.2  # 0.2 s of gap
    assert np.all(growth > 0.9 * sigma**2) and np.all(growth < 10.0)
    # three lost frames after a measured one (the frontend's 9999 I, a wrong motion in them): bridged too, their
    # motion not used, and the rotation's covariance grows as over one 0.3 s outage (diag(gap_sigma²) T² + n² Σ_v),
    # not by three independent 0.1 s links nor by 9999
    assert graph.add_vo(vo[12]) == "accepted"
    before_lost = graph.covariance()
    for k in (13, 14, 15):
        wrong = se3_exp(np.array([5.0, 0.0, 0.0, 0.0, 0.5, 0.0]))
        assert graph.add_vo(RelativeMeasurement(vo[k].stamp, vo[k].reference_stamp, wrong, np.eye(6) * 9999.0)) == "accepted"
    assert graph.counts["vo.lost"] == 3
    np.testing.assert_allclose(graph.pose()[:3, 3], truth[16][:3, 3], atol=0.5)
    growth = np.diag(graph.covariance() - before_lost)
    outage = np.array(FusionGraph().config.inputs.vo.gap_sigma) ** 2 * 0.3**2 + 9.0 * np.diag(VO_COV)
    np.testing.assert_allclose(growth[3:], outage[3:], rtol=0.05)
    assert np.all(growth[:3] > 0.9 * outage[:3]) and np.all(growth[:3] < 10.0)  # plus the rotation's lever arm
    for m in vo[16:]:
        graph.add_vo(m)
    assert np.all(np.isfinite(graph.pose()))
    np.testing.assert_allclose(graph.pose()[:3, 3], truth[59][:3, 3], atol=1.0)


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_a_lost_frame_bridge_is_loosened_by_lost_sigma_scale_and_a_gap_is_not(scale: float) -> None:
    _, vo, graph = fed_graph(30, 10, from_flat({"inputs.vo.lost_sigma_scale": scale}))
    before = graph.covariance()
    graph.add_vo(RelativeMeasurement(vo[10].stamp, vo[10].reference_stamp, vo[10].transform, np.eye(6) * 9999.0))
    lost_growth = np.diag(graph.covariance() - before)[3:]
    gap_sigma = np.array(graph.config.inputs.vo.gap_sigma)
    np.testing.assert_allclose(lost_growth, (scale * gap_sigma[3:] * 0.1) ** 2 + np.diag(VO_COV)[3:], rtol=0.05)
    for m in vo[11:20]:
        graph.add_vo(m)
    before = graph.covariance()
    graph.add_vo(vo[21])  # frame 21 refers to frame 20, never seen: a gap of 0.2 s, bridged at gap_sigma itself
    gap_growth = np.diag(graph.covariance() - before)[3:]
    np.testing.assert_allclose(gap_growth, (gap_sigma[3:] * 0.2) ** 2 + 4.0 * np.diag(VO_COV)[3:], rtol=0.05)
    with pytest.raises(ValueError, match="lost_sigma_scale must be positive"):
        from_flat({"inputs.vo.lost_sigma_scale": 0.0})


def test_a_vo_lost_on_its_first_motion_is_bridged_within_what_a_vehicle_can_do() -> None:
    """No motion measured yet, so no velocity to bridge with: standing still, with the covariance of the plausibility
    bounds over the interval (not lost_variance·I, whose 31 rad of rotation σ is no distribution on SO(3))."""
    truth = truth_trajectory(20)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    first = vo[0]
    assert (
        graph.add_vo(RelativeMeasurement(first.stamp, first.reference_stamp, first.transform, np.eye(6) * 9999.0)) == "accepted"
    )
    assert graph.counts["vo.lost"] == 1
    np.testing.assert_allclose(graph.pose(), np.eye(4), atol=1e-9)
    vo_config = graph.config.inputs.vo
    sigma = np.array([vo_config.max_speed * 0.1] * 3 + [min(vo_config.max_angular_rate * 0.1, 1.0)] * 3)
    np.testing.assert_allclose(np.diag(graph.covariance()), sigma**2, rtol=0.05)  # plus the first state's tight prior
    for m in vo[1:]:
        assert graph.add_vo(m) == "accepted"
    assert np.all(np.isfinite(graph.pose()))


FIXTURES = Path(__file__).parent / "fixtures"


def replay_fixture(name: str, sun: bool, diverge_at: int | None = None) -> tuple[FusionGraph, np.ndarray, np.ndarray, np.ndarray]:
    """A recorded drive through the graph as the sun experiment runs it; the online pose after each VO, the smoothed
    path, and the truth at each of them. ``diverge_at``: the update of that VO frame's state diverges (one NaN pose)."""
    z = np.load(FIXTURES / name)
    stamps = [int(s) for s in z["stamps"]]
    config = from_flat(
        {"prior.source": "given", "inputs.sun.reference": "table", "inputs.vo.max_speed": 1000.0, "inputs.sun.enabled": sun}
    )
    graph = FusionGraph(config, TabulatedSunReference(stamps, z["sun_map"]))
    graph.set_initial_pose(z["ground_truth"][0])
    suns = {
        int(s): SunMeasurement(int(s), d, c)
        for s, d, c in zip(z["sun_stamps"], z["sun_directions"], z["sun_covariances"], strict=True)
    }
    online = []
    for frame, ((reference, stamp), transform, covariance) in enumerate(
        zip(z["vo_stamps"], z["vo_transforms"], z["vo_covariances"], strict=True)
    ):
        if frame == diverge_at:
            key = gtsam.symbol_shorthand.X(graph._next_index)
            graph._smoother = _Diverging(graph._smoother, key, np.array([np.nan, 0.0, 0.0]))
        graph.add_vo(RelativeMeasurement(int(stamp), int(reference), transform, covariance))
        assert not isinstance(graph._smoother, _Diverging)  # the restart made a fresh smoother: one diverged update
        if int(stamp) in suns:
            graph.add_sun(suns[int(stamp)])
        online.append(graph.pose())
    smoothed = np.array([p.pose for p in graph.trajectory()])
    return graph, np.array(online), smoothed, z["ground_truth"]


def test_a_lost_vo_stretch_between_sun_readings_does_not_make_the_fusion_diverge() -> None:
    """Stop 78's defect, on 130 frames of the rendered drive 03bm (renderer revision 9, through the lens): the VO loses
    frames 54-57 (its covariances there 5e3-1e6, the frontend's 9999 I calibrated), the sun readings are the true
    directions with Sun-BCNN's covariances. Linked by those covariances, the lost frames let the smoother turn the
    window about the sun without bound: 2.6e13 m of online error by frame 130. Bridged, the fusion stays near the VO."""
    graph, online, smoothed, truth = replay_fixture("lost_vo_with_sun_03bm.npz", sun=True)
    _, vo_online, _, _ = replay_fixture("lost_vo_with_sun_03bm.npz", sun=False)
    assert graph.counts["vo.lost"] == 4 and graph.factor_counts["sun"] >= 10
    assert not any(k.startswith("solver.") for k in graph.counts), graph.counts
    assert np.all(np.isfinite(online)) and np.all(np.isfinite(smoothed)) and len(smoothed) == len(truth)
    error = np.linalg.norm(online[:, :3, 3] - truth[1:, :3, 3], axis=1)
    vo_error = np.linalg.norm(vo_online[:, :3, 3] - truth[1:, :3, 3], axis=1)
    # measured: the VO fused alone at most 11.0 m, with the sun readings 9.9 m (online)
    assert error.max() < vo_error.max(), (error.max(), vo_error.max())
    smoothed_error = np.linalg.norm(smoothed[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert smoothed_error.max() < vo_error.max(), (smoothed_error.max(), vo_error.max())


class _Diverging:
    """A smoother that, once armed, answers one update with a pose ``value`` (NaN or 1e12 m away) for the newest state."""

    def __init__(self, smoother: object, key: int, translation: np.ndarray) -> None:
        self._smoother = smoother
        self._key = key
        self._translation = translation

    def calculateEstimate(self) -> gtsam.Values:  # noqa: N802 (GTSAM's name)
        estimate = gtsam.Values(self._smoother.calculateEstimate())
        estimate.update(self._key, gtsam.Pose3(gtsam.Rot3(), self._translation))
        return estimate

    def __getattr__(self, name: str) -> object:
        return getattr(self._smoother, name)


@pytest.mark.parametrize("translation", [np.array([np.nan, 0.0, 0.0]), np.array([1e12, 0.0, 0.0])])
def test_a_diverged_solution_restarts_a_lost_state_at_the_last_good_estimate(translation: np.ndarray) -> None:
    truth, vo, graph = fed_graph(40, 20)
    good = graph.pose()
    healthy = graph._smoother
    new_key = gtsam.symbol_shorthand.X(graph._next_index)
    graph._smoother = _Diverging(healthy, new_key, translation)
    assert graph.add_vo(vo[20]) == "accepted"
    assert graph.counts["solver.diverged"] == 1 and graph.last_rejection.startswith("solver: diverged")
    # the newest state restarts where the motion model put it, with the covariance of a lost state: the position by
    # lost_variance, the orientation by 1 rad of σ per axis (a distribution on SO(3))
    np.testing.assert_allclose(graph.pose()[:3, 3], truth[21][:3, 3], atol=1e-6)
    assert np.linalg.norm(graph.pose()[:3, 3] - good[:3, 3]) < 2.0
    variances = np.diag(graph.covariance())
    assert np.min(variances[:3]) >= 0.999 * graph.config.inputs.vo.lost_variance
    np.testing.assert_allclose(variances[3:], 1.0, rtol=0.01)
    for m in vo[21:]:  # the restarted window is the graph's own again
        graph.add_vo(m)
    fused = np.array([p.pose for p in graph.trajectory()])
    assert np.all(np.isfinite(fused)) and len(fused) == len(truth)
    np.testing.assert_allclose(fused[:, :3, 3], truth[:, :3, 3], atol=1e-6)


@pytest.mark.parametrize("restart_at", [10, 30])
def test_a_restart_with_sun_readings_keeps_the_orientation_within_what_was_known(restart_at: int) -> None:
    """A restart forced (one diverged update) into stop 78's recorded drive 03bm with its sun readings. The restarted
    state's orientation prior was lost_variance·I (31 rad of σ): the sun readings then turned the window through
    84-105° (57-70 m of online error; the VO alone errs 11.0 m and 10.1° at most). At 1 rad of σ per axis it stays
    within 6.7° and 11.9 m (measured)."""
    graph, online, _, truth = replay_fixture("lost_vo_with_sun_03bm.npz", sun=True, diverge_at=restart_at)
    assert graph.counts["solver.diverged"] == 1
    truth = truth[1:]
    rotation_error = [np.degrees(np.linalg.norm(so3_log(o[:3, :3].T @ t[:3, :3]))) for o, t in zip(online, truth, strict=True)]
    assert max(rotation_error) < 10.0, max(rotation_error)
    assert np.linalg.norm(online[:, :3, 3] - truth[:, :3, 3], axis=1).max() < 16.0


def test_a_restarted_vo_after_a_long_gap_continues_the_estimate_and_its_covariance_recovers() -> None:
    """Issue 18, defect 3: the VO killed for 2 s and restarted; its first message refers to a frame the fusion
    never saw. The bridge keeps the path continuous and the covariance stays that of a 2 s dead reckoning."""
    truth = truth_trajectory(80)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    for m in vo[:30]:
        graph.add_vo(m)
    pose_before = graph.pose()
    for m in vo[50:]:  # frames 31..50 never come; the restarted VO's first motion is 50 -> 51
        assert graph.add_vo(m) == "accepted"
    assert graph.counts["vo.gap"] == 1
    poses = [p.pose for p in graph.trajectory()]
    steps = np.linalg.norm(np.diff(np.array([p[:3, 3] for p in poses]), axis=0), axis=1)
    assert steps.max() < 25.0  # the 2 s bridge is one step of about 20 frames' travel, nothing jumps beyond it
    np.testing.assert_allclose(graph.pose()[:3, 3], truth[79][:3, 3], atol=5.0)
    variance = np.diag(graph.covariance())[:3]
    assert np.max(variance) < 1e3  # 2 s of dead reckoning (≈10 m), not the 1e6 m^2 of a lost_variance link
    assert np.all(np.abs(graph.pose()[:3, 3] - truth[79][:3, 3]) < 3.0 * np.sqrt(variance))  # and consistent
    assert np.linalg.norm(graph.pose()[:3, 3] - pose_before[:3, 3]) > 10.0


def straight_then_turning(n: int, turn_from: int) -> np.ndarray:
    """Camera poses T_map,cam: forward 1 m/frame, straight until ``turn_from``, then turning 2 deg per frame."""
    poses = [np.eye(4)]
    for k in range(1, n):
        yaw = np.radians(2.0) if k > turn_from else 0.0
        poses.append(poses[-1] @ se3_exp(np.array([0.0, 0.0, 1.0, 0.0, yaw, 0.0])))
    return np.array(poses)


def rotation_readings(truth: np.ndarray, first: int, last: int, sigma: float = 1e-3) -> list[RelativeMeasurement]:
    """Exact C_k,k-1 for the frame pairs first..last, as HydraNet publishes them (rotation block sigma rad)."""
    readings = []
    for k in range(first, last + 1):
        c = (se3_inverse(truth[k]) @ truth[k - 1]).copy()
        c[:3, 3] = 0.0
        covariance = np.diag([1e6, 1e6, 1e6, sigma**2, sigma**2, sigma**2])
        readings.append(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, c, covariance, True))
    return readings


@pytest.mark.parametrize("bridge", [True, False])
def test_a_vo_outage_in_a_turn_is_bridged_by_the_rotations_received_over_it(bridge: bool) -> None:
    """The VO stops for 2 s just as the vehicle starts to turn (frames 31..50 never come) while a rotation sensor
    keeps reading every frame pair: with ``bridge_gaps`` the heading follows its readings through the gap and the
    position is dead-reckoned along them; the constant-velocity bridge drives on straight, 38 deg off."""
    truth = straight_then_turning(80, turn_from=31)
    vo = vo_stream(truth, None)
    graph = FusionGraph(from_flat({"inputs.rotation.bridge_gaps": bridge}))
    for m in vo[:30]:  # motions up to frame 30
        graph.add_vo(m)
    for reading in rotation_readings(truth, 31, 50):  # they come while the VO is down, and wait in the buffer
        assert graph.add_rotation(reading) == "buffered"
    assert graph.add_vo(vo[50]) == "accepted"  # the restarted VO's first motion, 50 -> 51
    assert graph.counts["vo.gap"] == 1
    heading_error = np.degrees(np.linalg.norm(so3_log(graph.pose()[:3, :3].T @ truth[51][:3, :3])))
    position_error = np.linalg.norm(graph.pose()[:3, 3] - truth[51][:3, 3])
    if bridge:
        assert graph.counts["rotation.bridged"] == 20 and graph.counts["rotation.buffered"] == 0
        assert heading_error < 2.5  # the last pair (50 -> 51) at the last angular velocity: 2 deg
        assert position_error < 0.5  # along the arc, not the chord (the 2 s arc leaves the straight line by 6.6 m)
    else:
        assert graph.counts["rotation.bridged"] == 0
        assert heading_error > 35.0 and position_error > 5.0
    for m in vo[51:]:
        graph.add_vo(m)
    assert np.all(np.isfinite(graph.pose()))


def test_a_gap_bridged_part_way_turns_the_rest_at_the_last_rate_and_a_wild_chain_is_not_used() -> None:
    truth = straight_then_turning(60, turn_from=0)  # turning all the way: the last angular velocity is right
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    for m in vo[:30]:
        graph.add_vo(m)
    for reading in rotation_readings(truth, 31, 45):  # the readings for 46..50 have not come yet
        graph.add_rotation(reading)
    graph.add_vo(vo[50])
    assert graph.counts["rotation.bridged"] == 15
    assert np.degrees(np.linalg.norm(so3_log(graph.pose()[:3, :3].T @ truth[51][:3, :3]))) < 0.5
    # readings 90 deg off the constant-velocity bridge over 2 s are garbage, not a turn: the bridge ignores them
    wild = FusionGraph()
    for m in vo[:30]:
        wild.add_vo(m)
    for reading in rotation_readings(truth, 31, 50):
        wrong = reading.transform.copy()
        wrong[:3, :3] = so3_exp(np.array([0.0, np.radians(4.5), 0.0])) @ wrong[:3, :3]
        wild.add_rotation(RelativeMeasurement(reading.stamp, reading.reference_stamp, wrong, reading.covariance, True))
    wild.add_vo(vo[50])
    assert wild.counts["rotation.bridged"] == 0 and wild.counts["rotation.bridge_gated"] == 1


def test_pose_corrections_and_relative_rotations_pull_towards_the_truth() -> None:
    truth = truth_trajectory(200)
    rng = np.random.default_rng(6)
    biased = VO_COV.copy()
    vo = []
    for m in vo_stream(truth, rng):
        # a constant yaw bias the VO covariance does not know about
        t = se3_exp(np.array([0, 0, 0, 0, 2e-3, 0])) @ m.transform
        vo.append(RelativeMeasurement(m.stamp, m.reference_stamp, t, biased))
    # The VO is biased beyond its covariance, so the aiding measurements disagree with it by several
    # sigma: the gates (tested below) would call them outliers; here we test the factors' pull.
    ungated = {"window.lag": 12.0, "inputs.correction.gate_probability": 0.0, "inputs.rotation.gate_probability": 0.0}
    graph = FusionGraph(from_flat(ungated))
    hydra = FusionGraph(from_flat(ungated))
    dp = 5
    fused_poses: dict[int, np.ndarray] = {}
    hydra_poses: dict[int, np.ndarray] = {}
    for i, m in enumerate(vo):
        graph.add_vo(m)
        hydra.add_vo(m)
        k = i + 1
        if k % dp == 0:
            t = se3_inverse(truth[k]) @ truth[k - dp]
            correction = RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - dp) * STEP_NS, t, VO_COV / 10)
            assert graph.add_correction(correction) == "accepted"
            rot_cov = np.diag([9.0, 9.0, 9.0, 1e-7, 1e-7, 1e-7])
            assert (
                hydra.add_rotation(RelativeMeasurement(correction.stamp, correction.reference_stamp, t, rot_cov, True))
                == "accepted"
            )
        fused_poses.update({p.stamp: p.pose for p in graph.drain_finished()})
        hydra_poses.update({p.stamp: p.pose for p in hydra.drain_finished()})
    fused_poses.update({p.stamp: p.pose for p in graph.trajectory()})
    hydra_poses.update({p.stamp: p.pose for p in hydra.trajectory()})
    vo_only = compose(vo, np.eye(4))
    fused = np.array([fused_poses[s] for s in sorted(fused_poses)])
    rotated = np.array([hydra_poses[s] for s in sorted(hydra_poses)])
    assert rotation_rms(fused, truth) < 0.3 * rotation_rms(vo_only, truth)
    assert rotation_rms(rotated, truth) < 0.3 * rotation_rms(vo_only, truth)
    assert graph.factor_counts["correction"] == 39 and hydra.factor_counts["rotation"] == 39


def turning_trajectory(n: int, yaw_per_frame: float) -> np.ndarray:
    """T_map,cam: 1 m/frame along z, turning ``yaw_per_frame`` rad about the camera y axis every frame."""
    step = se3_exp(np.array([0.0, 0.0, 1.0, 0.0, yaw_per_frame, 0.0]))
    poses = [np.eye(4)]
    for _ in range(n - 1):
        poses.append(poses[-1] @ step)
    return np.array(poses)


def test_the_vo_gain_term_adds_a_share_of_each_motion_to_its_covariance() -> None:
    motion = se3_exp(np.array([0.1, 0.0, 1.0, 0.0, 0.1, 0.02]))
    plain = FusionGraph(from_flat({"inputs.vo.covariance_scale": [2.0] * 6}))
    gained = FusionGraph(from_flat({"inputs.vo.covariance_scale": [2.0] * 6, "inputs.vo.gain_sigma": [0.05, 0.1]}))
    expected = 2.0 * VO_COV
    np.testing.assert_allclose(plain._vo_covariance(motion, VO_COV), expected, rtol=1e-12)
    t, phi = motion[:3, 3], so3_log(motion[:3, :3])
    expected[:3, :3] += 0.05**2 * np.outer(t, t)
    expected[3:, 3:] += 0.1**2 * np.outer(phi, phi)
    np.testing.assert_allclose(gained._vo_covariance(motion, VO_COV), expected, rtol=1e-12, atol=1e-15)
    # nothing is added where there is no motion
    np.testing.assert_allclose(gained._vo_covariance(np.eye(4), VO_COV), 2.0 * VO_COV, rtol=1e-12)
    with pytest.raises(ValueError, match="inputs.vo.gain_sigma needs 2 values >= 0"):
        from_flat({"inputs.vo.gain_sigma": [0.1, -0.1]})
    with pytest.raises(ValueError, match="inputs.vo.gain_sigma needs 2 values >= 0"):
        from_flat({"inputs.vo.gain_sigma": [0.1]})


def test_with_the_gain_term_a_rotation_sensor_mends_a_vo_that_reads_turns_long() -> None:
    """A VO reading every turn 10 % long (a miscalibrated rig) beside exact per-pair rotations at the shipped gate:
    without the gain term its turn-blind covariance makes every reading an outlier; with it they are fused."""
    truth = turning_trajectory(60, 0.1)
    vo = []
    for m in vo_stream(truth, None):
        xi = np.array([0.0, 0.0, 1.0, 0.0, -0.1 * 1.1, 0.0])  # T_k,k-1 of the turn, 10 % too much
        vo.append(RelativeMeasurement(m.stamp, m.reference_stamp, se3_exp(xi), VO_COV))
    rotation_cov = np.diag([9.0, 9.0, 9.0, 1e-6, 1e-6, 1e-6])
    estimates = {}
    for gain in (0.0, 0.1):
        graph = FusionGraph(from_flat({"inputs.vo.gain_sigma": [0.0, gain]}))
        results = []
        poses: dict[int, np.ndarray] = {}
        for k, m in enumerate(vo, start=1):
            graph.add_vo(m)
            exact = se3_inverse(truth[k]) @ truth[k - 1]
            results.append(graph.add_rotation(RelativeMeasurement(m.stamp, m.reference_stamp, exact, rotation_cov, True)))
            poses.update({p.stamp: p.pose for p in graph.drain_finished()})
        poses.update({p.stamp: p.pose for p in graph.trajectory()})
        estimates[gain] = (np.array([poses[s] for s in sorted(poses)]), results)
    vo_only = compose(vo, np.eye(4))
    gated, accepted = estimates[0.0][1], estimates[0.1][1]
    assert gated.count("gated") == len(vo) and accepted.count("accepted") == len(vo)
    assert rotation_rms(estimates[0.0][0], truth) == pytest.approx(rotation_rms(vo_only, truth), rel=1e-6)
    assert rotation_rms(estimates[0.1][0], truth) < 0.2 * rotation_rms(vo_only, truth)


ROTATION_BIAS = {"inputs.rotation.bias_sigma": (1e-3, 1e-3, 1e-3), "inputs.rotation.bias_walk_sigma": (3e-5, 3e-5, 3e-5)}


def offset_rotations(truth: np.ndarray, offset: np.ndarray, noise: float, sigma: float, rng: np.random.Generator) -> list:
    """Relative rotations read as C_from,to Exp(offset + white noise) (rad), each published with covariance sigma² I."""
    covariance = np.diag([9.0, 9.0, 9.0] + [sigma**2] * 3)
    out = []
    for k in range(1, len(truth)):
        c_from_to = truth[k - 1][:3, :3].T @ truth[k][:3, :3] @ so3_exp(offset + noise * rng.normal(size=3))
        reading = np.eye(4)
        reading[:3, :3] = c_from_to.T  # a RelativePose carries C_to,from
        out.append(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, reading, covariance, True))
    return out


def winding_trajectory(n: int, yaw_per_frame: float, period: int = 50) -> np.ndarray:
    """T_map,cam: 1 m/frame along z, ``period`` frames straight, then ``period`` turning, and so on."""
    poses = [np.eye(4)]
    for k in range(1, n):
        turn = yaw_per_frame if (k // period) % 2 else 0.0
        poses.append(poses[-1] @ se3_exp(np.array([0.0, 0.0, 1.0, 0.0, turn, 0.0])))
    return np.array(poses)


def run_with_rotations(graph: FusionGraph, vo: list[RelativeMeasurement], rotations: list[RelativeMeasurement]) -> np.ndarray:
    poses: dict[int, np.ndarray] = {}
    for m, r in zip(vo, rotations, strict=True):
        graph.add_vo(m)
        graph.add_rotation(r)
        poses.update({p.stamp: p.pose for p in graph.drain_finished()})
    poses.update({p.stamp: p.pose for p in graph.trajectory()})
    return np.array([poses[s] for s in sorted(poses)])


def test_a_rotation_offset_state_absorbs_a_drive_long_offset_instead_of_turning_a_good_vo() -> None:
    """Readings whose yaw carries half their sigma as an offset (as HydraNet's on a clean KITTI 10 drive): as white
    noise they turn a good VO by the drive's sum of it; with the offset state the VO stays good."""
    truth = truth_trajectory(600)
    rng = np.random.default_rng(5)
    vo = drifting_vo(truth, 0.0, rng)
    rotations = offset_rotations(truth, np.array([0.0, 5e-4, 2e-4]), 5e-4, 1e-3, rng)
    no_gate = {"inputs.rotation.gate_probability": 0.0}
    vo_error = rotation_rms(compose(vo, np.eye(4)), truth)
    independent = rotation_rms(run_with_rotations(FusionGraph(from_flat(no_gate)), vo, rotations), truth)
    graph = FusionGraph(from_flat({**no_gate, **ROTATION_BIAS}))
    with_offset = rotation_rms(run_with_rotations(graph, vo, rotations), truth)
    # measured: VO 0.0136 rad, independent readings 0.146, with the offset state 0.0082
    assert independent > 5 * vo_error, (vo_error, independent)
    assert with_offset < vo_error, (vo_error, with_offset)
    # every reading fused, one state per second of readings, one chain from one prior
    assert graph.factor_counts["rotation"] == 599 and graph.factor_counts["rotation_bias_prior"] == 1
    assert graph._next_rotation_bias == 60
    offsets = [key for key, _ in graph._rotation_bias]
    assert 10 <= len(offsets) <= 12  # those of the 100-frame window; older ones left with their states
    estimate = graph._estimates.vector(offsets[-1])
    np.testing.assert_allclose(estimate, [0.0, 5e-4, 2e-4], atol=2e-4)  # the offset, learned from the readings


def test_with_an_offset_state_a_rotation_sensor_still_mends_a_vo_that_reads_turns_long() -> None:
    """A VO reading each turn 10 % long (its gain term on) beside offset readings: the state learns the offset on
    the straights, and the turns are still mended."""
    truth = winding_trajectory(600, 0.02)
    rng = np.random.default_rng(5)
    vo = []
    for m in vo_stream(truth, rng, GOOD_VO):
        xi = se3_log(se3_inverse(truth[len(vo) + 1]) @ truth[len(vo)])
        xi[3:] *= 1.1
        vo.append(RelativeMeasurement(m.stamp, m.reference_stamp, se3_exp(xi), VO_COV))
    rotations = offset_rotations(truth, np.array([0.0, 5e-4, 2e-4]), 5e-4, 1e-3, rng)
    settings = {"inputs.rotation.gate_probability": 0.0, "inputs.vo.gain_sigma": (0.0, 0.1), **ROTATION_BIAS}
    vo_error = rotation_rms(compose(vo, np.eye(4)), truth)
    with_offset = rotation_rms(run_with_rotations(FusionGraph(from_flat(settings)), vo, rotations), truth)
    # measured: VO 0.338 rad, with the offset state 0.228 (independent readings 0.191: here the turns dominate)
    assert with_offset < 0.75 * vo_error, (vo_error, with_offset)


def test_rotation_offsets_marginals_from_the_bayes_tree_equal_the_dense_qr() -> None:
    truth = truth_trajectory(120)
    rng = np.random.default_rng(9)
    vo = drifting_vo(truth, 1e-4, rng)
    rotations = offset_rotations(truth, np.array([1e-4, 5e-4, 0.0]), 5e-4, 1e-3, rng)
    graph = FusionGraph(from_flat({**ROTATION_BIAS, "window.lag": 40.0, "solver.relinearize_threshold": 0.0}))
    for m, r in zip(vo, rotations, strict=True):
        graph.add_vo(m)
        graph.add_rotation(r)
    offsets = [key for key, _ in graph._rotation_bias]
    keys = [graph._keys[graph.newest_stamp], offsets[-1], offsets[0]]
    dense = graph._dense_joint_covariance(keys)
    assert dense.shape == (12, 12)
    # The Bayes tree holds the last linearisation, the dense QR the current estimate's: a rotation factor per frame
    # keeps them ~1e-4 apart (relative); a wrongly sized or ordered offset block would be off by its whole size.
    np.testing.assert_allclose(graph._joint_covariance(keys), dense, rtol=0.0, atol=1e-3 * np.abs(dense).max())


def test_rotation_bias_settings_are_checked() -> None:
    for values, words in (
        ({"inputs.rotation.bias_sigma": (0.1, 0.1)}, "inputs.rotation.bias_sigma needs 3 values"),
        ({"inputs.rotation.bias_sigma": (0.1, -0.1, 0.1)}, "inputs.rotation.bias_sigma needs 3 values >= 0"),
        ({"inputs.rotation.bias_sigma": (0.1, 0.1, 0.1)}, "all six > 0 for a bias state"),
        ({"inputs.rotation.bias_walk_sigma": (0.1,)}, "inputs.rotation.bias_walk_sigma needs 3 values"),
        ({"inputs.rotation.bias_interval": 0.0}, "inputs.rotation.bias_interval must be positive"),
    ):
        with pytest.raises(ValueError, match=words):
            from_flat(values)


def test_grossly_wrong_corrections_and_rotations_are_gated() -> None:
    truth = truth_trajectory(12)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    for m in vo:
        graph.add_vo(m)
    before = graph.pose().copy()
    t = se3_exp(np.array([0.0, 0.0, 2.0, 0.0, 0.2, 0.0])) @ se3_inverse(truth[11]) @ truth[6]
    wrong = RelativeMeasurement(T0 + 11 * STEP_NS, T0 + 6 * STEP_NS, t, VO_COV)
    assert graph.add_correction(wrong) == "gated"
    rot_cov = np.diag([9.0, 9.0, 9.0, 1e-6, 1e-6, 1e-6])
    assert graph.add_rotation(RelativeMeasurement(wrong.stamp, wrong.reference_stamp, t, rot_cov, True)) == "gated"
    np.testing.assert_array_equal(graph.pose(), before)
    right = RelativeMeasurement(wrong.stamp, wrong.reference_stamp, se3_inverse(truth[11]) @ truth[6], VO_COV)
    assert graph.add_correction(right) == "accepted"
    outside = RelativeMeasurement(right.stamp, T0 - STEP_NS * 50, right.transform, VO_COV)
    assert graph.add_correction(outside) == "dropped.reference_not_in_window"


def test_the_gate_s_rejections_in_a_row_are_counted_per_input_until_one_is_accepted() -> None:
    truth = truth_trajectory(14)
    vo = vo_stream(truth, None)  # frames 1..13
    graph = FusionGraph()
    for m in vo[:11]:
        graph.add_vo(m)
    t = se3_exp(np.array([0.0, 0.0, 2.0, 0.0, 0.2, 0.0])) @ se3_inverse(truth[11]) @ truth[6]
    wrong = RelativeMeasurement(T0 + 11 * STEP_NS, T0 + 6 * STEP_NS, t, VO_COV)
    for expected in range(1, 4):
        assert graph.add_correction(wrong) == "gated"
        assert graph.gated_in_a_row["correction"] == expected
    assert graph.gated_seconds("correction") == 0.0  # all three at one newest state
    rot_cov = np.diag([9.0, 9.0, 9.0, 1e-6, 1e-6, 1e-6])
    assert graph.add_rotation(RelativeMeasurement(wrong.stamp, wrong.reference_stamp, t, rot_cov, True)) == "gated"
    assert dict(graph.gated_in_a_row) == {"correction": 3, "rotation": 1}  # each input its own streak
    graph.add_vo(vo[11])
    graph.add_vo(vo[12])
    assert graph.gated_seconds("correction") == 0.0  # the sensor quiet: its streak does not grow with the VO alone
    assert graph.add_correction(wrong) == "gated"
    assert graph.gated_seconds("correction") == pytest.approx(2 * STEP_NS * 1e-9)  # first to latest rejection
    right = RelativeMeasurement(wrong.stamp, wrong.reference_stamp, se3_inverse(truth[11]) @ truth[6], VO_COV)
    assert graph.add_correction(right) == "accepted"
    assert dict(graph.gated_in_a_row) == {"rotation": 1}  # an accepted correction ends the corrections' streak only
    assert graph.gated_seconds("correction") == 0.0
    outside = RelativeMeasurement(right.stamp, T0 - STEP_NS * 50, right.transform, VO_COV)
    assert graph.add_rotation(outside) == "dropped.reference_not_in_window"
    assert graph.gated_in_a_row["rotation"] == 1  # a measurement dropped for another reason neither adds nor ends one


def test_relative_rotation_with_a_huge_covariance_is_skipped() -> None:
    truth = truth_trajectory(10)
    vo = vo_stream(truth, None)
    graph = FusionGraph()
    for m in vo:
        graph.add_vo(m)
    t = se3_inverse(truth[9]) @ truth[5]
    loose = RelativeMeasurement(T0 + 9 * STEP_NS, T0 + 5 * STEP_NS, t, np.eye(6) * 0.1, True)
    assert graph.add_rotation(loose) == "rejected.covariance_too_large"


def test_tabulated_reference_interpolates_and_refuses_far_outside() -> None:
    stamps = np.array([0, 1_000_000_000, 2_000_000_000])
    dirs = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    ref = TabulatedSunReference(stamps, dirs, slack_ns=100)
    np.testing.assert_allclose(ref.direction(500_000_000), np.array([1, 1, 0]) / np.sqrt(2))
    assert ref.direction(2_000_000_101) is None
    with pytest.raises(ValueError, match="increase"):
        TabulatedSunReference(stamps[::-1], dirs)


def test_config_round_trip_and_errors() -> None:
    config = FusionConfig()
    assert from_flat(flatten(config)) == config
    with pytest.raises(ValueError, match="unknown fusion parameter"):
        from_flat({"window.lagg": 3})
    with pytest.raises(ValueError, match="window.lag_unit"):
        from_flat({"window.lag_unit": "hours"})
    with pytest.raises(ValueError, match="inputs.vo.covariance_scale"):
        from_flat({"inputs.vo.covariance_scale": [1.0, 2.0]})
    with pytest.raises(ValueError, match="must be a boolean"):
        from_flat({"inputs.sun.enabled": "yes"})


def test_yaml_defaults_equal_the_typed_config() -> None:
    from pathlib import Path

    import yaml

    path = Path(__file__).resolve().parents[1] / "config" / "fusion.yaml"
    params = yaml.safe_load(path.read_text())["fusion"]["ros__parameters"]
    from pvo_fusion.fusion_node import FusionNodeConfig

    node_only = set(flatten(FusionNodeConfig()))
    assert from_flat({k: v for k, v in params.items() if k not in node_only}) == FusionConfig()
    assert set(params) - node_only == set(flatten(FusionConfig()))


def test_seconds_lag_keeps_the_window_by_time() -> None:
    truth = truth_trajectory(60)
    graph = FusionGraph(from_flat({"window.lag": 1.0, "window.lag_unit": "seconds"}))
    for m in vo_stream(truth, None):
        graph.add_vo(m)
    assert 10 <= graph.window_size <= 12


def test_vo_constant_velocity_gate_drops_a_jump_and_bridges_it() -> None:
    truth = truth_trajectory(20)
    vo = vo_stream(truth, None)
    graph = FusionGraph(from_flat({"inputs.vo.gate_probability": 0.9999}))
    for m in vo[:10]:
        assert graph.add_vo(m) == "accepted"
    jumped = se3_exp(np.array([3.0, 0, 0, 0, 0.5, 0])) @ vo[10].transform
    jump = RelativeMeasurement(vo[10].stamp, vo[10].reference_stamp, jumped, VO_COV)
    assert graph.add_vo(jump) == "gated"
    assert graph.add_vo(vo[11]) == "accepted"  # refers to the dropped frame: a bridged gap
    assert graph.counts["vo.gap"] == 1 and graph.counts["vo.gated"] == 1
    for m in vo[12:]:
        assert graph.add_vo(m) == "accepted"


def test_a_graph_resumed_from_a_checkpoint_continues_the_trajectory(tmp_path) -> None:
    """Issue 18: a fusion killed at frame 30 and restarted at frame 50 resumes from its checkpoint."""
    from pvo_fusion.checkpoint import FusionCheckpoint

    truth = truth_trajectory(80)
    vo = vo_stream(truth, None)
    first = FusionGraph()
    for m in vo[:30]:
        first.add_vo(m)
    path = tmp_path / "state.json"
    first.checkpoint().write(path)
    resumed = FusionGraph()
    resumed.resume(FusionCheckpoint.read(path))
    assert resumed.add_vo(vo[10]) == "rejected.before_checkpoint"  # older than the checkpoint
    for m in vo[50:]:
        assert resumed.add_vo(m) == "accepted"
    assert resumed.counts["vo.gap"] == 1
    np.testing.assert_allclose(resumed.pose()[:3, 3], truth[79][:3, 3], atol=5.0)
    steps = np.linalg.norm(np.diff([p.pose[:3, 3] for p in resumed.trajectory()], axis=0), axis=1)
    assert steps.max() < 25.0  # one bridged step of about 20 frames' travel, no jump back to the origin
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ValueError, match="fusion checkpoint .*bad.json"):
        FusionCheckpoint.read(bad)
