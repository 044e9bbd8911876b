"""``stereo_vo``: the stereo VO node, a thin adapter around :class:`pvo_frontend.vo.StereoVO`.

Subscribes: /stereo/{left,right}/image_rect (mono8/rgb8/bgr8), /stereo/{left,right}/camera_info, and
/imu/data (sensor_msgs/Imu) when the PROBE model (``probe.model``) has IMU predictors: the reading nearest
each frame (within 50 ms) feeds them; a frame without one is weighed by the model's other predictors alone.
Publishes: /pvo/vo/relative (pvo_msgs/RelativePose, T_cur,prev with ROS-order covariance of a left
perturbation), /pvo/vo/odometry and /pvo/vo/path (pose of camera_left_optical in odom),
/pvo/vo/status (diagnostic_msgs/DiagnosticArray: features, inliers, iterations, stage times, lost).

Parameters: every field of :class:`pvo_frontend.vo.VOConfig` under its dotted name
(``solver.loss``, ``tracker.window`` ...) plus those of :class:`StereoVONodeConfig`; defaults in
``config/stereo_vo.yaml``. ``publish_path`` and ``path_period`` can be changed at run time, the rest only at start-up.

Stereo pairs are synchronised on exact header stamps. Time comes only from message headers.
"""

from __future__ import annotations

import sys
from collections import deque
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from pvo_core.camera import StereoCamera
from pvo_core.msgconv import fill_pose, fill_stamp, image_to_array, stamp_to_nanoseconds
from sensor_msgs.msg import CameraInfo, Image, Imu

from pvo_msgs.msg import RelativePose
from pvo_ros import ERROR, OK, SENSOR_QUEUE_DEPTH, WARN, PvoNode, measurements, reliable, run_node

from .probe.model import ProbeModel, resolve_model
from .stereo_vo_settings import StereoVONodeConfig
from .vo import FrameResult, FrameStatus, StereoVO, VOConfig

LEVELS = {FrameStatus.FIRST: OK, FrameStatus.TRACKING: OK, FrameStatus.LOST: WARN, FrameStatus.REJECTED: ERROR}


IMU_HISTORY = 400  # IMU messages kept (2 s at 200 Hz) to find the one nearest a frame
IMU_TOLERANCE_NS = 50_000_000


