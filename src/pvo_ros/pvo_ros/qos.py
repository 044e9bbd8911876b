"""QoS profiles of the pvo graph, named by what they are for."""

from __future__ import annotations

from typing import Any

SENSOR_QUEUE_DEPTH = 10  # messages per input topic held by DDS until the callbacks take them
# measurements each sensor keeps for a late joiner: a fusion node restarted from its checkpoint takes again what was
# published while it was down (20 s of VO at 10 Hz; a RelativePose is ~0.4 kB)
MEASUREMENT_HISTORY = 200


def reliable(depth: int) -> Any:
    """Reliable, keep-last ``depth``: outputs, and inputs whose loss the node reports itself."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=max(1, int(depth)), reliability=ReliabilityPolicy.RELIABLE)


def every_message() -> Any:
    """Reliable, keep-all: inputs of which a lagging node must not silently lose one (a lost VO frame is a gap)."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


def measurements(depth: int = MEASUREMENT_HISTORY) -> Any:
    """Reliable, keep-last ``depth``, transient-local: a sensor's measurements for the fusion. The publisher keeps
    the last ``depth`` for a subscription that asks for them (a fusion node resuming from its checkpoint); volatile
    subscriptions (recorders, ``pvo topic echo``, other nodes) match it as they match a volatile one."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        depth=max(1, int(depth)), reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )


def kept_history_durability(node: Any, topic: str) -> Any:
    """The durability a subscription to ``topic`` can ask for now: TRANSIENT_LOCAL when the topic has publishers and
    every one keeps its history (`measurements`), else VOLATILE, which matches every publisher (a transient-local
    subscription would not match a volatile publisher, a bag player say). Decided once, from what discovery has
    seen: a volatile publisher that appears later is not matched by a transient-local subscription."""
    from rclpy.qos import DurabilityPolicy

    publishers = node.get_publishers_info_by_topic(topic)
    if publishers and all(info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for info in publishers):
        return DurabilityPolicy.TRANSIENT_LOCAL
    return DurabilityPolicy.VOLATILE
