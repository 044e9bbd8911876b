"""The ``stereo_vo`` node's own parameters, beside the VO's (:class:`pvo_frontend.vo.VOConfig`): ROS-free, so that
offline tools (``pvo vo --params-file``) know which entries of a node's params file are not the VO's."""

from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass(frozen=True)
class StereoVONodeConfig:
    """The node's own parameters: output frames, how many image pairs may wait for camera_info, the path
    (``/pvo/vo/path`` at most once per ``path_period`` seconds of message time, 0: every frame; at most
    ``path_max_poses`` newest poses, 0: all — a long run's memory and publishing time stay bounded).

    max_lag: under overload, skip a frame whose stamp is more than this many seconds behind the node's clock
    (ROS time: ``/clock`` with ``use_sim_time``, else the system clock for live sensors), counted as
    ``skipped_overload`` and reported; 0 never skips (for replays without ``/clock``, whose stamps are old)."""

    odom_frame: str = "odom"
    camera_frame: str = "camera_left_optical"
    max_pending_frames: int = 100
    publish_path: bool = True
    path_period: float = 1.0
    path_max_poses: int = 500
    max_lag: float = 0.0

    def __post_init__(self) -> None:
        if not self.max_lag >= 0.0:
            raise ValueError(f"max_lag must be >= 0 s (0: never skip), got {self.max_lag}")
        if self.max_pending_frames < 1:
            raise ValueError(f"max_pending_frames must be >= 1, got {self.max_pending_frames}")
        if not self.path_period >= 0.0:
            raise ValueError(f"path_period must be >= 0 s, got {self.path_period}")
        if self.path_max_poses < 0:
            raise ValueError(f"path_max_poses must be >= 0 (0: the whole trajectory), got {self.path_max_poses}")
        if not self.odom_frame or not self.camera_frame:
            raise ValueError("odom_frame and camera_frame must not be empty")


def node_setting_names() -> frozenset[str]:
    """The undotted names a ``stereo_vo`` params file may hold besides the VO's dotted ones (and ROS's own)."""
    return frozenset(f.name for f in fields(StereoVONodeConfig)) | {"use_sim_time"}
