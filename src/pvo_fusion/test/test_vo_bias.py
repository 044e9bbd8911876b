"""The VO's bias learned from pose corrections: recovered exactly where it is constant, causal, stopped by gaps, and
in the fusion graph a biased VO corrected every Δp frames stops drifting between the corrections."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.lie import se3_exp, se3_inverse, so3_exp, so3_log

from pvo_fusion import FusionGraph, RelativeMeasurement, VOBiasTracker, debiased_motions
from pvo_fusion.config import from_flat

STEP_NS = 100_000_000
T0 = 5_000_000_000
VO_COV = np.diag([4e-4, 4e-4, 1e-3, 4e-6, 4e-6, 4e-6])
#: the VO's per-frame error (ROS order, left): 3 % long on its 1 m forward step, a little sideways
BIAS = np.array([0.004, -0.002, 0.03, 0.0, 0.0, 0.0])


def straight_motions(n: int) -> np.ndarray:
    """True motions T_k,k-1 (n, 4, 4): 1 m forward along the camera's z axis per frame, no turn."""
    return np.array([se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))) for _ in range(n)])


def windows(n: int, delta: int) -> tuple[np.ndarray, np.ndarray]:
    first = np.arange(0, n - delta + 1, delta)
    return first, first + delta


def chained(motions: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """T_last,first (M, 4, 4) of motions T_k,k-1 (motions[k-1])."""
    out = []
    for a, b in zip(first, last, strict=True):
        chain = np.eye(4)
        for k in range(a + 1, b + 1):
            chain = motions[k - 1] @ chain
        out.append(chain)
    return np.array(out)


def test_a_constant_translation_bias_is_recovered_from_exact_corrections_and_removed_causally() -> None:
    truth = straight_motions(60)
    read = np.array([se3_exp(-BIAS) @ t for t in truth])  # the VO reads Exp(-b) T: Exp(b) undoes it
    first, last = windows(60, 3)
    tracker = VOBiasTracker(windows=10)
    np.testing.assert_allclose(tracker.debias(read[0]), read[0])  # nothing learned yet: the VO as read
    for k in range(1, 4):
        tracker.observe(k - 1, k, read[k - 1])
    assert tracker.update(0, 3, chained(truth, first, last)[0])
    np.testing.assert_allclose(tracker.bias, BIAS, atol=1e-12)  # the first correction: the plain mean of one
    np.testing.assert_allclose(tracker.debias(read[3]), truth[3], atol=1e-12)
    # offline: the first window as read (nothing learned before its correction), every later motion exact
    motions = debiased_motions(read, first, last, chained(truth, first, last), windows=10)
    np.testing.assert_allclose(motions[:3], read[:3], atol=1e-12)
    np.testing.assert_allclose(motions[3:], truth[3:], atol=1e-12)


def test_only_the_tracked_axes_learn_and_a_gap_or_lost_history_teaches_nothing() -> None:
    bias = np.array([0.0, 0.0, 0.03, 0.002, 0.0, 0.0])  # a translation and a rotation bias
    truth = straight_motions(6)
    read = np.array([se3_exp(-bias) @ t for t in truth])
    tracker = VOBiasTracker(windows=30)  # the translation only (the default)
    for k in (1, 2, 3):
        tracker.observe(k - 1, k, read[k - 1])
    assert tracker.update(0, 3, truth[2] @ truth[1] @ truth[0])
    assert tracker.bias[3:].tolist() == [0.0, 0.0, 0.0] and tracker.bias[2] == pytest.approx(0.03, abs=2e-4)
    # frame 4 never read (a gap): the correction over 3 -> 6 cannot be compared with the VO, so it teaches nothing
    before = tracker.bias
    tracker.observe(4, 5, read[4])
    tracker.observe(5, 6, read[5])
    assert not tracker.update(3, 6, truth[5] @ truth[4] @ truth[3])
    np.testing.assert_array_equal(tracker.bias, before)
    assert tracker.updates == 1
    short = VOBiasTracker(windows=30, history=2)  # the oldest motion forgotten
    for k in (1, 2, 3):
        short.observe(k - 1, k, read[k - 1])
    assert not short.update(0, 3, truth[2] @ truth[1] @ truth[0])


@pytest.mark.parametrize(
    ("windows", "axes", "scale", "message"),
    [
        (0.0, (1, 1, 1, 0, 0, 0), (0.0, 1.0), "needs a time constant > 0 for the bias or for a scale"),
        (-1.0, (1, 1, 1, 0, 0, 0), (0.0, 1.0), "time constant must be a number of corrections >= 0, got -1.0"),
        (float("nan"), (1, 1, 1, 0, 0, 0), (0.0, 1.0), "time constant must be a number of corrections >= 0"),
        (10.0, (1, 1, 1), (0.0, 1.0), "axes must be 6 weights of 0 or 1"),
        (10.0, (0.5, 1, 1, 0, 0, 0), (0.0, 1.0), "axes must be 6 weights of 0 or 1"),
        (10.0, (1, 1, 1, 0, 0, 0), (float("nan"), 1.0), "rotation scale's time constant must be a number of corrections"),
        (10.0, (1, 1, 1, 0, 0, 0), (100.0, 0.0), "rotation scale's gain must be in \\(0, 1\\], got 0.0"),
        (10.0, (1, 1, 1, 0, 0, 0), (100.0, 1.5), "rotation scale's gain must be in \\(0, 1\\], got 1.5"),
    ],
)
def test_bad_tracker_settings_are_named(windows: float, axes: tuple, scale: tuple, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        VOBiasTracker(windows, axes, rotation_scale_windows=scale[0], rotation_scale_gain=scale[1])


def turning_motions(n: int, seed: int = 3) -> np.ndarray:
    """True motions T_k,k-1 (n, 4, 4): 1 m forward per frame, turning left and right about the camera's y axis (up to
    ~2 deg per frame, a sine with its sign changing every ~40 frames), with a little pitch."""
    rng = np.random.default_rng(seed)
    yaw = np.radians(2.0) * np.sin(np.arange(n) * 2 * np.pi / 80.0)
    pitch = np.radians(0.05) * rng.normal(size=n)
    return np.array([se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, p, y, 0.0]))) for y, p in zip(yaw, pitch, strict=True)])


