"""fusion: the sliding-window smoother as a node (a thin adapter over :class:`~pvo_fusion.FusionGraph`).

Subscribes ``/pvo/vo/relative`` (creates one state per frame), ``/pvo/sun/direction``,
``/pvo/dpc/correction``, ``/pvo/hydranet/rotation``, ``/gps/fix`` (the map origin for the sun
ephemeris) and, when asked, ``/ground_truth/odometry`` for the first pose. Publishes, per VO frame,
``/pvo/fusion/odometry`` (newest state, marginal covariance in ROS order), ``/pvo/fusion/pose``,
``/pvo/fusion/path`` (final fixed-lag estimates plus the live window; at most once per ``path_period``
seconds of message time, since the message grows with the trajectory: 32 ms to publish at KITTI 00's
4541 poses) and ``/pvo/fusion/status`` (window size, factors per type, counted outcomes, update time).
Parameters: the dotted fields of :class:`~pvo_fusion.config.FusionConfig` plus those of
:class:`FusionNodeConfig`; defaults in ``config/fusion.yaml``. ``publish_path`` and ``path_period`` can be
changed at run time, the rest only at start-up.
"""

from __future__ import annotations

import os
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from pvo_core.ephemeris import GeodeticOrigin
from pvo_core.msgconv import (
    covariance_to_matrix,
    fill_pose,
    fill_stamp,
    pose_problem,
    pose_to_matrix,
    stamp_to_nanoseconds,
    xyz_xyzw_to_pose,
)
from rclpy.qos import DurabilityPolicy
from sensor_msgs.msg import NavSatFix, NavSatStatus

from pvo_msgs.msg import RelativePose, SunDirection
from pvo_ros import OK, WARN, PvoNode, every_message, kept_history_durability, reliable, run_node

from .checkpoint import FusionCheckpoint
from .config import FusionConfig
from .graph import ACCEPTED, BUFFERED, GATED_WARNING_SECONDS, FusionGraph
from .measurements import RelativeMeasurement, SunMeasurement
from .output import ContinuousOutput
from .sun_reference import EphemerisSunReference, FixedSunReference, SunReference, TabulatedSunReference


def relative_from_msg(msg: RelativePose) -> RelativeMeasurement:
    """The measurement of a message; ``ValueError`` whose text is the reason key (``pose_problem``)."""
    problem = pose_problem(msg.pose.pose)
    if problem is not None:
        raise ValueError(problem)
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


RESUME_SETTLE_S = 0.5  # after the VO's publisher is discovered, for the other sensors' (resuming from a checkpoint)
LATENCY_SAMPLES = 10_000  # the newest VO-in -> odometry-out latencies kept for benchmarks


@dataclass(frozen=True)
class FusionNodeConfig:
    """The node's own parameters.

    path_period: seconds of message time between two ``/pvo/fusion/path`` messages (0: every frame).
    path_max_poses: the path holds at most this many newest poses (0: the whole trajectory), so that a long
    run's memory and publishing time stay bounded.
    initial_pose: x y z qx qy qz qw of the first camera in ``map``, used when ``prior.source`` is
    ``given`` and ``initial_pose_from_ground_truth`` is false (then the first ``/ground_truth/odometry``
    at the first VO frame is used instead).
    state_file: where the newest state is checkpointed after every VO frame; a node started with an
    existing checkpoint resumes from it (a restart after a crash continues the trajectory). Empty: off.
    resume_wait: seconds a node resuming from its checkpoint waits for the VO's publisher to be discovered
    before it subscribes its inputs, asking each input whose publishers keep their measurements
    (``pvo_ros.measurements``: transient-local) for them: what was published while it was down is taken again,
    whatever came before the checkpoint set aside. A node starting afresh subscribes at once (volatile).
    """

    map_frame: str = "map"
    camera_frame: str = "camera_left_optical"
    publish_path: bool = True
    path_period: float = 1.0
    path_max_poses: int = 500
    initial_pose: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    initial_pose_from_ground_truth: bool = False
    state_file: str = ""
    resume_wait: float = 5.0

    def __post_init__(self) -> None:
        if not self.resume_wait >= 0.0:
            raise ValueError(f"resume_wait must be >= 0 s, got {self.resume_wait}")
        if not self.path_period >= 0.0:
            raise ValueError(f"path_period must be >= 0 s, got {self.path_period}")
        if self.path_max_poses < 0:
            raise ValueError(f"path_max_poses must be >= 0 (0: the whole trajectory), got {self.path_max_poses}")
        if not self.map_frame or not self.camera_frame:
            raise ValueError("map_frame and camera_frame must not be empty")
        try:
            xyz_xyzw_to_pose(self.initial_pose)
        except ValueError as exc:
            raise ValueError(f"initial_pose: {exc}") from None


