"""A recorded stereo bag read into memory: stereo pairs, camera_info, ground truth and ground-truth sun, by stamp."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.msgconv import pose_to_matrix, stamp_to_nanoseconds

from .bagio import iter_messages, open_bag
from .errors import BagError
from .typesys import project_typestore

Array = NDArray[np.float64]
LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"
LEFT_INFO, RIGHT_INFO = "/stereo/left/camera_info", "/stereo/right/camera_info"
GROUND_TRUTH, GROUND_TRUTH_SUN = "/ground_truth/odometry", "/ground_truth/sun_direction"
GPS = "/gps/fix"


@dataclass
class StereoSample:
    """Messages of a stereo bag (deserialised, rosbags types): pairs by stamp (ns), the first camera_info of each
    side, ground-truth poses T_world,cam, camera-frame sun vectors and GPS fixes (latitude, longitude in
    degrees, altitude in m) by stamp."""

    path: Path
    pairs: dict[int, tuple[Any, Any]]
    left_info: Any
    right_info: Any
    ground_truth: dict[int, Array] = field(default_factory=dict)
    sun: dict[int, Array] = field(default_factory=dict)
    gps: dict[int, Array] = field(default_factory=dict)

    @property
    def frame_stamps(self) -> NDArray[np.int64]:
        return np.array(sorted(self.pairs), dtype=np.int64)

    def ground_truth_at(self, stamps: NDArray[np.int64]) -> Array:
        """Ground-truth poses (N, 4, 4) at ``stamps``; ``BagError`` naming a stamp without one."""
        missing = [int(s) for s in stamps if int(s) not in self.ground_truth]
        if missing:
            raise BagError(f"{self.path}: no {GROUND_TRUTH} at {len(missing)} frame stamp(s), first {missing[0]} ns")
        return np.array([self.ground_truth[int(s)] for s in stamps])


def read_stereo_sample(path: Path) -> StereoSample:
    """Every stereo pair, the camera_info, the ground truth and its sun of a bag; ``BagError`` for what is missing."""
    store = project_typestore()
    lefts: dict[int, Any] = {}
    rights: dict[int, Any] = {}
    infos: dict[str, Any] = {}
    ground_truth: dict[int, Array] = {}
    sun: dict[int, Array] = {}
    gps: dict[int, Array] = {}
    wanted = {LEFT, RIGHT, LEFT_INFO, RIGHT_INFO, GROUND_TRUTH, GROUND_TRUTH_SUN, GPS}
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, _, raw in iter_messages(reader, connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            stamp = stamp_to_nanoseconds(msg.header.stamp)
            if connection.topic == LEFT:
                lefts[stamp] = msg
            elif connection.topic == RIGHT:
                rights[stamp] = msg
            elif connection.topic in (LEFT_INFO, RIGHT_INFO):
                infos.setdefault(connection.topic, msg)
            elif connection.topic == GROUND_TRUTH:
                ground_truth[stamp] = pose_to_matrix(msg.pose.pose)
            elif connection.topic == GPS:
                if msg.status.status >= 0:  # STATUS_NO_FIX is -1
                    gps[stamp] = np.array([msg.latitude, msg.longitude, msg.altitude])
            else:
                sun[stamp] = np.array([msg.direction.x, msg.direction.y, msg.direction.z])
    for topic in (LEFT_INFO, RIGHT_INFO):
        if topic not in infos:
            raise BagError(f"{path}: no {topic} in the bag")
    pairs = {s: (lefts[s], rights[s]) for s in sorted(set(lefts) & set(rights))}
    if len(pairs) < 2:
        raise BagError(f"{path}: fewer than 2 stereo pairs on {LEFT} and {RIGHT}")
    return StereoSample(Path(path), pairs, infos[LEFT_INFO], infos[RIGHT_INFO], ground_truth, sun, gps)