def read_turns_long(motions: np.ndarray, factor: float) -> np.ndarray:
    """The motions as a VO reads them whose every rotation vector is ``factor`` times too long (a lens error)."""
    out = motions.copy()
    for k, t in enumerate(motions):
        out[k, :3, :3] = so3_exp(factor * so3_log(t[:3, :3]))
    return out


def test_a_vo_that_reads_every_turn_8_percent_long_is_rescaled_by_the_corrections() -> None:
    """Turns of both signs: the additive bias learns nothing (its mean is zero), the rotation scale learns 1/1.08 - 1
    and the debiased VO's heading follows the truth; a gain of one half applies half the scale."""
    truth = turning_motions(240)
    read = read_turns_long(truth, 1.08)
    first, last = windows(240, 3)
    exact = chained(truth, first, last)
    tracker = VOBiasTracker(0.0, rotation_scale_windows=1000.0)
    assert not tracker.axes.any() and tracker.rotation_scale == 0.0
    for k in range(1, 241):
        tracker.observe(k - 1, k, read[k - 1])
        if k % 3 == 0:
            assert tracker.update(k - 3, k, exact[k // 3 - 1])
    # least squares of d ~ k phi with the small-angle log: exact to well under a per mille of the turn
    assert tracker.rotation_scale == pytest.approx(1.0 / 1.08 - 1.0, abs=2e-3)
    assert not tracker.bias.any()
    np.testing.assert_allclose(tracker.debias(read[100]), truth[100], atol=2e-5)
    motions = debiased_motions(read, first, last, exact, 0.0, rotation_scale_windows=1000.0)
    heading = {}  # the largest heading error along the drive (the turns' signs alternate: the end's cancels)
    for name, chain in (("read", read), ("debiased", motions)):
        estimated, true, worst = np.eye(4), np.eye(4), 0.0
        for t, u in zip(chain, truth, strict=True):
            estimated, true = estimated @ se3_inverse(t), true @ se3_inverse(u)
            worst = max(worst, float(np.linalg.norm(so3_log(estimated[:3, :3] @ true[:3, :3].T))))
        heading[name] = worst
    assert heading["read"] > np.radians(3.0)  # 8 % of a ~50 deg turn
    assert heading["debiased"] < 0.1 * heading["read"]
    halved = VOBiasTracker(0.0, rotation_scale_windows=1000.0, rotation_scale_gain=0.5)
    halved.restore(np.zeros(6), tracker.updates, tracker.scale_sums)
    assert halved.rotation_scale == pytest.approx(0.5 * tracker.rotation_scale, rel=1e-12)
    # straight driving teaches no scale: its turns are below the prior's ~1 deg
    straight = VOBiasTracker(0.0, rotation_scale_windows=1000.0)
    line = straight_motions(6)
    for k in range(1, 7):
        straight.observe(k - 1, k, line[k - 1])
    assert straight.update(0, 6, se3_exp(np.array([0, 0, 0, 0, 1e-4, 0])) @ chained(line, [0], [6])[0])
    assert straight.rotation_scale == 0.0


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("inputs.correction.vo_bias_windows", -1.0, "inputs.correction.vo_bias_windows must be >= 0"),
        ("inputs.correction.vo_bias_axes", [1.0, 1.0, 1.0], "inputs.correction.vo_bias_axes needs 6 values of 0 or 1"),
        ("inputs.correction.vo_bias_axes", [2.0, 0, 0, 0, 0, 0], "inputs.correction.vo_bias_axes needs 6 values of 0 or 1"),
        ("inputs.rotation.vo_bias_windows", float("inf"), "inputs.rotation.vo_bias_windows must be >= 0"),
        ("inputs.correction.vo_rotation_scale_windows", -5.0, "inputs.correction.vo_rotation_scale_windows must be >= 0"),
        ("inputs.correction.vo_rotation_scale_windows", float("nan"), "vo_rotation_scale_windows must be >= 0"),
        ("inputs.correction.vo_rotation_scale_gain", 0.0, "inputs.correction.vo_rotation_scale_gain must be in \\(0, 1\\]"),
        ("inputs.rotation.vo_bias_axes", [1.0, 0, 0, 1, 1, 1], "the first three \\(translation\\) 0: a rotation measures none"),
    ],
)
def test_bad_fusion_parameters_are_named(name: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        from_flat({name: value})
    both = {"inputs.correction.vo_bias_windows": 30.0, "inputs.rotation.vo_bias_windows": 100.0}
    FusionGraph(from_flat(both))  # translation from the corrections, rotation from the rotations: fine
    turns = {"inputs.correction.vo_rotation_scale_windows": 1000.0, "inputs.rotation.vo_rotation_scale_windows": 1000.0}
    with pytest.raises(ValueError, match="one input learns the scale of the VO's turns"):
        from_flat(turns)
    with pytest.raises(ValueError, match="inputs.rotation.vo_rotation_scale_gain must be in"):
        from_flat({"inputs.rotation.vo_rotation_scale_gain": 1.5})
    with pytest.raises(ValueError, match="vo_bias_axes overlap: one input learns each axis's VO bias"):
        from_flat(both | {"inputs.correction.vo_bias_axes": [1.0, 1.0, 1.0, 0.0, 1.0, 0.0]})


def fused_end_error(vo_bias_windows: float, rng: np.random.Generator, jitter_ns: int = 0) -> tuple[float, FusionGraph]:
    """The fused online end-position error (m) of a 300-frame drive whose VO reads 3 % long, corrected every 3 frames by
    corrections with 2 cm noise (and their covariance), stamped ``jitter_ns`` late (within the fusion's tolerance)."""
    n = 300
    truth_motions = straight_motions(n)
    vo_cov = np.diag([4e-4, 4e-4, 1e-3, 1e-8, 1e-8, 1e-8])  # turns read well: a heading walk would hide the translation
    chol = np.linalg.cholesky(vo_cov)
    read = np.array([se3_exp(chol @ rng.normal(size=6)) @ se3_exp(-BIAS) @ t for t in truth_motions])
    first, last = windows(n + 1, 3)
    correction_cov = np.diag([4e-4, 4e-4, 4e-4, 1e-8, 1e-8, 1e-8])
    corrected = [se3_exp(np.sqrt(np.diag(correction_cov)) * rng.normal(size=6)) @ t for t in chained(truth_motions, first, last)]
    graph = FusionGraph(from_flat({"inputs.correction.vo_bias_windows": vo_bias_windows}))
    ends = {int(b): (int(a), c) for a, b, c in zip(first, last, corrected, strict=True)}
    pose = np.eye(4)
    for k in range(1, n + 1):
        graph.add_vo(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, read[k - 1], vo_cov.copy()))
        if k in ends:
            a, c = ends[k]
            stamps = (T0 + k * STEP_NS + jitter_ns, T0 + a * STEP_NS + jitter_ns)
            graph.add_correction(RelativeMeasurement(*stamps, c, correction_cov.copy()))
        pose = graph.pose()
    true_end = np.eye(4)
    for t in truth_motions:
        true_end = true_end @ se3_inverse(t)
    return float(np.linalg.norm(pose[:3, 3] - true_end[:3, 3])), graph


