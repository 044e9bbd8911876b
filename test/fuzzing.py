"""Fuzzing of node inputs: bad variants of a good message, each with the reason a node must count for it.

Every node's tests feed these through DDS (``fuzz_input``): the node must stay alive, count the reason in
its status, and — where the bad message was dropped — give the same output as the clean run. New nodes
(the learned pseudo-sensors) reuse the variants for their inputs.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

NAN, INF = math.nan, math.inf


@dataclass(frozen=True)
class Variant:
    name: str
    message: Any
    reason: str  # the count key suffix, e.g. "rejected.non_finite_pose"


def _with(msg: Any, change: Callable[[Any], None]) -> Any:
    out = copy.deepcopy(msg)
    change(out)
    return out


def _set_position(pose: Any, x: float) -> None:
    pose.position.x = x


def _set_quaternion(pose: Any, w: float, x: float, y: float, z: float) -> None:
    # floats, not ints: rclpy accepts an int in a float64 field but does not serialise it as the number
    pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = (float(v) for v in (w, x, y, z))


def pose_variants(msg: Any, pose_of: Callable[[Any], Any]) -> list[Variant]:
    """NaN and infinite positions, a NaN, zero and non-unit (|q| = 2) quaternion."""
    return [
        Variant("NaN position", _with(msg, lambda m: _set_position(pose_of(m), NAN)), "rejected.non_finite_pose"),
        Variant("infinite position", _with(msg, lambda m: _set_position(pose_of(m), INF)), "rejected.non_finite_pose"),
        Variant("NaN quaternion", _with(msg, lambda m: _set_quaternion(pose_of(m), NAN, 0, 0, 0)), "rejected.non_finite_pose"),
        Variant("zero quaternion", _with(msg, lambda m: _set_quaternion(pose_of(m), 0, 0, 0, 0)), "rejected.zero_quaternion"),
        Variant("|q| = 2", _with(msg, lambda m: _set_quaternion(pose_of(m), 2, 0, 0, 0)), "rejected.quaternion_not_unit"),
    ]


def covariance_variants(msg: Any, field: str, size: int) -> list[Variant]:
    """NaN, infinite, zero, asymmetric and negative-definite covariances (row-major ``size`` x ``size``)."""

    def setter(values: list[float]) -> Callable[[Any], None]:
        def change(m: Any) -> None:
            holder = m
            *parents, leaf = field.split(".")
            for part in parents:
                holder = getattr(holder, part)
            setattr(holder, leaf, values)

        return change

    n = size * size
    identity = [1e-4 if i % (size + 1) == 0 else 0.0 for i in range(n)]
    asymmetric = list(identity)
    asymmetric[1] = 1e-5
    return [
        Variant("NaN covariance", _with(msg, setter([NAN] * n)), "rejected.non_finite_covariance"),
        Variant("infinite covariance", _with(msg, setter([INF, *identity[1:]])), "rejected.non_finite_covariance"),
        Variant("zero covariance", _with(msg, setter([0.0] * n)), "rejected.covariance_not_positive_definite"),
        Variant("asymmetric covariance", _with(msg, setter(asymmetric)), "rejected.covariance_not_positive_definite"),
        Variant("negative covariance", _with(msg, setter([-v for v in identity])), "rejected.covariance_not_positive_definite"),
    ]


def image_variants(msg: Any) -> list[Variant]:
    """Bad versions of a good ``sensor_msgs/Image`` (mono8); ``reason``: words the rejection must contain."""

    def truncate(m: Any) -> None:
        m.data = bytes(m.data)[: len(m.data) // 2]

    def empty(m: Any) -> None:
        m.data = b""

    def zero_width(m: Any) -> None:
        m.width = 0

    def wide_pixels(m: Any) -> None:
        m.encoding = "mono16"

    def unknown(m: Any) -> None:
        m.encoding = "yuv422"

    return [
        Variant("unknown encoding", _with(msg, unknown), "unsupported image encoding 'yuv422'"),
        Variant("16-bit pixels", _with(msg, wide_pixels), "unsupported image encoding 'mono16'"),
        Variant("empty image", _with(msg, empty), "image data of 0 bytes does not match"),
        Variant("truncated image", _with(msg, truncate), "does not match"),
        Variant("zero width", _with(msg, zero_width), "does not match 0x"),
    ]


def set_stamp(stamp: Any, nanoseconds: int) -> None:
    stamp.sec, stamp.nanosec = divmod(int(nanoseconds), 1_000_000_000)


def wait_for(predicate: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.02)
    return bool(predicate())
