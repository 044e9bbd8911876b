"""Fuzzing every input of the fusion node over DDS: each bad message is rejected with its reason counted,
the node keeps running, and the estimate equals the clean run's (issue 18, defects 1 and 7)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from fuzzing import Variant, covariance_variants, pose_variants, set_stamp, wait_for
from nav_msgs.msg import Odometry
from pvo_core.lie import se3_exp, se3_inverse
from pvo_core.msgconv import fill_pose, pose_to_matrix
from pvo_fusion.fusion_node import FusionNode
from pvo_tools.testing import Spinner
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from pvo_fusion import FusionGraph, RelativeMeasurement
from pvo_fusion.config import from_flat
from pvo_msgs.msg import RelativePose, SunDirection

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
T0 = 1_317_640_000_000_000_000
DT = 100_000_000
STEP = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.01, 0.0])))  # T_k,k-1: 1 m forward, a little yaw
COV = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])


def relative(k_to: int, k_from: int, transform=STEP, covariance=COV, rotation_only: bool = False) -> RelativePose:
    msg = RelativePose()
    set_stamp(msg.header.stamp, T0 + k_to * DT)
    set_stamp(msg.reference_stamp, T0 + k_from * DT)
    msg.header.frame_id = "camera_left_optical"
    fill_pose(msg.pose.pose, transform)
    msg.pose.covariance = [float(v) for v in np.asarray(covariance).reshape(-1)]
    msg.rotation_only = rotation_only
    return msg


def stamp_variants() -> list[Variant]:
    """After frames 1..3: a duplicate, a time-reversed, a far-past, a far-future and a zero-interval message."""
    far_past = relative(0, 0)
    set_stamp(far_past.header.stamp, T0 - 1000 * 10**9)
    set_stamp(far_past.reference_stamp, T0 - 1001 * 10**9)
    far_future = relative(3, 3)
    set_stamp(far_future.header.stamp, T0 + 10**15)
    return [
        Variant("duplicate stamp", relative(3, 2), "rejected.duplicate_stamp"),
        Variant("reference after stamp", relative(4, 5), "rejected.time_reversed"),
        Variant("far-past stamp", far_past, "rejected.out_of_order"),
        Variant("far-future stamp", far_future, "rejected.interval_too_long"),
        Variant("zero interval", relative(4, 4), "rejected.zero_interval"),
        Variant(
            "1e12 m in one frame",
            relative(4, 3, transform=np.diag([1.0, 1.0, 1.0, 1.0]) + np.eye(4, k=3) * 1e12),
            "rejected.implausible_motion",
        ),
    ]


def sun_variants() -> list[Variant]:
    def sun(direction, covariance) -> SunDirection:
        msg = SunDirection()
        set_stamp(msg.header.stamp, T0 + 2 * DT)
        msg.direction.x, msg.direction.y, msg.direction.z = (float(v) for v in direction)
        msg.covariance = [float(v) for v in covariance]
        return msg

    good_cov = [1e-3, 0.0, 0.0, 1e-3]
    return [
        Variant("NaN sun", sun([np.nan, 0.0, 1.0], good_cov), "rejected.non_finite_direction"),
        Variant("non-unit sun", sun([0.0, 0.0, 3.0], good_cov), "rejected.direction_not_unit"),
        Variant("NaN sun covariance", sun([0.0, 0.0, 1.0], [np.nan] * 4), "rejected.covariance_not_positive_definite"),
        Variant("zero sun covariance", sun([0.0, 0.0, 1.0], [0.0] * 4), "rejected.covariance_not_positive_definite"),
    ]


OFFSET_STATE = {"inputs.sun.bias_sigma": [0.1, 0.1], "inputs.sun.bias_walk_sigma": [0.002, 0.002]}  # the learned sun's
ROTATION_OFFSET_STATE = {"inputs.rotation.bias_sigma": [1e-3] * 3, "inputs.rotation.bias_walk_sigma": [3e-5] * 3}


@pytest.mark.parametrize(
    "settings", [{}, OFFSET_STATE, ROTATION_OFFSET_STATE], ids=["independent", "sun-offset-state", "rotation-offset-state"]
)
def test_every_bad_input_is_counted_and_the_estimate_equals_the_clean_run(ros_context, settings: dict) -> None:
    overrides = [Parameter("publish_path", value=False)] + [Parameter(name, value=v) for name, v in settings.items()]
    fusion = FusionNode(context=ros_context, parameter_overrides=overrides)
    assert fusion.graph.config.inputs.sun.has_bias == (settings is OFFSET_STATE)
    assert fusion.graph.config.inputs.rotation.has_bias == (settings is ROTATION_OFFSET_STATE)
    io = Node("io", context=ros_context)
    odometry: list[Odometry] = []
    io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    publishers = {
        "vo": io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE),
        "correction": io.create_publisher(RelativePose, "/pvo/dpc/correction", RELIABLE),
        "rotation": io.create_publisher(RelativePose, "/pvo/hydranet/rotation", RELIABLE),
        "sun": io.create_publisher(SunDirection, "/pvo/sun/direction", RELIABLE),
    }
    cases: list[tuple[str, Variant]] = []
    cases += [("vo", v) for v in pose_variants(relative(4, 3), lambda m: m.pose.pose)]
    cases += [("vo", v) for v in covariance_variants(relative(4, 3), "pose.covariance", 6)]
    cases += [("vo", v) for v in stamp_variants()]
    for name, rotation_only in (("correction", False), ("rotation", True)):
        good = relative(3, 1, STEP @ STEP, COV, rotation_only)
        cases += [(name, v) for v in pose_variants(good, lambda m: m.pose.pose)]
        cases += [(name, v) for v in covariance_variants(good, "pose.covariance", 6)[:2]]
    cases += [("sun", v) for v in sun_variants()]
    expected: Counter[str] = Counter()
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            assert wait_for(lambda: all(p.get_subscription_count() > 0 for p in publishers.values()))
            assert wait_for(lambda: len(io.get_publishers_info_by_topic("/pvo/fusion/odometry")) > 0)
            for k in range(1, 4):
                publishers["vo"].publish(relative(k, k - 1))
            assert wait_for(lambda: len(odometry) >= 3)
            for name, variant in cases:
                expected[f"{name}.{variant.reason}"] += 1
                publishers[name].publish(variant.message)
                key = f"{name}.{variant.reason}"
                assert wait_for(lambda key=key: fusion.graph.counts[key] >= expected[key]), (
                    variant.name,
                    dict(fusion.graph.counts),
                )
            for k in range(4, 7):
                publishers["vo"].publish(relative(k, k - 1))
            assert wait_for(lambda: len(odometry) >= 6)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    for key, count in expected.items():
        assert fusion.graph.counts[key] == count, key
    assert fusion.graph.counts["vo.accepted"] == 6 and len(odometry) == 6
    clean = FusionGraph(from_flat(settings))
    for k in range(1, 7):
        clean.add_vo(RelativeMeasurement(T0 + k * DT, T0 + (k - 1) * DT, STEP, COV))
    np.testing.assert_allclose(pose_to_matrix(odometry[-1].pose.pose), clean.pose(), atol=1e-9)


def test_a_bad_ground_truth_pose_is_rejected_and_the_next_good_one_starts_the_graph(ros_context) -> None:
    overrides = [
        Parameter("prior.source", value="given"),
        Parameter("initial_pose_from_ground_truth", value=True),
        Parameter("publish_path", value=False),
    ]
    fusion = FusionNode(context=ros_context, parameter_overrides=overrides)
    io = Node("io", context=ros_context)
    odometry: list[Odometry] = []
    io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    gt_pub = io.create_publisher(Odometry, "/ground_truth/odometry", RELIABLE)
    vo_pub = io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    truth = Odometry()
    set_stamp(truth.header.stamp, T0)
    start = se3_exp(np.array([5.0, 0.0, 2.0, 0.0, 0.3, 0.0]))
    fill_pose(truth.pose.pose, start)
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            assert wait_for(lambda: gt_pub.get_subscription_count() > 0 and vo_pub.get_subscription_count() > 0)
            vo_pub.publish(relative(1, 0))
            for variant in pose_variants(truth, lambda m: m.pose.pose):
                gt_pub.publish(variant.message)
            assert wait_for(lambda: sum(v for k, v in fusion.graph.counts.items() if k.startswith("ground_truth.")) == 5)
            assert not odometry
            gt_pub.publish(truth)
            assert wait_for(lambda: len(odometry) == 1)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    assert fusion.graph.counts["ground_truth.rejected.non_finite_pose"] == 3
    assert fusion.graph.counts["ground_truth.rejected.zero_quaternion"] == 1
    assert fusion.graph.counts["ground_truth.rejected.quaternion_not_unit"] == 1
    np.testing.assert_allclose(pose_to_matrix(odometry[0].pose.pose), start @ np.linalg.inv(STEP), atol=1e-6)


def test_simulated_sun_rejects_bad_truth_and_its_clean_output_is_unchanged(ros_context) -> None:
    from pvo_pseudosensors.simulated_sun_node import SimulatedSunNode

    def truth(k: int, direction) -> SunDirection:
        msg = SunDirection()
        set_stamp(msg.header.stamp, T0 + k * DT)
        msg.direction.x, msg.direction.y, msg.direction.z = (float(v) for v in direction)
        return msg

    good = [0.0, -0.6, 0.8]
    bad = [[np.nan, 0.0, 1.0], [np.inf, 0.0, 0.0], [0.0, 0.0, 0.0]]
    runs = {}
    for label, inject in (("clean", False), ("fuzzed", True)):
        node = SimulatedSunNode(context=ros_context, parameter_overrides=[Parameter("every_n", value=1)])
        io = Node("io", context=ros_context)
        out: list[SunDirection] = []
        io.create_subscription(SunDirection, "/pvo/sun/direction", out.append, RELIABLE)
        pub = io.create_publisher(SunDirection, "/ground_truth/sun_direction", RELIABLE)
        try:
            with Spinner(ros_context, node, io):
                assert wait_for(lambda p=pub, n=node: p.get_subscription_count() > 0 and n.publisher.get_subscription_count() > 0)
                for k in range(5):
                    if inject and k == 2:
                        for direction in bad:
                            pub.publish(truth(k, direction))
                    pub.publish(truth(k, good))
                expected = 3 if inject else 0
                assert wait_for(lambda o=out, n=node, e=expected: len(o) == 5 and n.rejected == e)
        finally:
            node.destroy_node()
            io.destroy_node()
        runs[label] = [(m.direction.x, m.direction.y, m.direction.z) for m in out]
    # a rejected input consumes no noise draw: the measurements equal the clean run's
    assert runs["fuzzed"] == runs["clean"]
