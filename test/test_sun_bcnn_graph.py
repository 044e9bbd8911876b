"""The sun_bcnn node over DDS: images in, sun directions with covariance out, exactly what the ROS-free
sensor computes; a bad image or a missing model is reported and the node keeps running."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pvo_core.msgconv import fill_stamp
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from pvo_msgs.msg import SunDirection

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture()
def tiny_model(tmp_path: Path) -> Path:
    import torch
    from pvo_pseudosensors.learning.checkpoint import save_model
    from pvo_pseudosensors.sun_bcnn import SunBCNNConfig
    from pvo_pseudosensors.sun_bcnn.model import SunBCNN, SunTask

    config = SunBCNNConfig(height=24, width=64, widths=(4, 8), hidden=8, dropout=0.2, bins=0, rotate=0.0)
    torch.manual_seed(0)
    card = SunTask(config).card()
    card.calibration = {"tau": 100.0}
    return save_model(tmp_path / "model", SunBCNN(config), card)


def image_message(pixels: np.ndarray, stamp_ns: int, encoding: str = "mono8") -> Image:
    msg = Image()
    fill_stamp(msg.header.stamp, stamp_ns)
    msg.header.frame_id = "camera_left_optical"
    msg.height, msg.width = pixels.shape[:2]
    msg.encoding = encoding
    msg.step = pixels.shape[1] * (1 if pixels.ndim == 2 else pixels.shape[2]) * pixels.itemsize
    msg.data = pixels.tobytes()
    return msg


@dataclass
class Graph:
    """The sun_bcnn node, a camera publishing left images, and what comes back."""

    node: Any
    camera: Node
    publisher: Any
    received: list[SunDirection] = field(default_factory=list)
    statuses: list[DiagnosticArray] = field(default_factory=list)


@contextmanager
def sun_bcnn_graph(ros_context, **parameters: Any) -> Iterator[Graph]:
    """Start the node with ``parameters`` and a camera; spin both for the with-block, then tear down."""
    from pvo_pseudosensors.sun_bcnn_node import SunBCNNNode

    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    node = SunBCNNNode(context=ros_context, parameter_overrides=overrides)
    camera = Node("camera", context=ros_context)
    graph = Graph(node, camera, camera.create_publisher(Image, "/stereo/left/image_rect", RELIABLE))
    camera.create_subscription(SunDirection, "/pvo/sun/direction", graph.received.append, RELIABLE)
    camera.create_subscription(DiagnosticArray, "/pvo/sun_bcnn/status", graph.statuses.append, RELIABLE)
    try:
        with Spinner(ros_context, node), Spinner(ros_context, camera):
            # both directions matched before anything is sent: a late match would lose the first messages
            wait_for(lambda: graph.publisher.get_subscription_count() > 0 and node.publisher.get_subscription_count() > 0, 10)
            yield graph
    finally:
        node.destroy_node()
        camera.destroy_node()


def test_images_in_sun_directions_out(ros_context, tiny_model: Path) -> None:
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensor, SunBCNNSensorConfig

    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (120, 320), dtype=np.uint8) for _ in range(6)]
    with sun_bcnn_graph(ros_context, model=str(tiny_model), every_n=2, samples=5) as graph:
        for k, pixels in enumerate(images[:4]):
            graph.publisher.publish(image_message(pixels, 1_000_000_000 + k * 100_000_000))
        wait_for(lambda: len(graph.received) >= 2, 30)
        # a 16-bit image: rejected and reported; the node goes on with the next good one
        graph.publisher.publish(image_message(np.zeros((120, 320), np.uint16), 1_400_000_000, "mono16"))
        graph.publisher.publish(image_message(images[4], 1_500_000_000))
        graph.publisher.publish(image_message(images[5], 1_600_000_000))
        wait_for(lambda: len(graph.received) >= 3 and any(s.status[0].level == DiagnosticStatus.WARN for s in graph.statuses), 30)
    received, statuses = graph.received, graph.statuses

    assert len(received) == 3  # images 0, 2 and (after the rejected one, 5th input) image 5
    reference = SunBCNNSensor(SunBCNNSensorConfig(model=str(tiny_model), every_n=2, samples=5))
    for msg, pixels in zip(received, (images[0], images[2], images[5]), strict=True):
        expected = reference.estimate(pixels)
        direction = np.array([msg.direction.x, msg.direction.y, msg.direction.z])
        np.testing.assert_allclose(direction, expected.direction, atol=1e-12)
        covariance = np.asarray(msg.covariance).reshape(2, 2)
        np.testing.assert_allclose(covariance, expected.covariance, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(covariance) >= 0.01 - 1e-12)  # tau^-1 = 0.01 was added
        assert msg.header.frame_id == "camera_left_optical"
    warning = next(s.status[0] for s in statuses if s.status[0].level == DiagnosticStatus.WARN)
    assert "unsupported image encoding 'mono16'" in warning.message


def test_a_missing_model_is_reported_and_the_node_keeps_running(ros_context, tmp_path: Path) -> None:
    with sun_bcnn_graph(ros_context, model=str(tmp_path / "none")) as graph:
        graph.publisher.publish(image_message(np.zeros((40, 80), np.uint8), 1_000_000_000))
        wait_for(lambda: bool(graph.statuses), 20)
    received, statuses = graph.received, graph.statuses
    assert received == []
    assert statuses[0].status[0].level == DiagnosticStatus.ERROR
    assert "model directory not found" in statuses[0].status[0].message


def test_every_bad_image_is_rejected_with_its_reason(ros_context, tiny_model: Path) -> None:
    from fuzzing import image_variants

    good = image_message(np.random.default_rng(1).integers(0, 256, (60, 160), dtype=np.uint8), 1_000_000_000)
    variants = image_variants(good)
    with sun_bcnn_graph(ros_context, model=str(tiny_model), every_n=1, samples=3) as graph:
        for variant in variants:
            graph.publisher.publish(variant.message)
        graph.publisher.publish(good)
        wait_for(lambda: len(graph.statuses) >= len(variants) + 1, 30)
    received, statuses = graph.received, graph.statuses
    messages = [s.status[0].message for s in statuses]
    for variant, message in zip(variants, messages, strict=False):
        assert variant.reason in message, (variant.name, message)
    assert len(received) == 1 and statuses[-1].status[0].level == DiagnosticStatus.OK  # alive, and right after