class FusionNode(PvoNode[FusionConfig, FusionNodeConfig]):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(
            "fusion",
            FusionConfig(),
            FusionNodeConfig(),
            runtime={"publish_path": lambda _: None, "path_period": lambda _: None},
            status_depth=200,
            **kwargs,
        )
        settings = self.settings
        self._last_path_stamp: int | None = None
        self.graph = FusionGraph(self.config, self._static_sun_reference())
        self.output = ContinuousOutput.from_config(self.config)
        self.latencies_ms: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        # measurements other than VO handed to the graph, by kind: the status carries them so that an offline
        # replay can reproduce the order in which the node saw its inputs
        self.handled: Counter[str] = Counter()
        self.arrivals: list[str] = []  # "kind@stamp_ns" of the measurements taken since the last VO frame, in order
        self._waiting_vo: list[RelativePose] = []
        self._ground_truth: dict[int, np.ndarray] = {}
        self._initial_known = self.config.prior.source == "identity"
        self._gps_fixes = 0
        self._final_path: deque[PoseStamped] = deque(maxlen=settings.path_max_poses or None)
        if self.config.prior.source == "given" and not settings.initial_pose_from_ground_truth:
            self.graph.set_initial_pose(xyz_xyzw_to_pose(settings.initial_pose))
            self._initial_known = True
        resuming = False
        if settings.state_file and os.path.isfile(settings.state_file):
            try:
                checkpoint = FusionCheckpoint.read(settings.state_file)
            except ValueError as exc:
                self.get_logger().warning(f"{exc}; starting without it")
            else:
                self.graph = FusionGraph(self.config, self._static_sun_reference())
                self.graph.resume(checkpoint)
                self._initial_known = True
                resuming = True
                self.get_logger().info(f"resuming from {settings.state_file} at {checkpoint.stamp * 1e-9:.3f} s")
        # the input topics whose kept measurements this node asked for (resuming), and the ones it subscribed
        self.history_topics: list[str] = []
        self.subscribed = False
        if resuming and settings.resume_wait > 0.0:
            # The sensors' publishers keep their last measurements for a late joiner; to ask for them the node
            # must know that every publisher of a topic keeps them (a volatile one, a bag player, would not match)
            waited_since = time.monotonic()
            found_at: list[float] = []

            def subscribe_when_discovered() -> None:
                now = time.monotonic()
                if not found_at and self.count_publishers("/pvo/vo/relative") > 0:
                    found_at.append(now)
                # the other sensors' publishers are discovered within moments of the VO's: give them RESUME_SETTLE_S
                settled = bool(found_at) and now - found_at[0] >= RESUME_SETTLE_S
                if settled or now - waited_since >= settings.resume_wait:
                    self.destroy_timer(self._discovery_timer)
                    self._subscribe_inputs(history=True)

            self._discovery_timer = self.create_timer(0.05, subscribe_when_discovered)
        else:
            self._subscribe_inputs(history=False)
        self.pub_odometry = self.create_publisher(Odometry, "/pvo/fusion/odometry", reliable(200))
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "/pvo/fusion/pose", reliable(200))
        self.pub_path = self.create_publisher(Path, "/pvo/fusion/path", reliable(10))

    def _subscribe_inputs(self, history: bool) -> None:
        """The inputs, each keeping every message: a lagging fusion must not silently lose VO frames (a lost frame
        would become a gap). ``history``: ask each measurement topic whose publishers all keep theirs for them."""
        inputs = {
            "/pvo/vo/relative": (RelativePose, self._on_vo),
            "/pvo/sun/direction": (SunDirection, self._on_sun),
            "/pvo/dpc/correction": (RelativePose, self._on_correction),
            "/pvo/hydranet/rotation": (RelativePose, self._on_rotation),
        }
        for topic, (message_type, callback) in inputs.items():
            qos = every_message()
            if history:
                qos.durability = kept_history_durability(self, topic)
                if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
                    self.history_topics.append(topic)
            self.create_subscription(message_type, topic, callback, qos)
        self.create_subscription(NavSatFix, "/gps/fix", self._on_gps, every_message())
        if not self._initial_known:
            self.create_subscription(Odometry, "/ground_truth/odometry", self._on_ground_truth, every_message())
        if history:
            kept = ", ".join(self.history_topics) or "none (no publisher keeps them)"
            self.get_logger().info(f"resuming: the measurements published while it was down taken again from {kept}")
        self.subscribed = True

    def _static_sun_reference(self) -> SunReference | None:
        sun = self.config.inputs.sun
        if sun.reference == "fixed":
            return FixedSunReference(sun.reference_direction)
        if sun.reference == "table":
            if not sun.reference_table:
                raise ValueError("inputs.sun.reference is table but inputs.sun.reference_table is empty")
            return TabulatedSunReference.read(sun.reference_table)
        return None  # ephemeris: set at the first GPS fix

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
        problem = pose_problem(msg.pose.pose)
        if problem is not None:
            self._reject("ground_truth", stamp_to_nanoseconds(msg.header.stamp), problem)
            return
        self._ground_truth[stamp_to_nanoseconds(msg.header.stamp)] = pose_to_matrix(msg.pose.pose)
        self._try_start()

    def _reject(self, name: str, stamp: int, reason: str) -> None:
        """Count an input refused before it reached the graph (as the graph counts its own rejections)."""
        self.graph.count(name, f"rejected.{reason}")
        self.problem(f"{name} message at {stamp * 1e-9:.9f} s rejected: {reason}")
        self._publish_status(stamp, f"{name}: rejected.{reason}")

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
        try:
            measurement = relative_from_msg(msg)
        except ValueError as exc:
            self._reject("vo", stamp, str(exc))
            return
        outcome = self.graph.add_vo(measurement)
        self._keep_finished()
        if outcome == ACCEPTED:
            pose, covariance = self._publish_estimate(stamp)
            if self.settings.state_file:
                checkpoint = self.graph.checkpoint(pose, covariance)  # the marginal just computed, not a second one
                if checkpoint is not None:
                    checkpoint.write(self.settings.state_file)
            self.latencies_ms.append(1e3 * (time.perf_counter() - received))
            period_ns = int(1e9 * self.settings.path_period)
            due = self._last_path_stamp is None or stamp - self._last_path_stamp >= period_ns
            if self.settings.publish_path and due:
                self._publish_path(stamp)
                self._last_path_stamp = stamp
        self._publish_status(stamp, outcome, arrivals=self.arrivals)
        self.arrivals = []

    def _on_sun(self, msg: SunDirection) -> None:
        self._other("sun", self.graph.add_sun, sun_from_msg(msg))

    def _on_correction(self, msg: RelativePose) -> None:
        self._relative_other("correction", self.graph.add_correction, msg)

    def _on_rotation(self, msg: RelativePose) -> None:
        self._relative_other("rotation", self.graph.add_rotation, msg)

    def _relative_other(self, name: str, add: Any, msg: RelativePose) -> None:
        try:
            measurement = relative_from_msg(msg)
        except ValueError as exc:
            self._reject(name, stamp_to_nanoseconds(msg.header.stamp), str(exc))
            return
        self._other(name, add, measurement)

    def _other(self, name: str, add: Any, measurement: Any) -> None:
        outcome = add(measurement)
        self.handled[name] += 1
        self.arrivals.append(f"{name}@{measurement.stamp}")
        if outcome not in (ACCEPTED, BUFFERED):
            self._publish_status(measurement.stamp, f"{name}: {outcome}")

    # --- outputs --------------------------------------------------------------------------------
    def _publish_estimate(self, stamp: int) -> tuple[np.ndarray, np.ndarray]:
        """Publish the newest state (continuous: :mod:`pvo_fusion.output`); returns the smoother's estimate
        and marginal covariance of it (what a restart resumes from)."""
        estimate, marginal = self.graph.pose(), self.graph.covariance()
        published = self.output.publish_newest(self.graph)
        pose, covariance = published.pose, published.covariance(marginal)
        odom = Odometry()
        fill_stamp(odom.header.stamp, stamp)
        odom.header.frame_id = self.settings.map_frame
        odom.child_frame_id = self.settings.camera_frame
        fill_pose(odom.pose.pose, pose)
        odom.pose.covariance = [float(v) for v in covariance.reshape(-1)]
        self.pub_odometry.publish(odom)
        stamped = PoseWithCovarianceStamped()
        stamped.header = odom.header
        stamped.pose = odom.pose
        self.pub_pose.publish(stamped)
        return estimate, marginal

    def _stamped(self, stamp: int, pose: np.ndarray) -> PoseStamped:
        out = PoseStamped()
        fill_stamp(out.header.stamp, stamp)
        out.header.frame_id = self.settings.map_frame
        fill_pose(out.pose, pose)
        return out

    def _keep_finished(self) -> None:
        """Move the states the window marginalised into the (bounded) final path."""
        self._final_path.extend(self._stamped(p.stamp, p.pose) for p in self.graph.drain_finished())

    def _publish_path(self, stamp: int) -> None:
        path = Path()
        fill_stamp(path.header.stamp, stamp)
        path.header.frame_id = self.settings.map_frame
        poses = [*self._final_path, *(self._stamped(p.stamp, p.pose) for p in self.graph.window())]
        limit = self.settings.path_max_poses
        path.poses = poses[-limit:] if limit else poses
        self.pub_path.publish(path)

    def _publish_status(self, stamp: int, message: str, arrivals: list[str] | None = None) -> None:
        """The node's diagnostics; a VO frame's status also lists ``arrivals``: ``kind@stamp_ns`` of the
        measurements taken since the frame before, in the order taken (what replays the node's input exactly: a
        message the node never received - published before it subscribed - is not in it)."""
        problems = any(k.startswith(("solver.", "vo.gap", "vo.lost")) for k in self.graph.counts)
        problems = problems or any(self.graph.gated_seconds(k) >= GATED_WARNING_SECONDS for k in self.graph.gated_in_a_row)
        level = WARN if (problems or message not in (ACCEPTED, BUFFERED)) else OK
        values: dict[str, Any] = {
            "stamp": f"{stamp * 1e-9:.9f}",
            "window_size": self.graph.window_size,
            "pending": self.graph.pending(),
            "update_time_ms": f"{1e3 * self.graph.last_update_seconds:.3f}",
            "last_rejection": self.graph.last_rejection,
            "sun_reference": "none" if self.graph.sun_reference is None else type(self.graph.sun_reference).__name__,
        }
        for kind, tracker in self.graph.vo_biases.items():
            values[f"vo_bias.{kind}"] = " ".join(f"{v:.6g}" for v in tracker.bias)  # per frame: x y z m, rot rad
            if tracker.rotation_scale_windows:
                values[f"vo_rotation_scale.{kind}"] = f"{tracker.rotation_scale:.6g}"  # each VO turn taken 1 + this long
            if tracker.translation_scale_windows:
                values[f"vo_translation_scale.{kind}"] = f"{tracker.translation_scale:.6g}"  # each VO step 1 + this long
        for kind, count in sorted(self.graph.gated_in_a_row.items()):
            values[f"gated_in_a_row.{kind}"] = count  # the gate's rejections since its last accepted one
            values[f"gated_for_s.{kind}"] = f"{self.graph.gated_seconds(kind):.3f}"  # over this long (newest state's time)
        values.update({f"factors.{k}": v for k, v in sorted(self.graph.factor_counts.items())})
        values.update({f"count.{k}": v for k, v in sorted(self.graph.counts.items()) if v})
        values.update({f"handled.{k}": v for k, v in sorted(self.handled.items())})
        if arrivals is not None:
            values["arrivals"] = ",".join(arrivals)
        self.publish_status(stamp, self.settings.map_frame, level, message, values)


def main(args: list[str] | None = None) -> None:
    run_node(FusionNode, "fusion", args)


if __name__ == "__main__":
    main()
