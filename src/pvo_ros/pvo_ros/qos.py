"""QoS profiles of the pvo graph, named by what they are for."""

from __future__ import annotations

from typing import Any

SENSOR_QUEUE_DEPTH = 10  # messages per input topic held by DDS until the callbacks take them


def reliable(depth: int) -> Any:
    """Reliable, keep-last ``depth``: outputs, and inputs whose loss the node reports itself."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=max(1, int(depth)), reliability=ReliabilityPolicy.RELIABLE)


def every_message() -> Any:
    """Reliable, keep-all: inputs of which a lagging node must not silently lose one (a lost VO frame is a gap)."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
