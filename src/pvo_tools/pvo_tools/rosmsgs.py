"""Builders of rosbags message objects (for writing bags) from plain numpy data."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import rotation_to_quaternion
from pvo_core.sun import unit_vector, vector_to_zenith_azimuth

from .typesys import project_typestore

#: Frames (ARCHITECTURE.md "Frames and time").
LEFT_FRAME = "camera_left_optical"
RIGHT_FRAME = "camera_right_optical"


def _t(name: str) -> Any:
    return project_typestore().types[name]


def stamp(stamp_ns: int) -> Any:
    return _t("builtin_interfaces/msg/Time")(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def header(stamp_ns: int, frame_id: str) -> Any:
    return _t("std_msgs/msg/Header")(stamp=stamp(stamp_ns), frame_id=frame_id)


def image(stamp_ns: int, frame_id: str, pixels: NDArray[np.uint8]) -> Any:
    """sensor_msgs/Image: mono8 for (H, W), rgb8 for (H, W, 3)."""
    if pixels.ndim == 2:
        encoding, step = "mono8", pixels.shape[1]
    else:
        encoding, step = "rgb8", pixels.shape[1] * 3
    return _t("sensor_msgs/msg/Image")(
        header=header(stamp_ns, frame_id),
        height=pixels.shape[0],
        width=pixels.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=np.ascontiguousarray(pixels).reshape(-1),
    )


def camera_info(stamp_ns: int, frame_id: str, projection: NDArray[np.float64], width: int, height: int) -> Any:
    """sensor_msgs/CameraInfo of a rectified camera with its true 3x4 projection matrix."""
    p = np.asarray(projection, dtype=float).reshape(3, 4)
    k = p[:, :3].copy()
    types = project_typestore().types
    roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return types["sensor_msgs/msg/CameraInfo"](
        header=header(stamp_ns, frame_id),
        height=int(height),
        width=int(width),
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=k.reshape(-1),
        r=np.eye(3).reshape(-1),
        p=p.reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def pose(transform: NDArray[np.float64]) -> Any:
    types = project_typestore().types
    w, x, y, z = rotation_to_quaternion(transform[:3, :3])
    tx, ty, tz = transform[:3, 3]
    return types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=float(tx), y=float(ty), z=float(tz)),
        orientation=types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def odometry(
    stamp_ns: int,
    frame_id: str,
    child_frame_id: str,
    transform: NDArray[np.float64],
    pose_covariance: NDArray[np.float64],
    twist_covariance: NDArray[np.float64],
) -> Any:
    types = project_typestore().types
    vector3 = types["geometry_msgs/msg/Vector3"]
    twist = types["geometry_msgs/msg/Twist"](linear=vector3(x=0.0, y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=0.0))
    return types["nav_msgs/msg/Odometry"](
        header=header(stamp_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose(transform), covariance=pose_covariance.reshape(-1)),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=twist_covariance.reshape(-1)),
    )


def sun_direction(
    stamp_ns: int, frame_id: str, direction: NDArray[np.float64], covariance: NDArray[np.float64] | None = None
) -> Any:
    """pvo_msgs/SunDirection; zenith/azimuth from thesis eq. 5.7; covariance zeros = unknown."""
    types = project_typestore().types
    zenith, azimuth = vector_to_zenith_azimuth(direction)
    d = unit_vector(direction)
    return types["pvo_msgs/msg/SunDirection"](
        header=header(stamp_ns, frame_id),
        direction=types["geometry_msgs/msg/Vector3"](x=float(d[0]), y=float(d[1]), z=float(d[2])),
        zenith=float(zenith),
        azimuth=float(azimuth),
        covariance=np.zeros(4) if covariance is None else np.asarray(covariance, dtype=float).reshape(4),
    )


def relative_pose(
    stamp_ns: int,
    reference_ns: int,
    frame_id: str,
    transform: NDArray[np.float64],
    covariance: NDArray[np.float64],
    rotation_only: bool = False,
) -> Any:
    """pvo_msgs/RelativePose: T_to,from (stamp = t_to, reference_stamp = t_from), ROS-order left covariance."""
    types = project_typestore().types
    return types["pvo_msgs/msg/RelativePose"](
        header=header(stamp_ns, frame_id),
        reference_stamp=stamp(reference_ns),
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose(transform), covariance=np.asarray(covariance, dtype=float).reshape(-1)
        ),
        rotation_only=bool(rotation_only),
    )


def imu(stamp_ns: int, frame_id: str, angular_velocity: NDArray[np.float64], specific_force: NDArray[np.float64]) -> Any:
    """sensor_msgs/Imu without orientation (orientation_covariance[0] = -1, as REP 145 says)."""
    types = project_typestore().types
    vector3 = types["geometry_msgs/msg/Vector3"]
    w, f = np.asarray(angular_velocity, dtype=float), np.asarray(specific_force, dtype=float)
    unknown = np.zeros(9)
    unknown[0] = -1.0
    return types["sensor_msgs/msg/Imu"](
        header=header(stamp_ns, frame_id),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=unknown,
        angular_velocity=vector3(x=float(w[0]), y=float(w[1]), z=float(w[2])),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vector3(x=float(f[0]), y=float(f[1]), z=float(f[2])),
        linear_acceleration_covariance=np.zeros(9),
    )


def nav_sat_fix(stamp_ns: int, frame_id: str, latitude: float, longitude: float, altitude: float, sigma: float = 0.0) -> Any:
    """sensor_msgs/NavSatFix with a fix (GPS service) and a diagonal position covariance."""
    types = project_typestore().types
    status = types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
    covariance = np.diag([sigma**2] * 3).reshape(-1) if sigma > 0 else np.zeros(9)
    return types["sensor_msgs/msg/NavSatFix"](
        header=header(stamp_ns, frame_id),
        status=status,
        latitude=float(latitude),
        longitude=float(longitude),
        altitude=float(altitude),
        position_covariance=covariance,
        position_covariance_type=2 if sigma > 0 else 0,
    )