def test_the_fusion_learns_the_vo_bias_from_the_corrections_and_stops_its_drift() -> None:
    plain, _ = fused_end_error(0.0, np.random.default_rng(7))
    learned, graph = fused_end_error(30.0, np.random.default_rng(7))
    # independent errors: the fusion keeps part of the VO's 3 cm per frame on every frame (a metre over 300 m); with
    # the bias learned only the corrections' noise is left
    assert plain > 0.8  # 1.10 m at this seed
    assert learned < 0.5 * plain  # 0.41 m: about the corrections' own 2 cm x sqrt(100 windows) per axis
    assert graph.counts["vo_bias.correction.learned"] == 100 and list(graph.vo_biases) == ["correction"]
    np.testing.assert_allclose(graph.vo_biases["correction"].bias[:3], BIAS[:3], atol=0.004)
    assert graph.vo_biases["correction"].bias[3:].tolist() == [0.0, 0.0, 0.0]
    # corrections stamped 0.5 ms off the VO's frames (the fusion's tolerance is 1 ms) teach the same
    jittered, graph = fused_end_error(30.0, np.random.default_rng(7), jitter_ns=500_000)
    assert graph.counts["vo_bias.correction.learned"] == 100 and jittered == pytest.approx(learned, abs=1e-9)


def test_relative_rotations_teach_the_vo_its_rotation_bias() -> None:
    """A VO whose yaw reads 0.05 deg per frame short on a turning drive; exact rotation-only readings every frame (as
    HydraNet's), their covariance ten times the VO's: fused as independent they take a tenth of the bias off; with the
    VO's rotation bias learned from them the heading stays."""
    n = 200
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.02, 0.0])))  # T_k,k-1: forward, turning about y
    bias = np.array([0.0, 0.0, 0.0, 0.0, np.radians(0.05), 0.0])
    read = se3_exp(-bias) @ step
    vo_cov = np.diag([4e-4, 4e-4, 1e-3, 1e-8, 1e-8, 1e-8])
    rotation_cov = np.diag([1e6, 1e6, 1e6, 1e-7, 1e-7, 1e-7])
    headings = {}
    for windows in (0.0, 20.0):
        graph = FusionGraph(from_flat({"inputs.rotation.vo_bias_windows": windows, "inputs.rotation.gate_probability": 0.0}))
        reading = np.eye(4)
        reading[:3, :3] = step[:3, :3]
        for k in range(1, n + 1):
            graph.add_vo(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, read, vo_cov.copy()))
            graph.add_rotation(
                RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, reading, rotation_cov.copy(), rotation_only=True)
            )
        true_end = np.linalg.matrix_power(se3_inverse(step), n)
        headings[windows] = float(np.linalg.norm(so3_log(graph.pose()[:3, :3] @ true_end[:3, :3].T)))
        if windows:
            assert graph.counts["vo_bias.rotation.learned"] == n
            np.testing.assert_allclose(graph.vo_biases["rotation"].bias, bias, atol=1e-6)
    assert headings[0.0] > np.radians(8.0)  # 0.05 deg x 200 frames, a tenth taken off
    assert headings[20.0] < 0.05 * headings[0.0]


