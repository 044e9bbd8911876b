"""`pvo bag play`: publish a bag's stored CDR bytes unchanged, with the recorded timing and /clock."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from pvo_core.msgconv import fill_stamp
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from .bagio import iter_messages, open_bag
from .errors import BagError
from .recorder import has_header, header_stamp_ns, with_header_stamp
from .typesys import message_class

#: Reliable publishers reach both reliable and best-effort subscribers.
PLAYER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)


@dataclass
class PlayOptions:
    """wait_for_subscribers: before playing, wait (up to ``wait_timeout`` s) until the subscriptions have not
    changed for ``settle`` s and every topic that has subscribers has at least this many (topics nobody
    subscribes to are not waited for, but what is published on them is counted); 0 plays at once."""

    rate: float = 1.0
    start_offset: float = 0.0
    topics: list[str] | None = None
    loop: bool = False
    passes: int = 0  # with loop: stop after this many passes (0: forever)
    clock: bool = True
    wait_for_subscribers: int = 1
    wait_timeout: float = 10.0
    settle: float = 2.0
    delay: float = 0.0
    # fault injection (benchmarks): called with (topic, header stamp or None, CDR bytes) before each publish;
    # returns the bytes to publish (possibly restamped) or None to drop the message
    hook: Callable[[str, int | None, bytes], bytes | None] | None = None


@dataclass
class PlayStats:
    """Messages published (per topic), and those published while the topic had no subscriber (``unheard``)."""

    messages: int = 0
    seconds: float = 0.0
    per_topic: dict[str, int] = field(default_factory=dict)
    unheard: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)  # by the fault-injection hook
    passes: int = 0

    def report(self) -> str:
        line = f"played {self.messages} messages in {self.seconds:.2f} s"
        if self.unheard:
            lost = ", ".join(f"{topic} ({n})" for topic, n in sorted(self.unheard.items()))
            line += f"; published with no subscriber (nobody received them): {lost}"
        return line


class BagPlayer:
    """Publishes a bag from a node; usable in-process (tests) or from `pvo bag play`."""

    def __init__(self, node: Node, bag: Path, options: PlayOptions) -> None:
        if options.rate <= 0:
            raise BagError(f"--rate must be positive, got {options.rate}")
        if options.start_offset < 0:
            raise BagError(f"--start-offset must be non-negative, got {options.start_offset}")
        self.node = node
        self.bag = Path(bag)
        self.options = options
        self.publishers: dict[str, object] = {}
        self.clock_publisher = node.create_publisher(Clock, "/clock", CLOCK_QOS) if options.clock else None

    def _prepare(self, reader) -> list:
        connections = list(reader.connections)
        if self.options.topics:
            wanted = set(self.options.topics)
            unknown = wanted - {c.topic for c in connections}
            if unknown:
                raise BagError(
                    f"{self.bag}: no topic {sorted(unknown)} in the bag (it has {sorted({c.topic for c in connections})})"
                )
            connections = [c for c in connections if c.topic in wanted]
        for connection in connections:
            if connection.topic not in self.publishers:
                cls = message_class(connection.msgtype)
                self.publishers[connection.topic] = self.node.create_publisher(cls, connection.topic, PLAYER_QOS)
        return connections

    def _wait_for_subscribers(self) -> None:
        """Until the subscriptions have been stable for ``settle`` s (a node's endpoints are discovered one by
        one, over a second or more) and every subscribed topic has ``wait_for_subscribers`` of them."""
        wanted = self.options.wait_for_subscribers
        if wanted <= 0:
            return
        start = time.monotonic()
        last: dict[str, int] = {}
        changed = start
        while True:
            counts = {topic: p.get_subscription_count() for topic, p in self.publishers.items()}
            now = time.monotonic()
            if counts != last:
                last, changed = counts, now
            subscribed = [n for n in counts.values() if n > 0]
            if subscribed and now - changed >= self.options.settle and all(n >= wanted for n in subscribed):
                return
            if now - start > self.options.wait_timeout:
                if not subscribed:
                    self.node.get_logger().warning(f"no subscriber after {self.options.wait_timeout:g} s; playing anyway")
                else:
                    short = sorted(t for t, n in counts.items() if 0 < n < wanted)
                    self.node.get_logger().warning(f"{', '.join(short)} did not reach {wanted} subscriber(s); playing anyway")
                return
            time.sleep(0.02)

    def play(self) -> PlayStats:
        stats = PlayStats()
        wall_start = time.monotonic()
        with open_bag(self.bag) as reader:
            connections = self._prepare(reader)
            self._wait_for_subscribers()
            if self.options.delay > 0:
                time.sleep(self.options.delay)
            bag_start = reader.start_time
            first_ns = bag_start + int(self.options.start_offset * 1e9)
            header_topics = {c.topic for c in connections if has_header(c.msgtype)}
            restamp = 0  # ns added to every stamp from the second pass of a loop on: stamps keep increasing
            frame_stamps: list[int] = []
            while True:
                t0_wall = time.monotonic()
                t0_bag: int | None = None
                last_bag = first_ns
                for connection, stamp_ns, raw in iter_messages(reader, connections, first_ns):
                    if t0_bag is None:
                        t0_bag = stamp_ns
                    last_bag = stamp_ns
                    target = t0_wall + (stamp_ns - t0_bag) / 1e9 / self.options.rate
                    delay = target - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    if connection.topic in header_topics:
                        header = header_stamp_ns(raw)
                        if header is not None and restamp == 0 and (not frame_stamps or header > frame_stamps[-1]):
                            frame_stamps.append(header)
                        if restamp and header is not None:
                            raw = with_header_stamp(raw, header + restamp)
                    if self.options.hook is not None:
                        hooked = self.options.hook(
                            connection.topic, header_stamp_ns(raw) if connection.topic in header_topics else None, bytes(raw)
                        )
                        if hooked is None:
                            stats.dropped[connection.topic] = stats.dropped.get(connection.topic, 0) + 1
                            continue
                        raw = hooked
                    if self.clock_publisher is not None:
                        clock = Clock()
                        fill_stamp(clock.clock, stamp_ns + restamp)
                        self.clock_publisher.publish(clock)
                    publisher = self.publishers[connection.topic]
                    if publisher.get_subscription_count() == 0:
                        stats.unheard[connection.topic] = stats.unheard.get(connection.topic, 0) + 1
                    publisher.publish(bytes(raw))
                    stats.messages += 1
                    stats.per_topic[connection.topic] = stats.per_topic.get(connection.topic, 0) + 1
                passes_done = stats.passes = stats.passes + 1
                if not self.options.loop or t0_bag is None or (self.options.passes and passes_done >= self.options.passes):
                    break
                # the next pass starts one frame interval after this one ended, in bag time and in stamps
                interval = (frame_stamps[-1] - frame_stamps[0]) // max(len(frame_stamps) - 1, 1) if frame_stamps else 0
                restamp += (last_bag - t0_bag) + max(interval, 1)
            self._wait_for_acknowledgements()
        stats.seconds = time.monotonic() - wall_start
        return stats

    def _wait_for_acknowledgements(self, timeout_s: float = 10.0) -> None:
        """Reliable delivery needs the publishers alive until every subscriber has acknowledged."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        for topic, publisher in self.publishers.items():
            remaining = max(deadline - time.monotonic(), 0.0)
            if not publisher.wait_for_all_acked(Duration(nanoseconds=int(remaining * 1e9))):
                self.node.get_logger().warning(f"not every subscriber of {topic} acknowledged all messages within {timeout_s} s")


def play(bag: Path, options: PlayOptions, args: list[str] | None = None) -> PlayStats:
    """Run a player node until the bag ends (or forever with ``loop``)."""
    rclpy.init(args=args)
    node = Node("pvo_bag_player")
    try:
        return BagPlayer(node, bag, options).play()
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
