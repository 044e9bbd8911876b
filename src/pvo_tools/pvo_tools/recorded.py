"""Estimates read back from a recorded bag: odometry topics and the last message of a path topic."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.msgconv import covariance_to_matrix, pose_to_matrix, stamp_to_nanoseconds

from .bagio import iter_messages, open_bag
from .errors import PvoError
from .typesys import project_typestore

Array = NDArray[np.float64]


@dataclass
class RecordedPoses:
    """Poses (N, 4, 4) by header stamp (N,) in ns, with their 6x6 covariances (ROS order) when recorded."""

    stamps: NDArray[np.int64]
    poses: Array
    covariances: Array | None

    def at(self, stamps: NDArray[np.int64]) -> tuple[Array, Array | None]:
        """Poses (and covariances) at ``stamps``, NaN where nothing was recorded."""
        index = {int(s): i for i, s in enumerate(self.stamps)}
        poses = np.full((len(stamps), 4, 4), np.nan)
        covs = None if self.covariances is None else np.full((len(stamps), 6, 6), np.nan)
        for k, stamp in enumerate(stamps):
            i = index.get(int(stamp))
            if i is not None:
                poses[k] = self.poses[i]
                if covs is not None and self.covariances is not None:
                    covs[k] = self.covariances[i]
        return poses, covs


def read_recorded(bag: Path, topics: list[str]) -> dict[str, RecordedPoses]:
    """Every ``nav_msgs/Odometry`` or ``pvo_msgs/RelativePose`` message of the given topics (a relative pose:
    T_to,from at its header stamp, the later frame), and the last ``nav_msgs/Path`` message of each path topic,
    by stamp. A topic with no message is missing from the result."""
    store = project_typestore()
    odometry: dict[str, list[tuple[int, Array, Array]]] = {}
    last_path: dict[str, tuple] = {}
    with open_bag(bag) as reader:
        for connection, _, raw in iter_messages(reader):
            if connection.topic not in topics:
                continue
            if connection.msgtype == "nav_msgs/msg/Path":
                last_path[connection.topic] = (connection, raw)
            elif connection.msgtype in ("nav_msgs/msg/Odometry", "pvo_msgs/msg/RelativePose"):
                msg = store.deserialize_cdr(raw, connection.msgtype)
                odometry.setdefault(connection.topic, []).append(
                    (
                        stamp_to_nanoseconds(msg.header.stamp),
                        pose_to_matrix(msg.pose.pose),
                        covariance_to_matrix(msg.pose.covariance),
                    )
                )
            else:
                raise PvoError(f"{bag}: {connection.topic} is {connection.msgtype}, not an odometry, relative pose or path topic")
    out: dict[str, RecordedPoses] = {}
    for topic, rows in odometry.items():
        out[topic] = RecordedPoses(
            np.array([r[0] for r in rows], dtype=np.int64), np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
        )
    for topic, (connection, raw) in last_path.items():
        path = store.deserialize_cdr(raw, connection.msgtype)
        out[topic] = RecordedPoses(
            np.array([stamp_to_nanoseconds(p.header.stamp) for p in path.poses], dtype=np.int64),
            np.array([pose_to_matrix(p.pose) for p in path.poses]).reshape(-1, 4, 4),
            None,
        )
    return out


def read_arrivals(bag: Path, topic: str = "/pvo/fusion/status") -> dict[int, list[str]]:
    """VO frame stamp (ns) -> ``kind@stamp_ns`` of the measurements the fusion node took since the frame before,
    in the order it took them (its status's ``arrivals``); empty without such statuses."""
    store = project_typestore()
    arrivals: dict[int, list[str]] = {}
    with open_bag(bag) as reader:
        for connection, _, raw in iter_messages(reader):
            if connection.topic != topic:
                continue
            msg = store.deserialize_cdr(raw, connection.msgtype)
            for status in msg.status:
                values = {v.key: v.value for v in status.values}
                if "arrivals" in values:
                    arrivals[stamp_to_nanoseconds(msg.header.stamp)] = [k for k in values["arrivals"].split(",") if k]
    return arrivals


def read_header_stamps(bag: Path, topic: str) -> list[int]:
    """Header stamps (ns) of every message on ``topic``, in recording order."""
    store = project_typestore()
    stamps = []
    with open_bag(bag) as reader:
        for connection, _, raw in iter_messages(reader):
            if connection.topic == topic:
                stamps.append(stamp_to_nanoseconds(store.deserialize_cdr(raw, connection.msgtype).header.stamp))
    return stamps


def read_windows(bag: Path, topic: str) -> list[tuple[int, int]]:
    """(reference_stamp, header stamp) in ns of every ``RelativePose`` on ``topic``, in recording order: the frames
    each measurement spans."""
    store = project_typestore()
    windows = []
    with open_bag(bag) as reader:
        for connection, _, raw in iter_messages(reader):
            if connection.topic == topic:
                msg = store.deserialize_cdr(raw, connection.msgtype)
                windows.append((stamp_to_nanoseconds(msg.reference_stamp), stamp_to_nanoseconds(msg.header.stamp)))
    return windows
