"""The sun experiment's parts on the real viso2-s data: loading, calibration, ARMSE, whole-sequence exactness."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pvo_tools.sun_experiment import (
    SEQUENCE_DRIVES,
    armse,
    calibrate_vo,
    crmse,
    experiment_config,
    load_sun_sequence,
    ordered_events,
    run_fusion,
    span_errors,
    sun_measurements,
    sun_seed,
    vo_measurements,
)

from pvo_fusion import FusionGraph
from pvo_fusion.config import from_flat


def test_armse_is_the_mean_of_the_cumulative_rmse() -> None:
    errors = np.array([1.0, 2.0, 3.0, 4.0])
    expected_curve = [1.0, np.sqrt(2.5), np.sqrt(14 / 3), np.sqrt(7.5)]
    np.testing.assert_allclose(crmse(errors), expected_curve)
    gt = np.repeat(np.eye(4)[None], 4, axis=0)
    est = gt.copy()
    est[:, 0, 3] = errors  # east error only
    est[:, 2, 3] = 1.0  # and 1 m up, invisible in the EN plane
    metrics = armse(gt, est)
    assert metrics["trans_en"] == pytest.approx(np.mean(expected_curve))
    assert metrics["trans"] == pytest.approx(np.mean(crmse(np.sqrt(errors**2 + 1.0))))
    assert metrics["rot"] == 0.0


def test_sequences_load_and_sun_vectors_agree_with_the_ground_truth(pvo_data: Path) -> None:
    seq = load_sun_sequence(pvo_data, "04")
    assert seq.covariances is None and len(seq.stamps) == 271
    seq = load_sun_sequence(pvo_data, "07")
    assert seq.covariances is not None and seq.covariances.shape == (len(seq.stamps) - 1, 6, 6)
    # The map-frame sun direction from ground truth barely moves over the drive: the camera-frame
    # vectors and the poses are in the same frame.
    s_map = seq.sun_map()
    spread = np.degrees(np.arccos(np.clip(s_map @ s_map[0], -1.0, 1.0)))
    assert spread.max() < 2.0
    with pytest.raises(ValueError, match="not one of"):
        load_sun_sequence(pvo_data, "03")


def test_calibration_makes_the_training_vo_consistent(pvo_data: Path) -> None:
    train = [load_sun_sequence(pvo_data, n) for n in ("05", "06", "07")]
    calibration = calibrate_vo(train)
    assert calibration.trained_on == ("05", "06", "07")
    assert np.all(calibration.scale > 1.0)  # viso2-s is overconfident on every dof
    ratios = []
    for seq in train:
        covs = seq.covariances * np.outer(np.sqrt(calibration.scale), np.sqrt(calibration.scale))
        errors, propagated = span_errors(seq, 10, covs)
        ratios.append(errors**2 / np.diagonal(propagated, axis1=1, axis2=2))
    # exact per dof up to the mixing of scaled rotation variance into translation through the adjoint
    np.testing.assert_allclose(np.concatenate(ratios).mean(axis=0), 1.0, rtol=0.15)
    # one-frame errors are dominated by ground-truth noise: the scale learned over them differs
    one = calibrate_vo(train, span=1)
    assert not np.allclose(one.scale, calibration.scale, rtol=0.2)


def test_whole_sequence_00_without_sun_reproduces_the_vo_and_never_goes_indeterminate(pvo_data: Path) -> None:
    seq = load_sun_sequence(pvo_data, "00")
    vo = vo_measurements(seq, calibrate_vo([load_sun_sequence(pvo_data, "05")]))
    result = run_fusion(seq, vo, None, experiment_config())
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


def test_cholesky_breaks_down_on_a_long_chain_and_the_graph_survives(pvo_data: Path) -> None:
    seq = load_sun_sequence(pvo_data, "05")
    vo = vo_measurements(seq, None)[:1900]
    graph = FusionGraph(from_flat({"solver.smoother": "batch", "solver.linear_solver": "cholesky"}))
    for m in vo:
        graph.add_vo(m)
        graph.drain_finished()
    assert graph.counts["solver.failure"] >= 1  # GTSAM's IndeterminateSystemException near frame 1726
    assert "Indeterminate" in graph.last_rejection or "solver" in graph.last_rejection
    assert np.all(np.isfinite(graph.pose()))
    assert np.max(np.diag(graph.covariance())) > 100.0  # reported as a lost state


def test_simulated_sun_every_tenth_frame_in_arrival_order(pvo_data: Path) -> None:
    seq = load_sun_sequence(pvo_data, "04")
    sun = sun_measurements(seq, 10.0, sun_seed(0, "04", 10.0))
    assert [int((m.stamp - seq.stamps[0]) // 100_000_000) for m in sun] == list(range(0, 271, 10))
    vo = vo_measurements(seq, calibrate_vo([load_sun_sequence(pvo_data, "06")]))
    events = ordered_events(vo, sun)
    assert events[0][0] == "sun" and events[1][0] == "vo" and events[2][0] == "vo"
    assert sum(kind == "sun" for kind, _ in events) == 28
    again = sun_measurements(seq, 10.0, sun_seed(0, "04", 10.0))
    assert all(np.array_equal(a.direction, b.direction) for a, b in zip(sun, again, strict=True))


def test_cli_runs_one_sequence_and_writes_results(pvo_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "sun"
    command = ["pvo", "experiment", "sun-sim", "--data", str(pvo_data), "--sequences", "04", "--levels", "0", "30"]
    result = subprocess.run(
        [*command, "-q", "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "Trans. ARMSE (EN-plane) [m]" in result.stdout and "GT-Sun-30" in result.stdout
    assert "ARMSE = mean over frames k of CRMSE(k)" in result.stdout
    payload = json.loads((out / "results.json").read_text())
    rows = payload["sequences"][0]["rows"]
    assert set(rows) == {"Without Sun", "GT-Sun-0", "GT-Sun-30"}
    assert rows["GT-Sun-0"]["rot"] < rows["Without Sun"]["rot"]
    assert 0.0 < rows["Without Sun"]["anees"]
    assert (out / "report.md").is_file()
    bad = subprocess.run(["pvo", "experiment", "sun-sim", "--data", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "has no kitti/ folder" in bad.stderr


def test_all_sequences_are_mapped() -> None:
    assert list(SEQUENCE_DRIVES) == ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"]
