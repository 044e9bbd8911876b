"""The offline runner and the VO covariance calibration on the real viso2-s data (fusion-solver regressions)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.readers import read_kitti_sun_sequence
from pvo_fusion.calibration import span_errors
from pvo_fusion.sun_reference import TabulatedSunReference

from pvo_fusion import (
    CalibrationSequence,
    FusionGraph,
    SunMeasurement,
    calibrate_vo,
    ordered_events,
    run_offline,
    sun_events,
    vo_measurements,
)
from pvo_fusion.config import from_flat


def _calibration_input(seq, covariances=None) -> CalibrationSequence:
    covs = seq.covariances if covariances is None else covariances
    return CalibrationSequence(seq.name, seq.ground_truth, seq.motions, covs)


def test_calibration_makes_the_training_vo_consistent(pvo_data: Path) -> None:
    train = [read_kitti_sun_sequence(pvo_data, n) for n in ("05", "06", "07")]
    calibration = calibrate_vo((_calibration_input(s) for s in train), span=10)
    assert calibration.trained_on == ("05", "06", "07")
    assert np.all(calibration.scale > 1.0)  # viso2-s is overconfident on every dof
    ratios = []
    for seq in train:
        covs = seq.covariances * np.outer(np.sqrt(calibration.scale), np.sqrt(calibration.scale))
        errors, propagated = span_errors(_calibration_input(seq, covs), 10)
        ratios.append(errors**2 / np.diagonal(propagated, axis1=1, axis2=2))
    # exact per dof up to the mixing of scaled rotation variance into translation through the adjoint
    np.testing.assert_allclose(np.concatenate(ratios).mean(axis=0), 1.0, rtol=0.15)
    # one-frame errors are dominated by ground-truth noise: the scale learned over them differs
    one = calibrate_vo((_calibration_input(s) for s in train), span=1)
    assert not np.allclose(one.scale, calibration.scale, rtol=0.2)
    with pytest.raises(ValueError, match="at least one training sequence with covariances"):
        calibrate_vo([_calibration_input(read_kitti_sun_sequence(pvo_data, "04"))], span=10)


def _graph(seq) -> FusionGraph:
    config = from_flat({"prior.source": "given", "inputs.sun.reference": "table"})
    graph = FusionGraph(config, TabulatedSunReference(seq.stamps, seq.sun_map()))
    graph.set_initial_pose(seq.ground_truth[0])
    return graph


def test_whole_sequence_00_without_sun_reproduces_the_vo_and_never_goes_indeterminate(pvo_data: Path) -> None:
    seq = read_kitti_sun_sequence(pvo_data, "00")
    calibration = calibrate_vo([_calibration_input(read_kitti_sun_sequence(pvo_data, "05"))], span=10)
    vo = vo_measurements(seq.stamps, seq.motions, seq.covariances, calibration)
    result = run_offline(_graph(seq), seq.stamps, ordered_events(vo))
    assert len(result.poses) == 4541 and np.all(np.isfinite(result.poses))
    composed = [seq.ground_truth[0]]
    for m in vo:
        composed.append(composed[-1] @ np.linalg.inv(m.transform))
    composed = np.array(composed)
    # Exact to round-off over 3.7 km (measured 7.3e-11 m, 1.3e-15 rad): the loader projects the file's
    # rotations onto SO(3), so a general inverse and GTSAM's transpose compose the same trajectory.
    np.testing.assert_allclose(result.poses[:, :3, :3], composed[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(result.poses[:, :3, 3], composed[:, :3, 3], atol=1e-9)
    assert result.counts.get("solver.failure", 0) == 0
    np.testing.assert_allclose(result.online_poses[-1], result.poses[-1], atol=1e-9)


def test_cholesky_breaks_down_on_a_long_chain_and_the_graph_survives(pvo_data: Path) -> None:
    seq = read_kitti_sun_sequence(pvo_data, "05")
    vo = vo_measurements(seq.stamps, seq.motions, seq.covariances, None)[:1900]
    graph = FusionGraph(from_flat({"solver.smoother": "batch", "solver.linear_solver": "cholesky"}))
    for m in vo:
        graph.add_vo(m)
        graph.drain_finished()
    assert graph.counts["solver.failure"] >= 1  # GTSAM's IndeterminateSystemException near frame 1726
    assert "Indeterminate" in graph.last_rejection or "solver" in graph.last_rejection
    assert np.all(np.isfinite(graph.pose()))
    assert np.max(np.diag(graph.covariance())) > 100.0  # reported as a lost state


def test_events_come_in_arrival_order_and_the_result_does_not_depend_on_a_frames_sun_arriving_first(
    pvo_data: Path,
) -> None:
    seq = read_kitti_sun_sequence(pvo_data, "06").clipped(60)
    calibration = calibrate_vo([_calibration_input(read_kitti_sun_sequence(pvo_data, "07"))], span=10)
    vo = vo_measurements(seq.stamps, seq.motions, seq.covariances, calibration)
    cov = np.diag(np.radians([5.0, 5.0]) ** 2)
    sun = [SunMeasurement(int(seq.stamps[k]), seq.sun_camera[k], cov) for k in range(0, 60, 10)]
    events = ordered_events(vo, sun_events(sun))
    assert [kind for kind, _ in events[:4]] == ["sun", "vo", "vo", "vo"]
    assert sum(kind == "sun" for kind, _ in events) == 6
    vo_after = run_offline(_graph(seq), seq.stamps, events)
    # the node may take a frame's sun before its VO: it is buffered and attached right after the VO update
    sun_first = []
    for kind, m in events:
        if kind == "sun" and sun_first and sun_first[-1][0] == "vo" and sun_first[-1][1].stamp == m.stamp:
            sun_first.insert(len(sun_first) - 1, (kind, m))
        else:
            sun_first.append((kind, m))
    assert sun_first != events
    buffered = run_offline(_graph(seq), seq.stamps, sun_first)
    np.testing.assert_allclose(buffered.poses, vo_after.poses, atol=1e-12)
    assert buffered.counts["sun.accepted"] == 6


def test_the_default_plausibility_bound_rejects_the_baselines_failures_on_01(pvo_data: Path) -> None:
    """viso2-s fails on six frames of the 01 highway (up to 358 m/s); nothing else in 00-10 comes near 100 m/s."""
    seq = read_kitti_sun_sequence(pvo_data, "01")
    calibration = calibrate_vo([_calibration_input(read_kitti_sun_sequence(pvo_data, "05"))], span=10)
    vo = vo_measurements(seq.stamps, seq.motions, seq.covariances, calibration)
    graph = FusionGraph(from_flat({}))
    result = run_offline(graph, seq.stamps, ordered_events(vo))
    assert result.counts["vo.rejected.implausible_motion"] == 6
    assert result.counts["vo.gap"] == 6  # each next frame bridges from the newest state
    assert np.isnan(result.poses[:, 0, 3]).sum() == 6  # no state where the motion was impossible


def test_ephemeris_in_a_map_frame_found_from_the_gps_track() -> None:
    from pvo_core.ephemeris import GeodeticOrigin, enu_to_geodetic, sun_direction_enu
    from pvo_core.lie import so3_exp
    from pvo_fusion.sun_reference import TabulatedSunReference

    origin = GeodeticOrigin(75.4, -89.8, 30.0)
    angle = np.linspace(0, 1.5 * np.pi, 40)
    enu = np.column_stack([30 * np.sin(angle), 30 * (1 - np.cos(angle)), 0.1 * angle])  # a curve, not a line
    fixes = enu_to_geodetic(origin, enu)
    c_map_enu = so3_exp(np.array([0.3, -1.2, 2.0]))
    map_positions = enu @ c_map_enu.T + np.array([5.0, -2.0, 1.0])
    stamps = (1_215_874_800 + np.arange(5) * 60) * 1_000_000_000
    table, rotation = TabulatedSunReference.from_ephemeris_in_map(stamps, fixes, map_positions)
    np.testing.assert_allclose(rotation, c_map_enu, atol=1e-6)
    expected = sun_direction_enu(origin, stamps * 1e-9) @ c_map_enu.T
    np.testing.assert_allclose(table.directions, expected, atol=1e-6)
    with pytest.raises(ValueError, match="straight line"):
        line = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
        TabulatedSunReference.from_ephemeris_in_map(stamps, enu_to_geodetic(origin, line), line)


def test_kinds_named_before_come_ahead_of_the_vo_of_their_frame() -> None:
    from pvo_fusion import RelativeMeasurement

    def relative(stamp: int, rotation_only: bool = False) -> RelativeMeasurement:
        return RelativeMeasurement(stamp, stamp - 1, np.eye(4), np.eye(6), rotation_only)

    vo = [relative(s) for s in (1, 2, 3)]
    sun = SunMeasurement(2, np.array([0.0, 0.0, 1.0]), np.eye(2))
    rotations = [("rotation", relative(s, True)) for s in (1, 2, 3, 4)]
    events = ordered_events(vo, [("sun", sun), *rotations], before={"rotation"})
    assert [(kind, int(m.stamp)) for kind, m in events] == [
        ("rotation", 1),
        ("vo", 1),
        ("rotation", 2),
        ("vo", 2),
        ("sun", 2),
        ("rotation", 3),
        ("vo", 3),
        ("rotation", 4),
    ]
    default = ordered_events(vo, rotations[:2])
    assert [(kind, int(m.stamp)) for kind, m in default] == [("vo", 1), ("rotation", 1), ("vo", 2), ("rotation", 2), ("vo", 3)]


def test_the_offline_result_keeps_each_input_s_longest_run_of_gated_readings() -> None:
    from pvo_core.lie import se3_exp, se3_inverse

    from pvo_fusion import RelativeMeasurement

    step_ns, t0 = 100_000_000, 1_000_000_000
    stamps = t0 + step_ns * np.arange(30, dtype=np.int64)
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))  # T_k,k-1
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    vo = [RelativeMeasurement(int(stamps[k]), int(stamps[k - 1]), step, cov) for k in range(1, 30)]
    right, wrong = step @ step, se3_exp(np.array([0.0, 0.0, 2.0, 0.0, 0.2, 0.0])) @ step @ step

    def correction(k: int, transform: np.ndarray) -> tuple[str, RelativeMeasurement]:
        return "correction", RelativeMeasurement(int(stamps[k]), int(stamps[k - 2]), transform, cov)

    # gated at frames 4, 6, 8 (a run over 0.4 s), accepted at 10, gated at 12 .. 20 (0.8 s), accepted at 22
    corrections = [correction(k, wrong) for k in (4, 6, 8)] + [correction(10, right)]
    corrections += [correction(k, wrong) for k in range(12, 21, 2)] + [correction(22, right)]
    result = run_offline(_started(), stamps, ordered_events(vo, corrections))
    assert result.counts["correction.gated"] == 8 and result.counts["correction.accepted"] == 2
    assert result.gated_for_s == {"correction": pytest.approx(0.8)}
    clean = run_offline(_started(), stamps, ordered_events(vo, [correction(k, right) for k in range(4, 23, 2)]))
    assert clean.gated_for_s == {}
    # readings that come ahead of the VO of their frame wait for its state and are gated only when it comes
    rotations = [("rotation", RelativeMeasurement(m.stamp, m.reference_stamp, wrong, cov, True)) for _, m in corrections]
    early = run_offline(_started(), stamps, ordered_events(vo, rotations, before=("rotation",)))
    assert early.counts["rotation.gated"] == 10
    assert early.gated_for_s == {"rotation": pytest.approx(1.8)}  # frames 4 to 22, never one accepted


def _started() -> FusionGraph:
    graph = FusionGraph(from_flat({}))
    graph.set_initial_pose(np.eye(4))
    return graph
