"""The dpc_net node over DDS: stereo images and VO transforms in, a correction of every Δp-frame window out,
exactly what the ROS-free sensor computes; a broken VO chain starts a new window; a bad stereo pair and a
missing model are reported and the node keeps running."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pvo_core.lie import se3_exp
from pvo_core.msgconv import fill_pose, fill_stamp, pose_to_matrix
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from test_sun_bcnn_graph import image_message

from pvo_msgs.msg import RelativePose

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
STEP = 100_000_000


@pytest.fixture()
def tiny_model(tmp_path: Path) -> Path:
    import torch
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.model import DPCNet, DPCTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    config = DPCNetConfig(height=32, width=104, stem=(4, 4, 8), body=(8, 16), test_delta=3)
    torch.manual_seed(0)
    network = DPCNet(config)
    with torch.no_grad():
        network.head.weight.normal_(0.0, 0.01)  # a non-zero correction, so the test sees it applied
    return save_model(tmp_path / "model", network, DPCTask(config, np.diag([0.01] * 3 + [0.001] * 3)).card())


def vo_message(stamp: int, reference: int, transform: np.ndarray) -> RelativePose:
    msg = RelativePose()
    fill_stamp(msg.header.stamp, stamp)
    fill_stamp(msg.reference_stamp, reference)
    msg.header.frame_id = "camera_left_optical"
    fill_pose(msg.pose.pose, transform)
    msg.pose.covariance = [float(v) for v in np.eye(6).reshape(-1) * 1e-4]
    return msg


def run_graph(ros_context, parameters: dict, script) -> tuple[list[RelativePose], list[DiagnosticArray]]:
    from pvo_pseudosensors.dpc_net_node import DPCNetNode

    node = DPCNetNode(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in parameters.items()])
    source = Node("source", context=ros_context)
    left = source.create_publisher(Image, "/stereo/left/image_rect", RELIABLE)
    right = source.create_publisher(Image, "/stereo/right/image_rect", RELIABLE)
    vo = source.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    received: list[RelativePose] = []
    statuses: list[DiagnosticArray] = []
    source.create_subscription(RelativePose, "/pvo/dpc/correction", received.append, RELIABLE)
    source.create_subscription(DiagnosticArray, "/pvo/dpc_net/status", statuses.append, RELIABLE)
    try:
        with Spinner(ros_context, node), Spinner(ros_context, source):
            wait_for(lambda: vo.get_subscription_count() > 0 and right.get_subscription_count() > 0, 10)
            wait_for(lambda: node.publisher.get_subscription_count() > 0, 10)
            script(left, right, vo, received, statuses, node)
    finally:
        node.destroy_node()
        source.destroy_node()
    return received, statuses


def test_windows_of_vo_in_corrections_out(ros_context, tiny_model: Path) -> None:
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    rng = np.random.default_rng(0)
    frames = [(rng.integers(0, 256, (64, 208), np.uint8), rng.integers(0, 256, (64, 208), np.uint8)) for _ in range(8)]
    motions = [
        se3_exp(np.r_[0.02 * rng.normal(size=3), 0.01 * rng.normal(size=3)]) @ se3_exp([0, 0, 0.8, 0, 0, 0]) for _ in range(8)
    ]

    def script(left, right, vo, received, statuses, node) -> None:
        for k, (a, b) in enumerate(frames):
            left.publish(image_message(a, (k + 1) * STEP))
            right.publish(image_message(b, (k + 1) * STEP))
        wait_for(lambda: len(node.sensor.images) == len(frames), 20)  # the pairs before their VO, as on a robot
        for k in range(1, 8):
            vo.publish(vo_message((k + 1) * STEP, k * STEP, motions[k]))
        wait_for(lambda: len(received) >= 2, 20)

    received, _ = run_graph(ros_context, {"model": str(tiny_model)}, script)
    reference = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    expected = []
    for k, (a, b) in enumerate(frames):
        reference.add_images((k + 1) * STEP, a, b)
    for k in range(1, 8):
        correction = reference.add_vo(k * STEP, (k + 1) * STEP, motions[k])
        if correction is not None:
            expected.append(correction)
    assert len(received) == len(expected) == 2  # windows 1-4 and 4-7 (frames at 0.1 s steps)
    for msg, correction in zip(received, expected, strict=True):
        assert msg.reference_stamp.nanosec == correction.reference_stamp % 1_000_000_000
        np.testing.assert_allclose(pose_to_matrix(msg.pose.pose), correction.transform, atol=1e-9)
        np.testing.assert_allclose(np.reshape(msg.pose.covariance, (6, 6)), np.diag([0.01] * 3 + [0.001] * 3))
    vo_only = np.eye(4)
    for k in (1, 2, 3):
        vo_only = motions[k] @ vo_only
    assert not np.allclose(expected[0].transform, vo_only)  # the correction was applied


def test_a_broken_chain_starts_a_new_window_and_a_bad_pair_is_reported(ros_context, tiny_model: Path) -> None:
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    sensor = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    image = np.zeros((64, 208), np.uint8)
    for k in range(1, 8):
        sensor.add_images(k * STEP, image, image)
    assert sensor.add_vo(1 * STEP, 2 * STEP, np.eye(4)) is None
    assert sensor.add_vo(2 * STEP, 3 * STEP, np.eye(4)) is None
    assert sensor.add_vo(4 * STEP, 5 * STEP, np.eye(4)) is None  # frame 3 -> 4 missing: a new window from 4
    assert sensor.add_vo(5 * STEP, 6 * STEP, np.eye(4)) is None
    correction = sensor.add_vo(6 * STEP, 7 * STEP, np.eye(4))
    assert correction is not None and correction.reference_stamp == 4 * STEP
    with pytest.raises(ValueError, match="left and right images differ in size"):
        sensor.add_images(9 * STEP, image, image[:, :100])

    def script(left, right, vo, received, statuses, node) -> None:
        left.publish(image_message(image, STEP))
        right.publish(image_message(image[:, :100].copy(), STEP))
        wait_for(lambda: any(s.status[0].level == DiagnosticStatus.WARN for s in statuses), 20)

    _, statuses = run_graph(ros_context, {"model": str(tiny_model)}, script)
    assert "left and right images differ in size" in statuses[-1].status[0].message


def test_a_missing_model_is_reported_and_the_node_keeps_running(ros_context, tmp_path: Path) -> None:
    def script(left, right, vo, received, statuses, node) -> None:
        vo.publish(vo_message(2 * STEP, STEP, np.eye(4)))
        vo.publish(vo_message(3 * STEP, 2 * STEP, np.eye(4)))
        wait_for(lambda: len(statuses) >= 2, 20)

    received, statuses = run_graph(ros_context, {"model": str(tmp_path / "none")}, script)
    assert received == [] and all(s.status[0].level == DiagnosticStatus.ERROR for s in statuses)
    assert "model directory not found" in statuses[0].status[0].message