def test_a_resumed_fusion_goes_on_from_the_vo_bias_it_had_learned(tmp_path) -> None:
    """The checkpoint carries each learned VO bias: a fusion restarted from it debiases its first VO motion as the
    one before did; a checkpoint from before stop 64 (no bias in it) resumes with nothing learned."""
    import json

    from pvo_fusion.checkpoint import FusionCheckpoint

    truth = straight_motions(12)
    read = np.array([se3_exp(-BIAS) @ t for t in truth])
    settings = {"inputs.correction.vo_bias_windows": 30.0}
    first = FusionGraph(from_flat(settings))
    for k in range(1, 7):
        first.add_vo(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, read[k - 1], VO_COV.copy()))
        if k % 3 == 0:
            exact = truth[k - 1] @ truth[k - 2] @ truth[k - 3]
            first.add_correction(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 3) * STEP_NS, exact, VO_COV.copy()))
    assert first.counts["vo_bias.correction.learned"] == 2
    path = tmp_path / "state.json"
    first.checkpoint().write(path)
    resumed = FusionGraph(from_flat(settings))
    resumed.resume(FusionCheckpoint.read(path))
    np.testing.assert_allclose(resumed.vo_biases["correction"].bias, BIAS, atol=1e-9)
    assert resumed.vo_biases["correction"].updates == 2
    np.testing.assert_allclose(resumed.vo_biases["correction"].debias(read[7]), truth[7], atol=1e-9)
    data = json.loads(path.read_text())
    del data["vo_bias"]
    path.write_text(json.dumps(data))
    older = FusionGraph(from_flat(settings))
    older.resume(FusionCheckpoint.read(path))
    assert older.vo_biases["correction"].updates == 0 and not older.vo_biases["correction"].bias.any()
    data["vo_bias"] = {"correction": {"bias": [float("nan")] * 6, "updates": 1}}
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="fusion checkpoint .*state.json: non-finite VO bias"):
        FusionCheckpoint.read(path)


