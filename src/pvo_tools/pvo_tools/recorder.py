"""`pvo bag record`: raw subscriptions written to rosbag2 with the type definitions preserved."""

from __future__ import annotations

import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from .bagio import SafeBagWriter
from .typesys import message_class, normalise_type_name, project_typestore

#: Topics the ROS middleware creates for itself; `--all` skips them.
INTERNAL_TOPICS = {"/rosout", "/parameter_events"}


def header_stamp_ns(raw: bytes) -> int | None:
    """``header.stamp`` of a CDR message whose first field is a std_msgs/Header (else None)."""
    if len(raw) < 12:
        return None
    sec, nanosec = struct.unpack_from("<iI", raw, 4) if raw[1] == 1 else struct.unpack_from(">iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


def with_header_stamp(raw: bytes, stamp_ns: int) -> bytes:
    """The CDR message with its ``header.stamp`` replaced (the message must start with a std_msgs/Header)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    out = bytearray(raw)
    struct.pack_into("<iI" if raw[1] == 1 else ">iI", out, 4, sec, nanosec)
    return bytes(out)


def has_header(type_name: str) -> bool:
    """Whether messages of the type start with a std_msgs/Header."""
    return _has_header(type_name)


def _has_header(type_name: str) -> bool:
    fields = project_typestore().fielddefs.get(type_name)
    if not fields or not fields[1]:
        return False
    first = fields[1][0][1]
    return isinstance(first, tuple) and len(first) == 2 and first[1] in ("std_msgs/msg/Header",)


@dataclass
class RecordOptions:
    topics: list[str]
    record_all: bool = False
    duration: float | None = None
    stamp: str = "receive"  # or "header"
    storage: str = "mcap"
    overwrite: bool = False


class BagRecorder:
    """Subscribes raw to topics (discovered continuously with ``record_all``) and writes them."""

    def __init__(self, node: Node, out: Path, options: RecordOptions) -> None:
        if options.stamp not in ("receive", "header"):
            raise ValueError(f"--stamp must be 'receive' or 'header', got {options.stamp!r}")
        self.node = node
        self.options = options
        self.writer = SafeBagWriter(out, storage=options.storage, overwrite=options.overwrite, keep_interrupted=True)
        self._lock = threading.Lock()
        self._subscribed: dict[str, object] = {}
        self._header_topics: set[str] = set()
        self.discover()
        self._timer = node.create_timer(0.2, self.discover)

    @property
    def subscribed_topics(self) -> list[str]:
        """Topics being recorded so far."""
        return list(self._subscribed)

    def received(self, topic: str) -> int:
        """Messages written for ``topic`` so far."""
        with self._lock:
            return int(self.writer.counts.get(topic, 0))

    def discover(self) -> None:
        """Subscribe to every wanted topic that has appeared on the graph."""
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._subscribed:
                continue
            if self.options.record_all:
                if topic in INTERNAL_TOPICS:
                    continue
            elif topic not in self.options.topics:
                continue
            type_name = normalise_type_name(types[0])
            cls = message_class(type_name)
            publishers = self.node.get_publishers_info_by_topic(topic)
            best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers)
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=1000,
                reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
            )
            with self._lock:
                self.writer.add_topic(topic, type_name)
            if _has_header(type_name):
                self._header_topics.add(topic)
            self._subscribed[topic] = self.node.create_subscription(
                cls, topic, lambda raw, topic=topic: self._on_message(topic, raw), qos, raw=True
            )
            self.node.get_logger().info(f"recording {topic} [{type_name}]")

    def _on_message(self, topic: str, raw: bytes) -> None:
        stamp = None
        if self.options.stamp == "header" and topic in self._header_topics:
            stamp = header_stamp_ns(raw)
        if stamp is None:
            stamp = time.time_ns()
        with self._lock:
            self.writer.write_raw(topic, stamp, raw)

    def close(self) -> dict[str, int]:
        with self._lock:
            self.writer.close()
        return dict(self.writer.counts)


def record(out: Path, options: RecordOptions, args: list[str] | None = None) -> dict[str, int]:
    """Record until Ctrl-C or ``options.duration`` seconds; the bag is closed cleanly either way."""
    rclpy.init(args=args)
    node = Node("pvo_bag_recorder")
    recorder = BagRecorder(node, out, options)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = None if options.duration is None else time.monotonic() + options.duration
    try:
        while rclpy.ok() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        counts = recorder.close()
        executor.shutdown()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return counts
