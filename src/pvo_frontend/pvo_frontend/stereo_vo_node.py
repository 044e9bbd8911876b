"""``stereo_vo``: the stereo VO node, a thin adapter around :class:`pvo_frontend.vo.StereoVO`.

Subscribes: /stereo/{left,right}/image_rect (mono8/rgb8/bgr8), /stereo/{left,right}/camera_info.
Publishes: /pvo/vo/relative (pvo_msgs/RelativePose, T_cur,prev with ROS-order covariance of a left
perturbation), /pvo/vo/odometry and /pvo/vo/path (pose of camera_left_optical in odom),
/pvo/vo/status (diagnostic_msgs/DiagnosticArray: features, inliers, iterations, stage times, lost).

Parameters: every field of :class:`pvo_frontend.vo.VOConfig` under its dotted name
(``solver.loss``, ``tracker.window`` ...; defaults in ``config/stereo_vo.yaml``), plus
``odom_frame``, ``camera_frame``, ``max_pending_frames`` and ``publish_path``.

Stereo pairs are synchronised on exact header stamps. Time comes only from message headers.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from pvo_core.camera import StereoCamera
from pvo_core.lie import se3_adjoint
from pvo_core.msgconv import fill_pose, image_to_array, stamp_to_nanoseconds
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from pvo_msgs.msg import RelativePose

from .vo import FrameResult, FrameStatus, StereoVO, VOConfig, flatten, from_flat

STATUS_NAME = "pvo/stereo_vo"
INPUT_QUEUE_DEPTH = 10  # messages per input topic held by DDS until the callbacks take them


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


class StereoVONode(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("stereo_vo", **kwargs)
        defaults = flatten(VOConfig())
        for name, value in defaults.items():
            self.declare_parameter(name, value)
        self.declare_parameter("odom_frame", "odom")
        self.declare_parameter("camera_frame", "camera_left_optical")
        self.declare_parameter("max_pending_frames", 30)
        self.declare_parameter("publish_path", True)
        values = {name: self.get_parameter(name).value for name in defaults}
        self.config = from_flat(values)  # ValueError names the bad parameter
        self.odom_frame = str(self.get_parameter("odom_frame").value)
        self.camera_frame = str(self.get_parameter("camera_frame").value)
        self.publish_path = bool(self.get_parameter("publish_path").value)
        self.add_on_set_parameters_callback(self._refuse_runtime_changes)

        self.vo: StereoVO | None = None
        self.camera_info: dict[str, CameraInfo] = {}
        self.max_pending = int(self.get_parameter("max_pending_frames").value)
        # Halves wait for their partner independently of max_pending_frames (pairs waiting for camera_info):
        # the executor may take two lefts before the first right.
        self.sync = StereoPairSynchroniser(max(INPUT_QUEUE_DEPTH, self.max_pending))
        self._waiting: list[tuple[int, Image, Image]] = []  # pairs that arrived before camera_info
        self.pose_covariance = np.zeros((6, 6))
        self.path = Path()
        self.path.header.frame_id = self.odom_frame
        self.counts = {"processed": 0, "lost": 0, "rejected": 0, "waiting_for_camera_info": 0}
        self._last_problem = ""
        self._previous_stamp_ns: int | None = None  # exact stamp of the last frame the VO accepted

        # The DDS queue must not be shallower than a short burst: a frame it overwrites is lost unreported,
        # while one the node drops (beyond max_pending_frames) is reported on /pvo/vo/status.
        depth = max(INPUT_QUEUE_DEPTH, self.max_pending)
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(Image, "/stereo/left/image_rect", lambda m: self._on_image("left", m), qos)
        self.create_subscription(Image, "/stereo/right/image_rect", lambda m: self._on_image("right", m), qos)
        self.create_subscription(CameraInfo, "/stereo/left/camera_info", lambda m: self._on_info("left", m), qos)
        self.create_subscription(CameraInfo, "/stereo/right/camera_info", lambda m: self._on_info("right", m), qos)
        self.pub_relative = self.create_publisher(RelativePose, "/pvo/vo/relative", 50)
        self.pub_odometry = self.create_publisher(Odometry, "/pvo/vo/odometry", 50)
        self.pub_path = self.create_publisher(Path, "/pvo/vo/path", 10)
        self.pub_status = self.create_publisher(DiagnosticArray, "/pvo/vo/status", 50)

    def _refuse_runtime_changes(self, params: list) -> Any:
        from rcl_interfaces.msg import SetParametersResult

        return SetParametersResult(
            successful=False, reason="stereo_vo parameters are read at start-up; restart the node to change them"
        )

    # --- inputs ---------------------------------------------------------------------------------
    def _on_info(self, side: str, msg: CameraInfo) -> None:
        self.camera_info[side] = msg
        if self.vo is None and len(self.camera_info) == 2:
            try:
                camera = camera_from_infos(self.camera_info["left"], self.camera_info["right"])
            except ValueError as exc:
                self._problem(f"camera_info rejected: {exc}")
                return
            self.vo = StereoVO(camera, self.config)
            waiting, self._waiting = self._waiting, []
            for pair in waiting:
                self._process(*pair)
            self.get_logger().info(
                f"stereo camera: f={camera.f:.2f} px, c=({camera.cu:.1f}, {camera.cv:.1f}) px, "
                f"baseline={camera.baseline:.4f} m, {camera.width}x{camera.height}"
            )

    def _on_image(self, side: str, msg: Image) -> None:
        pair = self.sync.add(side, stamp_to_nanoseconds(msg.header.stamp), msg)
        if pair is not None:
            self._process(*pair)

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
            self._problem(f"frame at {dropped_ns * 1e-9:.3f} s dropped: {what}")
            self._publish_status(None, dropped_ns, f"frame dropped: {what}")
            return
        try:
            left = image_to_array(left_msg)
            right = image_to_array(right_msg)
        except ValueError as exc:
            result = FrameResult(stamp_ns * 1e-9, FrameStatus.REJECTED, f"image rejected: {exc}", pose=self.vo.pose.copy())
        else:
            expected = (self.vo.camera.height, self.vo.camera.width)
            if self.vo.camera.width and left.shape[:2] != expected:
                result = FrameResult(
                    stamp_ns * 1e-9,
                    FrameStatus.REJECTED,
                    f"image size {left.shape[1]}x{left.shape[0]} differs from camera_info {expected[1]}x{expected[0]}",
                    pose=self.vo.pose.copy(),
                )
            else:
                result = self.vo.process(left, right, stamp_ns * 1e-9)
        self.counts["processed"] += 1
        if result.status is FrameStatus.REJECTED:
            self.counts["rejected"] += 1
            self._problem(f"frame at {stamp_ns * 1e-9:.9f} s rejected: {result.message}")
        elif result.status is FrameStatus.LOST:
            self.counts["lost"] += 1
            self._problem(f"tracking lost at {stamp_ns * 1e-9:.9f} s: {result.message}")
        if result.transform is not None and result.covariance is not None and self._previous_stamp_ns is not None:
            self._publish_estimate(stamp_ns, self._previous_stamp_ns, result)
        if result.status is not FrameStatus.REJECTED:
            self._previous_stamp_ns = stamp_ns
        self._publish_status(result, stamp_ns, result.message or result.status.value)

    def _publish_estimate(self, stamp_ns: int, reference_ns: int, result: FrameResult) -> None:
        assert result.transform is not None and result.covariance is not None
        rel = RelativePose()
        rel.header.stamp.sec, rel.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        rel.header.frame_id = self.camera_frame
        rel.reference_stamp.sec, rel.reference_stamp.nanosec = divmod(reference_ns, 1_000_000_000)
        fill_pose(rel.pose.pose, result.transform)
        rel.pose.covariance = [float(v) for v in result.covariance.reshape(-1)]
        rel.rotation_only = False
        self.pub_relative.publish(rel)

        # integrated pose: T_odom,k = T_odom,k-1 T_k,k-1^-1; a left perturbation xi of T_k,k-1 moves
        # T_odom,k by -Ad(T_odom,k) xi, so its covariance grows by Ad Sigma Ad^T
        adjoint = se3_adjoint(result.pose)
        self.pose_covariance = self.pose_covariance + adjoint @ result.covariance @ adjoint.T
        odom = Odometry()
        odom.header.stamp = rel.header.stamp
        odom.header.frame_id = self.odom_frame
        odom.child_frame_id = self.camera_frame
        fill_pose(odom.pose.pose, result.pose)
        odom.pose.covariance = [float(v) for v in self.pose_covariance.reshape(-1)]
        self.pub_odometry.publish(odom)
        if self.publish_path:
            stamped = PoseStamped()
            stamped.header = odom.header
            stamped.pose = odom.pose.pose
            self.path.header.stamp = rel.header.stamp
            self.path.poses.append(stamped)
            self.pub_path.publish(self.path)

    def _publish_status(self, result: FrameResult | None, stamp_ns: int, message: str) -> None:
        status = DiagnosticStatus()
        status.name = STATUS_NAME
        status.hardware_id = self.camera_frame
        status.message = message
        values: dict[str, Any] = {"stamp": f"{stamp_ns * 1e-9:.9f}", "dropped_unpaired": self.sync.dropped, **self.counts}
        if result is None:
            status.level = DiagnosticStatus.WARN
            values["lost"] = True
        else:
            status.level = {
                FrameStatus.FIRST: DiagnosticStatus.OK,
                FrameStatus.TRACKING: DiagnosticStatus.OK,
                FrameStatus.LOST: DiagnosticStatus.WARN,
                FrameStatus.REJECTED: DiagnosticStatus.ERROR,
            }[result.status]
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
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp.sec, array.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        array.status = [status]
        self.pub_status.publish(array)

    def _problem(self, text: str) -> None:
        # one line per distinct problem, not one per frame
        if text.split(" at ")[0] != self._last_problem.split(" at ")[0]:
            self.get_logger().warning(text)
        self._last_problem = text


def camera_from_infos(left: CameraInfo, right: CameraInfo) -> StereoCamera:
    """The rectified stereo model from both camera_info messages; ``ValueError`` naming the problem."""
    if (left.width, left.height) != (right.width, right.height):
        raise ValueError(f"left camera_info is {left.width}x{left.height} but right is {right.width}x{right.height}")
    p_left = np.asarray(left.p, dtype=float).reshape(3, 4)
    p_right = np.asarray(right.p, dtype=float).reshape(3, 4)
    if not (np.all(np.isfinite(p_left)) and np.all(np.isfinite(p_right))):
        raise ValueError("projection matrix P contains NaN")
    if p_left[0, 0] <= 0.0:
        raise ValueError("left camera_info P has no focal length (P[0] = 0): is the camera calibrated?")
    if p_right[0, 3] >= 0.0:
        raise ValueError(f"right camera_info P[3] = {p_right[0, 3]} must be -fx * baseline < 0 for a rectified stereo pair")
    return StereoCamera.from_projection_matrices(p_left, p_right, int(left.width), int(left.height))


def main(args: list[str] | None = None) -> None:
    rclpy.init(args=args)
    try:
        node = StereoVONode()
    except ValueError as exc:
        print(f"stereo_vo: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