def test_the_fusion_rescales_the_vo_turns_and_a_resumed_graph_goes_on_from_the_scale(tmp_path) -> None:
    """A VO reading every turn 8 % long, fused with exact corrections every 3 frames at a covariance near the VO's:
    fused as read, the heading error keeps part of the VO's; with the rotation scale learned (time constant 1000, as
    the DPC-Net cards use) it nearly vanishes. The checkpoint carries the scale's sums to a restarted graph."""
    from pvo_fusion.checkpoint import FusionCheckpoint

    n = 240
    truth = turning_motions(n)
    read = read_turns_long(truth, 1.08)
    vo_cov = np.diag([4e-4, 4e-4, 1e-3, 1e-6, 1e-6, 1e-6])
    correction_cov = np.diag([4e-4, 4e-4, 4e-4, 3e-6, 3e-6, 3e-6])
    first, last = windows(n + 1, 3)
    exact = chained(truth, first, last)
    worst = {}
    for settings in ({}, {"inputs.correction.vo_rotation_scale_windows": 1000.0}):
        graph = FusionGraph(from_flat(settings))
        true = np.eye(4)
        worst[bool(settings)] = 0.0
        for k in range(1, n + 1):
            graph.add_vo(RelativeMeasurement(T0 + k * STEP_NS, T0 + (k - 1) * STEP_NS, read[k - 1], vo_cov.copy()))
            if k % 3 == 0:
                j = k // 3 - 1
                graph.add_correction(
                    RelativeMeasurement(T0 + k * STEP_NS, T0 + first[j] * STEP_NS, exact[j], correction_cov.copy())
                )
            true = true @ se3_inverse(truth[k - 1])
            heading = so3_log(graph.pose()[:3, :3] @ true[:3, :3].T)
            worst[bool(settings)] = max(worst[bool(settings)], float(np.linalg.norm(heading)))
    assert worst[False] > np.radians(0.5)
    assert worst[True] < 0.5 * worst[False]
    tracker = graph.vo_biases["correction"]
    assert not tracker.bias.any() and tracker.rotation_scale == pytest.approx(1.0 / 1.08 - 1.0, abs=3e-3)
    path = tmp_path / "state.json"
    graph.checkpoint().write(path)
    resumed = FusionGraph(from_flat({"inputs.correction.vo_rotation_scale_windows": 1000.0}))
    resumed.resume(FusionCheckpoint.read(path))
    assert resumed.vo_biases["correction"].rotation_scale == pytest.approx(tracker.rotation_scale, rel=1e-12)


