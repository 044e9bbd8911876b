"""`pvo run`, `pvo topic ...`, `pvo node list`, `pvo interface show`: the ros2cli verbs we need."""

from __future__ import annotations

import os
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from pvo_core.metrics import interval_statistics
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from .errors import PvoError
from .typesys import find_interface_file, message_class, normalise_type_name


# ----------------------------------------------------------------------------- run
def find_executable(package: str, executable: str) -> Path:
    """``<prefix>/lib/<package>/<executable>`` through the ament index, like `ros2 run`."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        prefix = Path(get_package_prefix(package))
    except (PackageNotFoundError, KeyError, LookupError):
        raise PvoError(
            f"package '{package}' not found in the ament index (AMENT_PREFIX_PATH); is install/setup.bash sourced?"
        ) from None
    lib = prefix / "lib" / package
    candidate = lib / executable
    if candidate.is_file() and os.access(candidate, os.X_OK):
        return candidate
    available = sorted(p.name for p in lib.iterdir() if p.is_file() and os.access(p, os.X_OK)) if lib.is_dir() else []
    raise PvoError(f"no executable '{executable}' in package '{package}' (it has: {', '.join(available) or 'none'})")


def run(package: str, executable: str, args: list[str]) -> None:
    """Replace this process with the package's executable (never returns on success)."""
    path = find_executable(package, executable)
    os.execv(str(path), [str(path), *args])


# ----------------------------------------------------------------------------- graph helpers
def _spin_for(node: Node, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


def _topic_types(node: Node, topic: str, wait: float) -> list[str]:
    end = time.monotonic() + wait
    while True:
        types = dict(node.get_topic_names_and_types()).get(topic)
        if types or time.monotonic() >= end:
            return types or []
        rclpy.spin_once(node, timeout_sec=0.05)


def topic_list(node: Node, show_types: bool, wait: float = 1.0) -> list[str]:
    _spin_for(node, wait)
    out = []
    for topic, types in sorted(node.get_topic_names_and_types()):
        out.append(f"{topic} [{', '.join(types)}]" if show_types else topic)
    return out


def topic_info(node: Node, topic: str, wait: float = 1.0) -> list[str]:
    types = _topic_types(node, topic, wait)
    if not types:
        raise PvoError(f"unknown topic '{topic}' (not on the graph)")
    publishers = node.get_publishers_info_by_topic(topic)
    subscriptions = node.get_subscriptions_info_by_topic(topic)
    return [f"Type: {', '.join(types)}", f"Publisher count: {len(publishers)}", f"Subscription count: {len(subscriptions)}"]


def node_list(node: Node, wait: float = 1.0) -> list[str]:
    _spin_for(node, wait)
    own = node.get_fully_qualified_name()
    names = set()
    for name, namespace in node.get_node_names_and_namespaces():
        full = f"{namespace.rstrip('/')}/{name}"
        if full != own:
            names.add(full)
    return sorted(names)


def _subscription_qos(node: Node, topic: str) -> QoSProfile:
    publishers = node.get_publishers_info_by_topic(topic)
    best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=100,
        reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
    )


# ----------------------------------------------------------------------------- echo
def to_yaml_lines(message: Any, indent: int = 0, max_array: int = 16) -> list[str]:
    """A YAML rendering of an rclpy message like `ros2 topic echo` (long arrays truncated)."""
    pad = "  " * indent
    lines: list[str] = []
    for field_name in message.get_fields_and_field_types():
        value = getattr(message, field_name)
        if hasattr(value, "get_fields_and_field_types"):
            lines.append(f"{pad}{field_name}:")
            lines.extend(to_yaml_lines(value, indent + 1, max_array))
        elif isinstance(value, (list, tuple, np.ndarray, bytes, bytearray)) or type(value).__name__ == "array":
            items = list(value)
            if items and hasattr(items[0], "get_fields_and_field_types"):
                lines.append(f"{pad}{field_name}:")
                for item in items[:max_array]:
                    sub = to_yaml_lines(item, indent + 2, max_array)
                    lines.append(f"{pad}- " + sub[0].strip())
                    lines.extend(sub[1:])
                if len(items) > max_array:
                    lines.append(f"{pad}- '... ({len(items) - max_array} more)'")
            else:
                shown = ", ".join(_scalar(v) for v in items[:max_array])
                more = f", '... ({len(items)} items)'" if len(items) > max_array else ""
                lines.append(f"{pad}{field_name}: [{shown}{more}]")
        else:
            lines.append(f"{pad}{field_name}: {_scalar(value)}")
    return lines


def _scalar(value: Any) -> str:
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def topic_echo(node: Node, topic: str, count: int | None, wait: float, full: bool, timeout: float | None) -> int:
    types = _topic_types(node, topic, wait)
    if not types:
        raise PvoError(f"unknown topic '{topic}' (no publisher seen in {wait:.1f} s)")
    cls = message_class(normalise_type_name(types[0]))
    received = 0

    def on_message(message: Any) -> None:
        nonlocal received
        received += 1
        print("\n".join(to_yaml_lines(message, max_array=10**9 if full else 16)))
        print("---", flush=True)

    node.create_subscription(cls, topic, on_message, _subscription_qos(node, topic))
    end = None if timeout is None else time.monotonic() + timeout
    while (count is None or received < count) and (end is None or time.monotonic() < end):
        rclpy.spin_once(node, timeout_sec=0.05)
    return received


def topic_hz(node: Node, topic: str, window: int, duration: float | None, wait: float, use_header: bool) -> list[float]:
    """Print the rate every second (from receive times, or header stamps); return the printed rates."""
    types = _topic_types(node, topic, wait)
    if not types:
        raise PvoError(f"unknown topic '{topic}' (no publisher seen in {wait:.1f} s)")
    cls = message_class(normalise_type_name(types[0]))
    times: deque[float] = deque(maxlen=window)

    def on_message(message: Any) -> None:
        if use_header and hasattr(message, "header"):
            stamp = message.header.stamp
            times.append(stamp.sec + stamp.nanosec * 1e-9)
        else:
            times.append(time.monotonic())

    node.create_subscription(cls, topic, on_message, _subscription_qos(node, topic))
    rates: list[float] = []
    start = time.monotonic()
    next_print = start + 1.0
    while duration is None or time.monotonic() - start < duration:
        rclpy.spin_once(node, timeout_sec=0.05)
        if time.monotonic() >= next_print:
            next_print += 1.0
            if len(times) >= 2:
                stats = interval_statistics(list(times))
                rates.append(stats["rate_hz"])
                print(
                    f"average rate: {stats['rate_hz']:.3f}\n\tmin: {stats['min_s']:.3f}s max: {stats['max_s']:.3f}s "
                    f"std dev: {stats['std_s']:.5f}s window: {len(times)}",
                    flush=True,
                )
            else:
                print("no new messages", flush=True)
    return rates


# ----------------------------------------------------------------------------- interface
def interface_show(type_name: str) -> str:
    path = find_interface_file(type_name)
    if path is None:
        raise PvoError(f"unknown message type '{type_name}': no installed package defines it")
    return path.read_text().rstrip("\n")


def make_node(name: str) -> Node:
    rclpy.init(args=None)
    return Node(name, start_parameter_services=False)


def shutdown(node: Node) -> None:
    node.destroy_node()
    if rclpy.ok():
        rclpy.shutdown()
