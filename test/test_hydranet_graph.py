"""The hydranet node over DDS: consecutive images in, rotation-only RelativePose messages out, exactly what the
ROS-free sensor computes; the first image, a bad image, a size change and a missing model are reported and
the node keeps running."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from test_sun_bcnn_graph import image_message

from pvo_msgs.msg import RelativePose

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
SECOND = 1_000_000_000


@pytest.fixture()
def tiny_model(tmp_path: Path) -> Path:
    import torch
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    config = HydraNetConfig(height=32, width=96, widths=(4, 8), feature=16, heads=4, head_hidden=8)
    torch.manual_seed(0)
    return save_model(tmp_path / "model", HydraNet(config), HydraTask(config).card())


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> list[np.ndarray]:
    import cv2
    from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence

    root = tmp_path_factory.mktemp("rotating")
    write_rotation_sequence(root, frames=6, size=(96, 288), focal=140.0)
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((root / "image_0").glob("*.png"))]


@dataclass
class Graph:
    node: Any
    camera: Node
    publisher: Any
    received: list[RelativePose] = field(default_factory=list)
    statuses: list[DiagnosticArray] = field(default_factory=list)


@contextmanager
def hydranet_graph(ros_context, **parameters: Any) -> Iterator[Graph]:
    from pvo_pseudosensors.hydranet_node import HydraNetNode

    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    node = HydraNetNode(context=ros_context, parameter_overrides=overrides)
    camera = Node("camera", context=ros_context)
    graph = Graph(node, camera, camera.create_publisher(Image, "/stereo/left/image_rect", RELIABLE))
    camera.create_subscription(RelativePose, "/pvo/hydranet/rotation", graph.received.append, RELIABLE)
    camera.create_subscription(DiagnosticArray, "/pvo/hydranet/status", graph.statuses.append, RELIABLE)
    try:
        with Spinner(ros_context, node), Spinner(ros_context, camera):
            wait_for(lambda: graph.publisher.get_subscription_count() > 0 and node.publisher.get_subscription_count() > 0, 10)
            yield graph
    finally:
        node.destroy_node()
        camera.destroy_node()


def test_images_in_rotations_out(ros_context, tiny_model: Path, frames: list[np.ndarray]) -> None:
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig

    stamps = [SECOND + k * SECOND // 10 for k in range(len(frames))]
    with hydranet_graph(ros_context, model=str(tiny_model)) as graph:
        for pixels, stamp in zip(frames, stamps, strict=True):
            graph.publisher.publish(image_message(pixels, stamp))
        wait_for(lambda: len(graph.received) >= len(frames) - 1, 30)
    received, statuses = graph.received, graph.statuses
    assert len(received) == len(frames) - 1
    assert "no predecessor" in statuses[0].status[0].message and statuses[0].status[0].level == DiagnosticStatus.OK
    reference = HydraNetSensor(HydraNetSensorConfig(model=str(tiny_model)))
    reference.estimate(frames[0], stamps[0])
    for k, msg in enumerate(received, start=1):
        expected = reference.estimate(frames[k], stamps[k])
        assert expected is not None and msg.rotation_only
        assert (msg.reference_stamp.sec * SECOND + msg.reference_stamp.nanosec, msg.header.stamp.nanosec) == (
            stamps[k - 1],
            stamps[k] % SECOND,
        )
        o = msg.pose.pose.orientation
        np.testing.assert_allclose([o.w, o.x, o.y, o.z], expected.quaternion, atol=1e-12)
        covariance = np.asarray(msg.pose.covariance).reshape(6, 6)
        np.testing.assert_allclose(covariance[3:, 3:], expected.covariance, atol=1e-15)
        assert np.all(np.diag(covariance)[:3] == 9999.0) and not np.any(covariance[:3, 3:])
        p = msg.pose.pose.position
        assert (p.x, p.y, p.z) == (0.0, 0.0, 0.0)


def test_bad_images_and_a_size_change_are_reported_and_the_next_pair_published(
    ros_context, tiny_model: Path, frames: list[np.ndarray]
) -> None:
    from fuzzing import image_variants

    variants = image_variants(image_message(frames[1], 2 * SECOND))
    with hydranet_graph(ros_context, model=str(tiny_model)) as graph:
        graph.publisher.publish(image_message(frames[0], SECOND))
        for variant in variants:
            graph.publisher.publish(variant.message)
        graph.publisher.publish(image_message(frames[1], SECOND + SECOND // 10))
        graph.publisher.publish(image_message(frames[2][::2, ::2].copy(), SECOND + 2 * SECOND // 10))  # another size
        graph.publisher.publish(image_message(frames[3][::2, ::2].copy(), SECOND + 3 * SECOND // 10))
        wait_for(lambda: len(graph.statuses) >= len(variants) + 4, 30)
    received, statuses = graph.received, graph.statuses
    messages = [s.status[0].message for s in statuses]
    for variant, message in zip(variants, messages[1:], strict=False):
        assert variant.reason in message, (variant.name, message)
    assert "image size changed from (96, 288) to (48, 144)" in messages[-2]
    assert len(received) == 2 and statuses[-1].status[0].level == DiagnosticStatus.OK


def test_a_missing_model_is_reported_and_the_node_keeps_running(ros_context, tmp_path: Path) -> None:
    with hydranet_graph(ros_context, model=str(tmp_path / "none")) as graph:
        graph.publisher.publish(image_message(np.zeros((40, 80), np.uint8), SECOND))
        graph.publisher.publish(image_message(np.zeros((40, 80), np.uint8), 2 * SECOND))
        wait_for(lambda: len(graph.statuses) >= 2, 20)
    assert graph.received == []
    assert all(s.status[0].level == DiagnosticStatus.ERROR for s in graph.statuses)
    assert "model directory not found" in graph.statuses[0].status[0].message
