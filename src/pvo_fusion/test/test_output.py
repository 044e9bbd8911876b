"""The published pose stays continuous: a correction beyond the bound is spread over frames, the rest is in the
covariance; within the bound (or switched off) the estimate is published exactly."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.lie import se3_adjoint, se3_exp, se3_inverse, se3_log
from pvo_fusion.output import ContinuousOutput

from pvo_fusion import FusionConfig, FusionGraph, RelativeMeasurement
from pvo_fusion.config import from_flat

SIGMA = np.array([1.0, 1.0, 2.0, 0.05, 0.1, 0.05])
STEP_NS = 100_000_000  # 10 Hz


def forward(k: int) -> np.ndarray:
    """T_map,cam of a camera driving 1 m per frame along its z axis."""
    return se3_exp([0.0, 0.0, float(k), 0.0, 0.0, 0.0])


def test_a_correction_within_the_bound_is_published_exactly() -> None:
    output = ContinuousOutput(2.5, SIGMA)
    first = output.publish(0, forward(0), None)
    np.testing.assert_array_equal(first.pose, forward(0))
    corrected = forward(1) @ se3_exp([0.05, 0.0, 0.1, 0.0, 0.004, 0.0])  # 0.5 sigma per frame, well within 2.5
    out = output.publish(STEP_NS, corrected, forward(0))
    np.testing.assert_array_equal(out.pose, corrected)
    np.testing.assert_array_equal(out.outstanding, np.zeros(6))
    covariance = np.diag(np.arange(1.0, 7.0))
    np.testing.assert_array_equal(out.covariance(covariance), covariance)


def test_a_large_correction_is_spread_over_frames_within_the_bound_and_stated_in_the_covariance() -> None:
    output = ContinuousOutput(2.5, SIGMA)
    output.publish(0, forward(0), None)
    # the smoother moves its newest state 2 m sideways and turns it 0.2 rad at once (a sun fix after a gap)
    jump = se3_exp([2.0, 0.0, 0.0, 0.0, 0.2, 0.0])
    bound = 2.5 * 0.1  # motion-model sigmas over one frame interval
    published = [forward(0)]
    caught_up = None
    for k in range(1, 40):
        estimate = jump @ forward(k)  # the smoother's estimates all moved, its motion is still 1 m forward
        previous = jump @ forward(k - 1)
        out = output.publish(k * STEP_NS, estimate, previous)
        predicted = published[-1] @ se3_inverse(previous) @ estimate
        step = se3_log(se3_inverse(predicted) @ out.pose)
        units = max(np.linalg.norm(step[:3]) / np.linalg.norm(SIGMA[:3]), np.linalg.norm(step[3:]) / np.linalg.norm(SIGMA[3:]))
        assert units <= bound + 1e-12  # never more than the bound beyond the smoother's motion
        if caught_up is None and np.array_equal(out.pose, estimate):
            caught_up = k
        if caught_up is None:
            assert units == pytest.approx(bound)  # still behind: the whole bound is used
        published.append(out.pose)
        expected_left = se3_adjoint(out.pose) @ out.outstanding
        np.testing.assert_allclose(out.covariance(np.zeros((6, 6))), np.outer(expected_left, expected_left), atol=1e-15)
        np.testing.assert_allclose(out.pose @ se3_exp(out.outstanding), estimate, atol=1e-9)
    # 0.2 rad at 0.25 x 0.122 rad per frame takes 7 frames; the ~3.6 m body-frame shift at 0.61 m per frame too
    assert caught_up is not None and 6 <= caught_up < 39
    for k in range(caught_up, 40):
        np.testing.assert_array_equal(published[k], jump @ forward(k))


def test_switched_off_or_without_the_previous_state_the_estimate_is_published() -> None:
    jump = se3_exp([5.0, 0.0, 0.0, 0.0, 0.5, 0.0])
    off = ContinuousOutput(0.0, SIGMA)
    off.publish(0, forward(0), None)
    np.testing.assert_array_equal(off.publish(STEP_NS, jump @ forward(1), forward(0)).pose, jump @ forward(1))
    on = ContinuousOutput(2.5, SIGMA)
    on.publish(0, forward(0), None)
    np.testing.assert_array_equal(on.publish(STEP_NS, jump @ forward(1), None).pose, jump @ forward(1))


def test_graph_newest_state_published_through_the_output_and_the_config_knob() -> None:
    config = FusionConfig()
    assert config.output.max_correction_sigma == 2.5
    with pytest.raises(ValueError, match="output.max_correction_sigma"):
        from_flat({"output.max_correction_sigma": -1.0})
    graph = FusionGraph(config)
    graph.set_initial_pose(np.eye(4))
    output = ContinuousOutput.from_config(config)
    motion = se3_exp([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])  # T_k,k-1 of 1 m forward
    for k in range(1, 6):
        graph.add_vo(RelativeMeasurement(k * STEP_NS, (k - 1) * STEP_NS, motion, np.eye(6) * 1e-4))
        out = output.publish_newest(graph)
        np.testing.assert_allclose(out.pose, graph.pose())  # no correction: the estimate itself
    assert output.stamp == 5 * STEP_NS