def test_a_vo_that_reads_every_step_3_percent_long_is_rescaled_by_the_corrections() -> None:
    """A focal length 3 % long: each step read 1.03 times as long, turning or not. The translation scale learned from
    exact corrections is 1/1.03 - 1 (within the metre of prior over ~80 windows of 3 m), every later step is the
    truth's, and a restored tracker goes on from the same sums."""
    truth = turning_motions(240)
    read = truth.copy()
    read[:, :3, 3] *= 1.03
    first, last = windows(240, 3)
    exact = chained(truth, first, last)
    tracker = VOBiasTracker(0.0, translation_scale_windows=100.0)
    for k in range(1, 241):
        tracker.observe(k - 1, k, read[k - 1])
        if k % 3 == 0:
            assert tracker.update(k - 3, k, exact[k // 3 - 1])
    assert tracker.translation_scale == pytest.approx(1.0 / 1.03 - 1.0, rel=2e-3)
    assert tracker.rotation_scale == 0.0 and not tracker.bias.any()
    np.testing.assert_allclose(tracker.debias(read[100]), truth[100], atol=1e-4)  # the prior: 6e-5 m short
    motions = debiased_motions(read, first, last, exact, 0.0, translation_scale_windows=100.0)
    np.testing.assert_allclose(motions[:3], read[:3])  # nothing learned before the first correction
    np.testing.assert_allclose(motions[60:, :3, 3], truth[60:, :3, 3], atol=3e-4)  # 0.3 mm of 1 m, the prior
    restored = VOBiasTracker(0.0, translation_scale_windows=100.0)
    restored.restore(np.zeros(6), tracker.updates, tracker.scale_sums)
    assert restored.translation_scale == pytest.approx(tracker.translation_scale, rel=1e-12)
    with pytest.raises(ValueError, match="VO scale sums to restore must be 4 finite numbers"):
        restored.restore(np.zeros(6), 1, [0.0, 1.0, 0.0, -1.0])
    with pytest.raises(ValueError, match="translation scale's time constant must be a number of corrections >= 0"):
        VOBiasTracker(0.0, translation_scale_windows=float("nan"))
