"""Conversions between numpy and ROS message *shapes*, without importing any ROS library.

The functions read and fill attributes (``msg.position.x``, ``msg.data`` ...), so they work on rclpy
messages in the nodes and on rosbags messages in the tools alike. Poses are 4x4 ``T_parent_child``;
covariances are 6x6 in ROS order (x, y, z, rotX, rotY, rotZ).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .lie import quaternion_to_rotation, rotation_to_quaternion

Array = NDArray[np.float64]

ENCODING_CHANNELS = {"mono8": 1, "8UC1": 1, "rgb8": 3, "bgr8": 3, "8UC3": 3}


def stamp_to_seconds(stamp: Any) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def stamp_to_nanoseconds(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def fill_stamp(stamp: Any, nanoseconds: int) -> Any:
    stamp.sec, stamp.nanosec = divmod(int(nanoseconds), 1_000_000_000)
    return stamp


def fill_pose(pose: Any, transform: Array) -> Any:
    """Set a ``geometry_msgs/Pose`` from a 4x4 transform."""
    t = np.asarray(transform, dtype=float)
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in t[:3, 3])
    w, x, y, z = rotation_to_quaternion(t[:3, :3])
    pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = float(w), float(x), float(y), float(z)
    return pose


QUATERNION_NORM_TOLERANCE = 1e-3


def pose_problem(pose: Any) -> str | None:
    """Why a ``geometry_msgs/Pose`` is unusable — ``non_finite_pose``, ``zero_quaternion`` or
    ``quaternion_not_unit`` (|q| off 1 by more than 1e-3) — or ``None``."""
    q = np.array([pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z], dtype=float)
    p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=float)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
        return "non_finite_pose"
    norm = float(np.linalg.norm(q))
    if norm < 1e-12:
        return "zero_quaternion"
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        return "quaternion_not_unit"
    return None


def pose_to_matrix(pose: Any) -> Array:
    """4x4 transform of a ``geometry_msgs/Pose``; ``ValueError`` naming what is wrong (:func:`pose_problem`)."""
    q = np.array([pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z], dtype=float)
    p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=float)
    problem = pose_problem(pose)
    if problem == "non_finite_pose":
        raise ValueError("pose contains NaN or infinite values")
    norm = np.linalg.norm(q)
    if problem is not None:
        raise ValueError(f"pose quaternion is not unit length (norm {norm:.6g})")
    out = np.eye(4)
    out[:3, :3] = quaternion_to_rotation(q / norm)
    out[:3, 3] = p
    return out


def pose_to_xyz_xyzw(transform: Array) -> list[float]:
    """``[x, y, z, qx, qy, qz, qw]`` of a 4x4 transform (the order of ROS pose parameters)."""
    t = np.asarray(transform, dtype=float)
    w, x, y, z = rotation_to_quaternion(t[:3, :3])
    return [float(v) for v in (*t[:3, 3], x, y, z, w)]


def xyz_xyzw_to_pose(values: Any) -> Array:
    """4x4 transform of ``[x, y, z, qx, qy, qz, qw]``; ``ValueError`` unless 7 finite numbers with a non-zero quaternion."""
    v = np.asarray(list(values), dtype=float)
    if v.shape != (7,) or not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-9:
        raise ValueError(f"a pose needs 7 finite numbers x y z qx qy qz qw with a non-zero quaternion, got {list(values)}")
    q = v[3:] / np.linalg.norm(v[3:])
    out = np.eye(4)
    out[:3, :3] = quaternion_to_rotation([q[3], q[0], q[1], q[2]])
    out[:3, 3] = v[:3]
    return out


def covariance_to_matrix(values: Any) -> Array:
    """6x6 matrix from a row-major 36-element covariance field."""
    c = np.asarray(values, dtype=float)
    if c.size != 36:
        raise ValueError(f"covariance must have 36 elements, got {c.size}")
    return c.reshape(6, 6)


def image_to_array(msg: Any) -> NDArray[np.uint8]:
    """HxW (mono8) or HxWx3 (rgb8; bgr8 is reordered to RGB) view of a ``sensor_msgs/Image``.

    Raises ``ValueError`` naming the problem for unsupported encodings or a data size that does not
    match height x step.
    """
    channels = ENCODING_CHANNELS.get(msg.encoding)
    if channels is None:
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (use mono8, rgb8 or bgr8)")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or step < w * channels or data.size < h * step:
        raise ValueError(f"image data of {data.size} bytes does not match {w}x{h} {msg.encoding} with step {step}")
    rows = data[: h * step].reshape(h, step)[:, : w * channels]
    img = rows.reshape(h, w, channels) if channels == 3 else rows.reshape(h, w)
    if msg.encoding == "bgr8":
        img = img[:, :, ::-1]
    return img