class StereoPairSynchroniser:
    """Pairs left/right messages with identical stamps; keeps at most ``capacity`` unmatched of each."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._left: dict[int, Any] = {}
        self._right: dict[int, Any] = {}
        self.dropped = 0

    def add(self, side: str, stamp_ns: int, msg: Any) -> tuple[int, Any, Any] | None:
        mine, other = (self._left, self._right) if side == "left" else (self._right, self._left)
        if stamp_ns in other:
            partner = other.pop(stamp_ns)
            # anything older than a completed pair can no longer be matched
            for buffer in (self._left, self._right):
                for stale in [s for s in buffer if s < stamp_ns]:
                    del buffer[stale]
                    self.dropped += 1
            return (stamp_ns, msg, partner) if side == "left" else (stamp_ns, partner, msg)
        mine[stamp_ns] = msg
        while len(mine) > self.capacity:
            del mine[min(mine)]
            self.dropped += 1
        return None


class FrameLedger:
    """Every camera frame announces itself with a left camera_info; a frame whose stereo pair never reaches the
    node (lost in transport, dropped by a full queue) is counted when a later pair arrives."""

    def __init__(self, capacity: int = 256) -> None:
        self._announced: deque[int] = deque()
        self._arrived: deque[int] = deque(maxlen=capacity)
        self._reported_late: deque[int] = deque(maxlen=capacity)
        self._capacity = capacity

    def announce(self, stamp_ns: int) -> list[int]:
        """Record a camera_info; returns ``[stamp]`` when it comes after a later pair was processed (its own
        pair can no longer be processed: it would go back in time) — unless that pair turns up after all
        (camera_info and images are separate topics), see :meth:`recover`."""
        if stamp_ns in self._arrived or (self._announced and stamp_ns <= self._announced[-1]):
            return []
        if self._arrived and stamp_ns < max(self._arrived):
            self._reported_late.append(stamp_ns)
            return [stamp_ns]
        self._announced.append(stamp_ns)
        while len(self._announced) > self._capacity:
            self._announced.popleft()
        return []

    def recover(self, stamp_ns: int) -> bool:
        """True (once) when the pair of ``stamp_ns`` arrives after its late camera_info was reported missing."""
        if stamp_ns in self._reported_late:
            self._reported_late.remove(stamp_ns)
            return True
        return False

    def arrived(self, stamp_ns: int) -> list[int]:
        """Record a pair; returns the announced stamps before it that never arrived."""
        self._arrived.append(stamp_ns)
        missing = []
        while self._announced and self._announced[0] <= stamp_ns:
            announced = self._announced.popleft()
            if announced != stamp_ns and announced not in self._arrived:
                missing.append(announced)
        return missing


class StereoVONode(PvoNode[VOConfig, StereoVONodeConfig]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(
            "stereo_vo",
            VOConfig(),
            StereoVONodeConfig(),
            runtime={"publish_path": lambda _: None, "path_period": lambda _: None},
            status_topic="/pvo/vo/status",
            **kwargs,
        )

        self.vo: StereoVO | None = None
        self.camera_info: dict[str, CameraInfo] = {}
        # Halves wait for their partner independently of max_pending_frames (pairs waiting for camera_info):
        # the executor may take two lefts before the first right.
        self.sync = StereoPairSynchroniser(max(SENSOR_QUEUE_DEPTH, self.max_pending))
        self._waiting: list[tuple[int, Image, Image]] = []  # pairs that arrived before camera_info
        self.path_poses: deque[PoseStamped] = deque(maxlen=self.settings.path_max_poses or None)
        self._last_path_ns: int | None = None
        self.counts = {"processed": 0, "lost_frames": 0, "rejected": 0, "waiting_for_camera_info": 0, "missing_images": 0}
        self.counts["skipped_overload"] = 0
        self.ledger = FrameLedger()
        self._previous_stamp_ns: int | None = None  # exact stamp of the last frame the VO accepted
        # PROBE: the model is loaded here so that a bad probe.model stops the node at start-up with one line
        self.probe = ProbeModel.load(resolve_model(self.config.probe.model)) if self.config.probe.model else None
        self._imu: deque[tuple[int, np.ndarray]] = deque(maxlen=IMU_HISTORY)

        # The DDS queue must not be shallower than a short burst: a frame it overwrites is lost unreported,
        # while one the node drops (beyond max_pending_frames) is reported on /pvo/vo/status.
        qos = reliable(max(SENSOR_QUEUE_DEPTH, self.max_pending))
        self.create_subscription(Image, "/stereo/left/image_rect", lambda m: self._on_image("left", m), qos)
        self.create_subscription(Image, "/stereo/right/image_rect", lambda m: self._on_image("right", m), qos)
        self.create_subscription(CameraInfo, "/stereo/left/camera_info", lambda m: self._on_info("left", m), qos)
        self.create_subscription(CameraInfo, "/stereo/right/camera_info", lambda m: self._on_info("right", m), qos)
        if self.probe is not None and self.probe.predictors.imu:
            self.counts["imu_rejected"] = 0
            self.create_subscription(Imu, "/imu/data", self._on_imu, reliable(IMU_HISTORY))
        self.pub_relative = self.create_publisher(RelativePose, "/pvo/vo/relative", measurements())
        self.pub_odometry = self.create_publisher(Odometry, "/pvo/vo/odometry", reliable(50))
        self.pub_path = self.create_publisher(Path, "/pvo/vo/path", reliable(10))

    @property
    def max_pending(self) -> int:
        return self.settings.max_pending_frames

    def close(self) -> None:
        """One summary line at shutdown: what became of every frame that reached the node."""
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items())
        # stderr, not the logger: at shutdown the context (and its /rosout publisher) may already be gone
        print(f"stereo_vo: {counts}, dropped_unpaired {self.sync.dropped}", file=sys.stderr, flush=True)

    # --- inputs ---------------------------------------------------------------------------------
    def _on_info(self, side: str, msg: CameraInfo) -> None:
        if side == "left":
            self._count_missing(self.ledger.announce(stamp_to_nanoseconds(msg.header.stamp)))
        self.camera_info[side] = msg
        if self.vo is None and len(self.camera_info) == 2:
            try:
                camera = StereoCamera.from_camera_infos(self.camera_info["left"], self.camera_info["right"])
            except ValueError as exc:
                self.problem(f"camera_info rejected: {exc}")
                return
            self.vo = StereoVO(camera, self.config, self.probe.feature_noise() if self.probe is not None else None)
            waiting, self._waiting = self._waiting, []
            for pair in waiting:
                self._process(*pair)
            self.get_logger().info(
                f"stereo camera: f={camera.f:.2f} px, c=({camera.cu:.1f}, {camera.cv:.1f}) px, "
                f"baseline={camera.baseline:.4f} m, {camera.width}x{camera.height}"
            )

    def _on_imu(self, msg: Imu) -> None:
        w, a = msg.angular_velocity, msg.linear_acceleration
        reading = np.array([w.x, w.y, w.z, a.x, a.y, a.z], dtype=float)
        stamp_ns = stamp_to_nanoseconds(msg.header.stamp)
        if not np.all(np.isfinite(reading)):
            self.counts["imu_rejected"] += 1
            self.problem(f"/imu/data at {stamp_ns * 1e-9:.3f} s rejected: not finite")
            return
        self._imu.append((stamp_ns, reading))

    def _imu_at(self, stamp_ns: int) -> np.ndarray | None:
        """The IMU reading nearest the frame, within IMU_TOLERANCE_NS; None without one (PROBE then weighs the
        frame by its other predictors alone)."""
        if not self._imu:
            return None
        stamp, reading = min(self._imu, key=lambda item: abs(item[0] - stamp_ns))
        return reading if abs(stamp - stamp_ns) <= IMU_TOLERANCE_NS else None

    def _on_image(self, side: str, msg: Image) -> None:
        pair = self.sync.add(side, stamp_to_nanoseconds(msg.header.stamp), msg)
        if pair is not None:
            if self.ledger.recover(pair[0]):  # counted as missing when its camera_info came late: it did arrive
                self.counts["missing_images"] -= 1
            self._count_missing(self.ledger.arrived(pair[0]))
            self._process(*pair)

    def _count_missing(self, missing: list[int]) -> None:
        if missing:
            self.counts["missing_images"] += len(missing)
            self.problem(
                f"{len(missing)} frame(s) missing at {missing[0] * 1e-9:.3f} s: the camera_info arrived, "
                "the stereo pair never reached the node"
            )

    # --- processing -----------------------------------------------------------------------------
    def _process(self, stamp_ns: int, left_msg: Image, right_msg: Image) -> None:
        if self.vo is None:
            # keep the pair until camera_info arrives (it may come just after the first images)
            self._waiting.append((stamp_ns, left_msg, right_msg))
            if len(self._waiting) <= self.max_pending:
                return
            dropped_ns = self._waiting.pop(0)[0]
            missing = [f"/stereo/{s}/camera_info" for s in ("left", "right") if s not in self.camera_info]
            what = f"no camera_info on {' and '.join(missing)}" if missing else "camera_info was rejected"
            self.counts["waiting_for_camera_info"] += 1
            self.problem(f"frame at {dropped_ns * 1e-9:.3f} s dropped: {what}")
            self._publish_status(None, dropped_ns, f"frame dropped: {what}")
            return
        stamp = stamp_ns * 1e-9
        if self._behind(stamp_ns):
            return
        try:
            left = image_to_array(left_msg)
            right = image_to_array(right_msg)
        except ValueError as exc:
            result = self.vo.reject(stamp, f"image rejected: {exc}")
        else:
            expected = (self.vo.camera.height, self.vo.camera.width)
            if left.shape != right.shape:
                result = self.vo.reject(
                    stamp, f"stereo images differ in size: left {_describe(left_msg)}, right {_describe(right_msg)}"
                )
            elif self.vo.camera.width and left.shape[:2] != expected:
                result = self.vo.reject(
                    stamp,
                    f"image size {left.shape[1]}x{left.shape[0]} differs from camera_info {expected[1]}x{expected[0]}",
                )
            else:
                result = self.vo.process(left, right, stamp, self._imu_at(stamp_ns) if self._imu else None)
        self.counts["processed"] += 1
        if result.status is FrameStatus.REJECTED:
            self.counts["rejected"] += 1
            self.problem(f"frame at {stamp:.9f} s rejected: {result.message}")
        elif result.status is FrameStatus.LOST:
            self.counts["lost_frames"] += 1
            self.problem(f"tracking lost at {stamp:.9f} s: {result.message}")
        if result.transform is not None and result.covariance is not None and self._previous_stamp_ns is not None:
            self._publish_estimate(stamp_ns, self._previous_stamp_ns, result)
        if result.status is not FrameStatus.REJECTED:
            self._previous_stamp_ns = stamp_ns
        self._publish_status(result, stamp_ns, result.message or result.status.value)

    def _behind(self, stamp_ns: int) -> bool:
        """Skip the frame deliberately when it lags the clock by more than max_lag (the node cannot keep up)."""
        max_lag = self.settings.max_lag
        if max_lag <= 0.0:
            return False
        lag = (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9
        if lag <= max_lag:
            return False
        self.counts["skipped_overload"] += 1
        self.problem(f"frame at {stamp_ns * 1e-9:.3f} s skipped: {lag:.2f} s behind the clock (max_lag {max_lag:g} s)")
        self._publish_status(None, stamp_ns, f"frame skipped: {lag:.2f} s behind the clock (overload)")
        return True

    def _publish_estimate(self, stamp_ns: int, reference_ns: int, result: FrameResult) -> None:
        assert result.transform is not None and result.covariance is not None
        settings = self.settings
        rel = RelativePose()
        fill_stamp(rel.header.stamp, stamp_ns)
        rel.header.frame_id = settings.camera_frame
        fill_stamp(rel.reference_stamp, reference_ns)
        fill_pose(rel.pose.pose, result.transform)
        rel.pose.covariance = [float(v) for v in result.covariance.reshape(-1)]
        rel.rotation_only = False
        self.pub_relative.publish(rel)

        odom = Odometry()
        odom.header.stamp = rel.header.stamp
        odom.header.frame_id = settings.odom_frame
        odom.child_frame_id = settings.camera_frame
        fill_pose(odom.pose.pose, result.pose)
        odom.pose.covariance = [float(v) for v in result.pose_covariance.reshape(-1)]
        self.pub_odometry.publish(odom)
        stamped = PoseStamped()
        stamped.header = odom.header
        stamped.pose = odom.pose.pose
        self.path_poses.append(stamped)
        due = self._last_path_ns is None or stamp_ns - self._last_path_ns >= int(1e9 * settings.path_period)
        if settings.publish_path and due:
            path = Path()
            path.header = odom.header
            path.poses = list(self.path_poses)
            self.pub_path.publish(path)
            self._last_path_ns = stamp_ns

    def _publish_status(self, result: FrameResult | None, stamp_ns: int, message: str) -> None:
        values: dict[str, Any] = {"stamp": f"{stamp_ns * 1e-9:.9f}", "dropped_unpaired": self.sync.dropped, **self.counts}
        if result is None:
            level = WARN
            values["lost"] = True
        else:
            level = LEVELS[result.status]
            values.update(
                status=result.status.value,
                lost=result.status is FrameStatus.LOST,
                features=result.features,
                tracked=result.tracked,
                inliers=result.inliers,
                ransac_iterations=result.ransac_iterations,
                gn_iterations=result.gn_iterations,
            )
            values.update({f"time_{k}_ms": f"{1e3 * v:.3f}" for k, v in result.timings.items()})
        self.publish_status(stamp_ns, self.settings.camera_frame, level, message, values)


def _describe(msg: Image) -> str:
    return f"{msg.width}x{msg.height} {msg.encoding}"


def main(args: list[str] | None = None) -> None:
    run_node(StereoVONode, "stereo_vo", args)


if __name__ == "__main__":
    main()
