"""fusion: the sliding-window smoother as a node (a thin adapter over :class:`~pvo_fusion.FusionGraph`).

Subscribes ``/pvo/vo/relative`` (creates one state per frame), ``/pvo/sun/direction``,
``/pvo/dpc/correction``, ``/pvo/hydranet/rotation``, ``/gps/fix`` (the map origin for the sun
ephemeris) and, when asked, ``/ground_truth/odometry`` for the first pose. Publishes, per VO frame,
``/pvo/fusion/odometry`` (newest state, marginal covariance in ROS order), ``/pvo/fusion/pose``,
``/pvo/fusion/path`` (final fixed-lag estimates plus the live window; at most once per ``path_period``
seconds of message time, since the message grows with the trajectory: 32 ms to publish at KITTI 00's
4541 poses) and ``/pvo/fusion/status`` (window size, factors per type, counted outcomes, update time).
Parameters: the dotted fields of :class:`~pvo_fusion.config.FusionConfig` plus ``map_frame``,
``camera_frame``, ``publish_path``, ``path_period`` (s; 0: every frame),
``initial_pose`` (x y z qx qy qz qw, used when ``prior.source`` is ``given``) and
``initial_pose_from_ground_truth``.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from pvo_core.ephemeris import GeodeticOrigin
from pvo_core.lie import make_transform, quaternion_to_rotation
from pvo_core.msgconv import covariance_to_matrix, fill_pose, pose_to_matrix, stamp_to_nanoseconds
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import NavSatFix, NavSatStatus

from pvo_msgs.msg import RelativePose, SunDirection

from .config import FusionConfig, flatten, from_flat
from .graph import ACCEPTED, BUFFERED, FusionGraph
from .measurements import RelativeMeasurement, SunMeasurement
from .sun_reference import EphemerisSunReference, FixedSunReference, SunReference, TabulatedSunReference

STATUS_NAME = "pvo fusion"


def relative_from_msg(msg: RelativePose) -> RelativeMeasurement:
    return RelativeMeasurement(
        stamp=stamp_to_nanoseconds(msg.header.stamp),
        reference_stamp=stamp_to_nanoseconds(msg.reference_stamp),
        transform=pose_to_matrix(msg.pose.pose),
        covariance=covariance_to_matrix(msg.pose.covariance),
        rotation_only=bool(msg.rotation_only),
    )


def sun_from_msg(msg: SunDirection) -> SunMeasurement:
    return SunMeasurement(
        stamp=stamp_to_nanoseconds(msg.header.stamp),
        direction=np.array([msg.direction.x, msg.direction.y, msg.direction.z], dtype=float),
        covariance=np.asarray(msg.covariance, dtype=float).reshape(2, 2),
    )


class FusionNode(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__("fusion", **kwargs)
        defaults = flatten(FusionConfig())
        for name, value in defaults.items():
            self.declare_parameter(name, value)
        self.declare_parameter("map_frame", "map")
        self.declare_parameter("camera_frame", "camera_left_optical")
        self.declare_parameter("publish_path", True)
        self.declare_parameter("path_period", 1.0)
        self.declare_parameter("initial_pose", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        self.declare_parameter("initial_pose_from_ground_truth", False)
        self.config = from_flat({n: self.get_parameter(n).value for n in defaults})
        self.map_frame = str(self.get_parameter("map_frame").value)
        self.camera_frame = str(self.get_parameter("camera_frame").value)
        self.publish_path = bool(self.get_parameter("publish_path").value)
        self.path_period_ns = int(1e9 * float(self.get_parameter("path_period").value))
        if self.path_period_ns < 0:
            raise ValueError(f"path_period must be >= 0 s, got {self.get_parameter('path_period').value}")
        self._last_path_stamp: int | None = None
        self.graph = FusionGraph(self.config, self._static_sun_reference())
        self.latencies_ms: list[float] = []
        self._waiting_vo: list[RelativePose] = []
        self._ground_truth: dict[int, np.ndarray] = {}
        self._initial_known = self.config.prior.source == "identity"
        self._gps_fixes = 0
        self._final_path: list[PoseStamped] = []
        if self.config.prior.source == "given" and not bool(self.get_parameter("initial_pose_from_ground_truth").value):
            self.graph.set_initial_pose(_pose_from_parameter(self.get_parameter("initial_pose").value))
            self._initial_known = True

        # Inputs keep every message: a lagging fusion must not silently lose VO frames (a lost frame
        # would become a gap); outputs keep the last 200.
        inputs = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(RelativePose, "/pvo/vo/relative", self._on_vo, inputs)
        self.create_subscription(SunDirection, "/pvo/sun/direction", self._on_sun, inputs)
        self.create_subscription(RelativePose, "/pvo/dpc/correction", self._on_correction, inputs)
        self.create_subscription(RelativePose, "/pvo/hydranet/rotation", self._on_rotation, inputs)
        self.create_subscription(NavSatFix, "/gps/fix", self._on_gps, inputs)
        if not self._initial_known:
            self.create_subscription(Odometry, "/ground_truth/odometry", self._on_ground_truth, inputs)
        self.pub_odometry = self.create_publisher(Odometry, "/pvo/fusion/odometry", qos)
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "/pvo/fusion/pose", qos)
        self.pub_path = self.create_publisher(Path, "/pvo/fusion/path", 10)
        self.pub_status = self.create_publisher(DiagnosticArray, "/pvo/fusion/status", qos)
        self.add_on_set_parameters_callback(self._refuse_runtime_changes)

    def _static_sun_reference(self) -> SunReference | None:
        sun = self.config.inputs.sun
        if sun.reference == "fixed":
            return FixedSunReference(sun.reference_direction)
        if sun.reference == "table":
            if not sun.reference_table:
                raise ValueError("inputs.sun.reference is table but inputs.sun.reference_table is empty")
            return TabulatedSunReference.read(sun.reference_table)
        return None  # ephemeris: set at the first GPS fix

    def _refuse_runtime_changes(self, params: list) -> Any:
        from rcl_interfaces.msg import SetParametersResult

        return SetParametersResult(successful=False, reason="fusion parameters are read at start-up; restart the node")

    # --- inputs ---------------------------------------------------------------------------------
    def _on_gps(self, msg: NavSatFix) -> None:
        self._gps_fixes += 1
        if self.graph.sun_reference is not None or self.config.inputs.sun.reference != "ephemeris":
            return
        if msg.status.status < NavSatStatus.STATUS_FIX or not np.isfinite([msg.latitude, msg.longitude, msg.altitude]).all():
            self.graph.counts["gps.rejected.no_fix"] += 1
            return
        try:
            origin = GeodeticOrigin(msg.latitude, msg.longitude, msg.altitude)
        except ValueError as exc:
            self.graph.counts["gps.rejected.invalid"] += 1
            self.get_logger().warning(f"/gps/fix rejected: {exc}")
            return
        self.graph.sun_reference = EphemerisSunReference(origin, self.config.inputs.sun.ephemeris_time_offset)
        self.get_logger().info(f"map origin (ENU) at {origin.latitude:.7f}, {origin.longitude:.7f}, {origin.altitude:.2f} m")

    def _on_ground_truth(self, msg: Odometry) -> None:
        if self._initial_known:
            return
        self._ground_truth[stamp_to_nanoseconds(msg.header.stamp)] = pose_to_matrix(msg.pose.pose)
        self._try_start()

    def _try_start(self) -> None:
        if self._initial_known or not self._waiting_vo:
            return
        first = stamp_to_nanoseconds(self._waiting_vo[0].reference_stamp)
        pose = self._ground_truth.get(first)
        if pose is None:
            return
        self.graph.set_initial_pose(pose)
        self._initial_known = True
        self._ground_truth.clear()
        waiting, self._waiting_vo = self._waiting_vo, []
        for msg in waiting:
            self._on_vo(msg)

    def _on_vo(self, msg: RelativePose) -> None:
        received = time.perf_counter()
        if not self._initial_known:
            if not self._waiting_vo:
                self.get_logger().info(
                    f"waiting for /ground_truth/odometry at {msg.reference_stamp.sec}.{msg.reference_stamp.nanosec:09d} "
                    "for the first pose (prior.source: given, initial_pose_from_ground_truth: true)"
                )
            self._waiting_vo.append(msg)
            if len(self._waiting_vo) > self.config.max_pending:
                self._waiting_vo.pop(0)
                self.graph.counts["vo.dropped.waiting_for_initial_pose"] += 1
            self._try_start()
            return
        stamp = stamp_to_nanoseconds(msg.header.stamp)
        outcome = self.graph.add_vo(relative_from_msg(msg))
        if outcome == ACCEPTED:
            self._publish_estimate(stamp)
            self.latencies_ms.append(1e3 * (time.perf_counter() - received))
            due = self._last_path_stamp is None or stamp - self._last_path_stamp >= self.path_period_ns
            if self.publish_path and due:
                self._publish_path(stamp)
                self._last_path_stamp = stamp
        self._publish_status(stamp, outcome)

    def _on_sun(self, msg: SunDirection) -> None:
        self._other("sun", self.graph.add_sun, sun_from_msg(msg))

    def _on_correction(self, msg: RelativePose) -> None:
        self._other("correction", self.graph.add_correction, relative_from_msg(msg))

    def _on_rotation(self, msg: RelativePose) -> None:
        self._other("rotation", self.graph.add_rotation, relative_from_msg(msg))

    def _other(self, name: str, add: Any, measurement: Any) -> None:
        outcome = add(measurement)
        if outcome not in (ACCEPTED, BUFFERED):
            self._publish_status(measurement.stamp, f"{name}: {outcome}")

    # --- outputs --------------------------------------------------------------------------------
    def _publish_estimate(self, stamp: int) -> None:
        pose = self.graph.pose()
        covariance = self.graph.covariance()
        odom = Odometry()
        odom.header.stamp.sec, odom.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        odom.header.frame_id = self.map_frame
        odom.child_frame_id = self.camera_frame
        fill_pose(odom.pose.pose, pose)
        odom.pose.covariance = [float(v) for v in covariance.reshape(-1)]
        self.pub_odometry.publish(odom)
        stamped = PoseWithCovarianceStamped()
        stamped.header = odom.header
        stamped.pose = odom.pose
        self.pub_pose.publish(stamped)

    def _stamped(self, stamp: int, pose: np.ndarray) -> PoseStamped:
        out = PoseStamped()
        out.header.stamp.sec, out.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        out.header.frame_id = self.map_frame
        fill_pose(out.pose, pose)
        return out

    def _publish_path(self, stamp: int) -> None:
        self._final_path.extend(self._stamped(p.stamp, p.pose) for p in self.graph.drain_finished())
        path = Path()
        path.header.stamp.sec, path.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        path.header.frame_id = self.map_frame
        path.poses = self._final_path + [self._stamped(p.stamp, p.pose) for p in self.graph.window()]
        self.pub_path.publish(path)

    def _publish_status(self, stamp: int, message: str) -> None:
        status = DiagnosticStatus()
        status.name = STATUS_NAME
        status.hardware_id = self.map_frame
        problems = any(k.startswith(("solver.", "vo.gap", "vo.lost")) for k in self.graph.counts)
        status.level = DiagnosticStatus.WARN if (problems or message not in (ACCEPTED, BUFFERED)) else DiagnosticStatus.OK
        status.message = message
        values: dict[str, Any] = {
            "stamp": f"{stamp * 1e-9:.9f}",
            "window_size": self.graph.window_size,
            "pending": self.graph.pending(),
            "update_time_ms": f"{1e3 * self.graph.last_update_seconds:.3f}",
            "last_rejection": self.graph.last_rejection,
            "sun_reference": "none" if self.graph.sun_reference is None else type(self.graph.sun_reference).__name__,
        }
        values.update({f"factors.{k}": v for k, v in sorted(self.graph.factor_counts.items())})
        values.update({f"count.{k}": v for k, v in sorted(self.graph.counts.items()) if v})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp.sec, array.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        array.status = [status]
        self.pub_status.publish(array)


def _pose_from_parameter(values: Any) -> np.ndarray:
    v = np.asarray(list(values), dtype=float)
    if v.shape != (7,) or not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-9:
        raise ValueError(f"initial_pose needs 7 finite numbers x y z qx qy qz qw with a non-zero quaternion, got {list(values)}")
    q = v[3:] / np.linalg.norm(v[3:])
    return make_transform(quaternion_to_rotation([q[3], q[0], q[1], q[2]]), v[:3])


def main(args: list[str] | None = None) -> None:
    rclpy.init(args=args)
    try:
        node = FusionNode()
    except ValueError as exc:
        print(f"fusion: error: {exc}", file=sys.stderr)
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
