"""The fusion and simulated_sun nodes over DDS: same numbers as the ROS-free objects; bad input reported."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMessage
from pvo_core.lie import se3_exp, se3_inverse
from pvo_core.msgconv import covariance_to_matrix, fill_pose, pose_to_matrix, stamp_to_nanoseconds
from pvo_fusion.fusion_node import FusionNode
from pvo_pseudosensors.simulated_sun import SimulatedSunConfig, SimulatedSunSensor
from pvo_pseudosensors.simulated_sun_node import SimulatedSunNode
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import NavSatFix, NavSatStatus

from pvo_fusion import FusionGraph
from pvo_fusion.config import from_flat
from pvo_msgs.msg import RelativePose, SunDirection

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)


def relative_msg(stamp: int, reference: int, transform: np.ndarray, covariance: np.ndarray) -> RelativePose:
    msg = RelativePose()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.header.frame_id = "camera_left_optical"
    msg.reference_stamp.sec, msg.reference_stamp.nanosec = divmod(reference, 1_000_000_000)
    fill_pose(msg.pose.pose, transform)
    msg.pose.covariance = [float(v) for v in np.asarray(covariance).reshape(-1)]
    return msg


def sun_msg(stamp: int, direction: np.ndarray, covariance: np.ndarray) -> SunDirection:
    msg = SunDirection()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.direction.x, msg.direction.y, msg.direction.z = (float(v) for v in direction)
    msg.covariance = [float(v) for v in np.asarray(covariance).reshape(-1)]
    return msg


def fusion_io(ros_context) -> tuple[Node, list[Odometry], list[DiagnosticArray], Any]:
    """A test node listening to the fusion's odometry and status; ``publisher(topic, type)`` makes its publishers."""
    io = Node("io", context=ros_context)
    odometry: list[Odometry] = []
    statuses: list[DiagnosticArray] = []
    io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    io.create_subscription(DiagnosticArray, "/pvo/fusion/status", statuses.append, RELIABLE)
    return io, odometry, statuses, lambda topic, kind=RelativePose: io.create_publisher(kind, topic, RELIABLE)


def test_sun_sim_sequence_through_the_fusion_node_equals_the_ros_free_run(pvo_data: Path, tmp_path: Path, domain_id: int) -> None:
    from pvo_core.readers import SEQUENCE_DRIVES, read_kitti_sun_sequence
    from pvo_tools.experiments.sun_sim import (
        calibration_input,
        experiment_config,
        run_fusion,
        sequence_vo,
        sun_measurements,
        sun_seed,
    )
    from pvo_tools.experiments.sun_sim_nodes import run_through_nodes

    from pvo_core import metrics
    from pvo_fusion import calibrate_vo

    seq = read_kitti_sun_sequence(pvo_data, "05")
    train = (read_kitti_sun_sequence(pvo_data, n) for n in SEQUENCE_DRIVES if n not in ("05", "00", "02", "08"))
    calibration = calibrate_vo((calibration_input(s) for s in train), span=10)
    seq = seq.clipped(200)
    vo = sequence_vo(seq, calibration)
    sun = sun_measurements(seq, 10.0, sun_seed(0, "05", 10.0))
    ros_free = run_fusion(seq, vo, sun, experiment_config())
    nodes = run_through_nodes(seq, vo, sun, tmp_path, rate=20.0, domain_id=domain_id, timeout_s=120.0)
    assert nodes.odometry_messages == len(vo) == 199
    assert np.all(np.isfinite(nodes.poses))
    np.testing.assert_allclose(nodes.poses, ros_free.poses, atol=1e-7)
    a, b = metrics.armse(seq.ground_truth, ros_free.poses), metrics.armse(seq.ground_truth, nodes.poses)
    for key in ("trans", "trans_en", "rot"):
        assert b[key] == pytest.approx(a[key], rel=1e-7)
    # Every 10th frame carried a sun factor, and it moved the estimate away from the VO alone.
    assert ros_free.factors["sun"] == 20
    vo_alone = run_fusion(seq, vo, None, experiment_config())
    assert np.max(np.abs(vo_alone.poses - ros_free.poses)) > 1e-3


def test_simulated_sun_node_publishes_every_nth_seeded_measurement(ros_context) -> None:
    node = SimulatedSunNode(
        context=ros_context, parameter_overrides=[Parameter("mean_error_deg", value=20.0), Parameter("seed", value=4)]
    )
    io = Node("io", context=ros_context)
    received: list[SunDirection] = []
    io.create_subscription(SunDirection, "/pvo/sun/direction", received.append, RELIABLE)
    pub = io.create_publisher(SunDirection, "/ground_truth/sun_direction", RELIABLE)
    truth = np.array([0.1, -0.6, 0.79])
    truth /= np.linalg.norm(truth)
    try:
        with Spinner(ros_context, node), Spinner(ros_context, io):
            wait_for(lambda: pub.get_subscription_count() > 0 and node.publisher.get_subscription_count() > 0, 10.0)
            for k in range(25):
                pub.publish(sun_msg(1_000_000_000 + k * 100_000_000, truth, np.zeros(4)))
            pub.publish(sun_msg(4_000_000_000, np.array([np.nan, 0.0, 1.0]), np.zeros(4)))
            wait_for(lambda: len(received) >= 3 and node.rejected == 1, 10.0)
    finally:
        node.destroy_node()
        io.destroy_node()
    assert [stamp_to_nanoseconds(m.header.stamp) for m in received] == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    reference = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=20.0, seed=4))
    expected = [r for r in (reference.measure(truth) for _ in range(25)) if r is not None]
    for msg, (direction, covariance) in zip(received, expected, strict=True):
        np.testing.assert_allclose([msg.direction.x, msg.direction.y, msg.direction.z], direction, atol=1e-15)
        np.testing.assert_allclose(np.reshape(msg.covariance, (2, 2)), covariance, atol=1e-18)
        assert msg.zenith == pytest.approx(np.arccos(-direction[1]))
    assert node.rejected == 1


def test_fusion_node_reports_bad_input_and_keeps_going(ros_context) -> None:
    fusion = FusionNode(context=ros_context, parameter_overrides=[Parameter("publish_path", value=False)])
    io, odometry, statuses, publisher = fusion_io(ros_context)
    vo_pub = publisher("/pvo/vo/relative")
    sun_pub = publisher("/pvo/sun/direction", SunDirection)
    gps_pub = publisher("/gps/fix", NavSatFix)
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.01, 0.0])))  # T_k,k-1
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0 = 1_317_640_000_000_000_000
    dt = 100_000_000
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            wait_for(lambda: vo_pub.get_subscription_count() > 0 and fusion.pub_status.get_subscription_count() > 0, 10.0)
            for k in range(1, 6):
                vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
            wait_for(lambda: len(odometry) >= 5)
            vo_pub.publish(relative_msg(t0 + 6 * dt, t0 + 5 * dt, step, np.full((6, 6), np.nan)))
            direction = np.array([0.0, -0.6, 0.8])
            sun_pub.publish(sun_msg(t0 + 5 * dt, direction, np.diag([1e-3, 2e-3])))  # no GPS origin yet
            sun_pub.publish(sun_msg(t0 + 5 * dt, 3.0 * direction, np.diag([1e-3, 2e-3])))
            wait_for(lambda: len(statuses) >= 8)
            fix = NavSatFix()
            fix.status.status = NavSatStatus.STATUS_FIX
            fix.latitude, fix.longitude, fix.altitude = 49.01, 8.43, 115.0
            gps_pub.publish(fix)
            wait_for(lambda: fusion.graph.sun_reference is not None, 10.0)
            vo_pub.publish(relative_msg(t0 + 6 * dt, t0 + 5 * dt, step, cov))
            wait_for(lambda: len(odometry) >= 6)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    messages = [s.status[0].message for s in statuses]
    assert "rejected.non_finite_covariance" in messages
    assert "sun: rejected.no_gps_origin" in messages
    assert "sun: rejected.direction_not_unit" in messages
    bad = next(s.status[0] for s in statuses if s.status[0].message == "rejected.non_finite_covariance")
    assert bad.level == DiagnosticStatus.WARN
    keys = {kv.key: kv.value for kv in statuses[-1].status[0].values}
    assert keys["count.vo.rejected.non_finite_covariance"] == "1"
    assert keys["count.sun.rejected.no_gps_origin"] == "1"
    assert keys["factors.vo"] == "6" and keys["window_size"] == "7"
    assert keys["sun_reference"] == "EphemerisSunReference"
    # what the node took since the frame before, in order, with each one's stamp (the demo replays it)
    assert keys["arrivals"] == f"sun@{t0 + 5 * dt},sun@{t0 + 5 * dt}"
    # the odometry equals the ROS-free graph fed the same good messages; covariance in ROS order
    graph = FusionGraph(from_flat({}))
    from pvo_fusion import RelativeMeasurement

    for k in range(1, 7):
        graph.add_vo(RelativeMeasurement(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
    assert len(odometry) == 6
    np.testing.assert_allclose(pose_to_matrix(odometry[-1].pose.pose), graph.pose(), atol=1e-9)
    np.testing.assert_allclose(covariance_to_matrix(odometry[-1].pose.covariance), graph.covariance(), rtol=1e-6, atol=1e-15)
    position_variance = np.diag(covariance_to_matrix(odometry[-1].pose.covariance))[:3]
    assert np.all(position_variance > 5e-4)  # grown from 1e-6 m² by six VO steps (ROS order: position first)


def test_fusion_node_warns_when_the_gate_keeps_an_input_out(ros_context) -> None:
    """Corrections the gate rejects for GATED_WARNING_SECONDS on end (the estimate and the sensor disagree for good: one
    is lost) turn the VO frames' status WARN, the streak per input in it; an accepted one ends it."""
    from pvo_fusion.graph import GATED_WARNING_SECONDS

    fusion = FusionNode(context=ros_context, parameter_overrides=[Parameter("publish_path", value=False)])
    io, odometry, statuses, publisher = fusion_io(ros_context)
    vo_pub, correction_pub = publisher("/pvo/vo/relative"), publisher("/pvo/dpc/correction")
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))  # T_k,k-1
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, int(GATED_WARNING_SECONDS / 4 * 1e9)  # four frames span the warning's time
    wrong = se3_exp(np.array([0.0, 0.0, 2.0, 0.0, 0.2, 0.0])) @ step @ step  # 2 m and 11 deg off the VO's two steps
    frames: dict[int, DiagnosticStatus] = {}  # the status of each VO frame

    def frame(k: int) -> None:
        vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
        wait_for(lambda: len(odometry) >= k and statuses[-1].status[0].message == "accepted")
        frames[k] = statuses[-1].status[0]

    def correction(transform: np.ndarray, outcome: str) -> None:
        before = fusion.graph.counts[f"correction.{outcome}"]
        correction_pub.publish(relative_msg(t0 + 3 * dt, t0 + dt, transform, cov))
        wait_for(lambda: fusion.graph.counts[f"correction.{outcome}"] > before)

    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            wait_for(lambda: correction_pub.get_subscription_count() > 0 and fusion.pub_status.get_subscription_count() > 0)
            for k in range(1, 4):
                frame(k)
            for k in range(4, 8):  # gated at frames 3, 4, 5, 6 and 7: the span reaches the warning after frame 7's
                correction(wrong, "gated")
                frame(k)
            correction(wrong, "gated")
            frame(8)
            correction(step @ step, "accepted")
            frame(9)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    values = {k: {kv.key: kv.value for kv in status.values} for k, status in frames.items()}
    assert [values[k].get("gated_in_a_row.correction") for k in (3, 4, 7, 8, 9)] == [None, "1", "4", "5", None]
    assert values[7]["gated_for_s.correction"] == f"{3 * dt * 1e-9:.3f}" and values[8]["gated_for_s.correction"] == "10.000"
    levels = [frames[k].level for k in range(1, 10)]
    assert levels == [DiagnosticStatus.OK] * 7 + [DiagnosticStatus.WARN, DiagnosticStatus.OK]


def test_fusion_path_is_published_once_per_path_period(ros_context) -> None:
    fusion = FusionNode(context=ros_context, parameter_overrides=[Parameter("path_period", value=0.5)])
    io = Node("io", context=ros_context)
    paths: list[PathMessage] = []
    odometry: list[Odometry] = []
    io.create_subscription(PathMessage, "/pvo/fusion/path", paths.append, 10)
    io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    vo_pub = io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, 100_000_000
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            wait_for(lambda: vo_pub.get_subscription_count() > 0 and fusion.pub_path.get_subscription_count() > 0, 10.0)
            for k in range(1, 13):
                vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
            wait_for(lambda: len(odometry) >= 12 and len(paths) >= 3)
            time.sleep(0.2)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    assert len(odometry) == 12
    # frames 1..12 at 10 Hz, one path per 0.5 s of message time: at frames 1, 6 and 11
    assert [stamp_to_nanoseconds(p.header.stamp) for p in paths] == [t0 + k * dt for k in (1, 6, 11)]
    assert [len(p.poses) for p in paths] == [2, 7, 12]  # the first state and every frame since


def test_missing_sun_table_is_one_clear_line(ros_env, tmp_path: Path) -> None:
    missing = tmp_path / "none.csv"
    command = ["pvo", "run", "pvo_fusion", "fusion", "--ros-args", "-p", "inputs.sun.reference:=table"]
    result = subprocess.run(
        [*command, "-p", f"inputs.sun.reference_table:={missing}"],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"fusion: error: sun reference table {missing}: no such file"


def test_fusion_node_takes_its_first_pose_from_ground_truth_when_asked(ros_context) -> None:
    params = [
        Parameter("prior.source", value="given"),
        Parameter("initial_pose_from_ground_truth", value=True),
        Parameter("publish_path", value=False),
    ]
    fusion = FusionNode(context=ros_context, parameter_overrides=params)
    io = Node("io", context=ros_context)
    odometry: list[Odometry] = []
    io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    vo_pub = io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    gt_pub = io.create_publisher(Odometry, "/ground_truth/odometry", RELIABLE)
    first = se3_exp(np.array([10.0, -4.0, 2.0, 0.1, -0.2, 0.3]))
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.01, 0.0])))
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, 100_000_000
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            wait_for(lambda: vo_pub.get_subscription_count() > 0 and gt_pub.get_subscription_count() > 0, 10.0)
            vo_pub.publish(relative_msg(t0 + dt, t0, step, cov))  # waits for the ground truth at t0
            time.sleep(0.3)
            assert odometry == []
            truth = Odometry()
            truth.header.stamp.sec, truth.header.stamp.nanosec = divmod(t0, 1_000_000_000)
            fill_pose(truth.pose.pose, first)
            gt_pub.publish(truth)
            wait_for(lambda: len(odometry) >= 1, 10.0)
            vo_pub.publish(relative_msg(t0 + 2 * dt, t0 + dt, step, cov))
            wait_for(lambda: len(odometry) >= 2, 10.0)
    finally:
        fusion.destroy_node()
        io.destroy_node()
    assert len(odometry) == 2
    expected = first @ se3_inverse(step) @ se3_inverse(step)
    np.testing.assert_allclose(pose_to_matrix(odometry[-1].pose.pose), expected, atol=1e-6)


def test_a_long_run_keeps_bounded_paths_and_drains_the_window_without_publishing(ros_context) -> None:
    """Issue 18, defect 5: the final path is bounded by path_max_poses, and marginalised states do not pile
    up when the path is not published."""
    overrides = [
        Parameter("window.lag", value=3.0),
        Parameter("path_period", value=0.0),
        Parameter("path_max_poses", value=5),
    ]
    fusion = FusionNode(context=ros_context, parameter_overrides=overrides)
    quiet = FusionNode(
        context=ros_context,
        namespace="quiet",
        parameter_overrides=[Parameter("window.lag", value=3.0), Parameter("publish_path", value=False)],
    )
    io = Node("io", context=ros_context)
    paths: list[PathMessage] = []
    io.create_subscription(PathMessage, "/pvo/fusion/path", paths.append, 50)
    vo_pub = io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, 100_000_000
    try:
        with Spinner(ros_context, fusion, quiet), Spinner(ros_context, io):
            wait_for(lambda: vo_pub.get_subscription_count() >= 2 and fusion.pub_path.get_subscription_count() > 0, 10.0)
            for k in range(1, 41):
                vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
            wait_for(lambda: len(paths) >= 40 and quiet.graph.counts["vo.accepted"] == 40)
    finally:
        for node in (fusion, quiet, io):
            node.destroy_node()
    assert len(paths) == 40
    assert [len(p.poses) for p in paths[:5]] == [2, 3, 4, 5, 5] and len(paths[-1].poses) == 5
    assert [stamp_to_nanoseconds(p.header.stamp) for p in paths[-1].poses] == [t0 + k * dt for k in range(36, 41)]
    assert quiet.graph.drain_finished() == []  # the node keeps draining what the window marginalises


def test_a_restarted_fusion_node_resumes_from_its_state_file(ros_context, tmp_path: Path) -> None:
    """Issue 18: the node checkpoints its newest state; a new node with the same state_file continues from it."""
    state = tmp_path / "state.json"
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, 100_000_000
    odometry: list[Odometry] = []
    for first, last in ((1, 10), (21, 25)):  # frames 11..20 are lost while the node is down
        fusion = FusionNode(context=ros_context, parameter_overrides=[Parameter("state_file", value=str(state))])
        io = Node("io", context=ros_context)
        io.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
        vo_pub = io.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
        try:
            with Spinner(ros_context, fusion), Spinner(ros_context, io):
                wait_for(
                    lambda p=vo_pub, f=fusion: p.get_subscription_count() > 0 and f.pub_odometry.get_subscription_count() > 0
                )
                for k in range(first, last + 1):
                    vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step, cov))
                n = last - first + 1
                wait_for(lambda f=fusion, n=n: f.graph.counts["vo.accepted"] == n)
                time.sleep(0.2)
        finally:
            fusion.destroy_node()
            io.destroy_node()
        assert state.is_file()
    z = [pose_to_matrix(m.pose.pose)[2, 3] for m in odometry]
    assert len(z) == 15
    # 1 m per frame forward: frame 10 at z = 10; the bridge over frames 11..20 continues at that velocity
    assert z[9] == pytest.approx(10.0, abs=1e-6)
    np.testing.assert_allclose(z[10:], [21.0, 22.0, 23.0, 24.0, 25.0], atol=1e-6)


def test_a_resumed_fusion_node_takes_again_what_the_sensors_kept_while_it_was_down(ros_context, tmp_path: Path) -> None:
    """The sensors publish their measurements transient-local (`pvo_ros.measurements`): a fusion node resuming from
    its checkpoint asks for what they kept and chains the frames published while it was down, where bridging at the
    last velocity would miss a change of speed; what came before the checkpoint is set aside."""
    from pvo_ros import measurements

    state = tmp_path / "state.json"
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    t0, dt = 1_000_000_000, 100_000_000

    def step(k: int) -> np.ndarray:  # 1 m per frame, 2 m per frame over frames 11..20 (while the node is down)
        return se3_inverse(se3_exp(np.array([0.0, 0.0, 2.0 if 11 <= k <= 20 else 1.0, 0.0, 0.0, 0.0])))

    odometry: list[Odometry] = []
    sensor = Node("vo_with_history", context=ros_context)
    vo_pub = sensor.create_publisher(RelativePose, "/pvo/vo/relative", measurements())
    sensor.create_publisher(RelativePose, "/pvo/hydranet/rotation", measurements())
    sensor.create_publisher(SunDirection, "/pvo/sun/direction", RELIABLE)  # volatile, as a bag player's: none kept
    listener = Node("io", context=ros_context)
    listener.create_subscription(Odometry, "/pvo/fusion/odometry", odometry.append, RELIABLE)
    parameters = [Parameter("state_file", value=str(state)), Parameter("publish_path", value=False)]
    try:
        with Spinner(ros_context, sensor), Spinner(ros_context, listener):
            first = FusionNode(context=ros_context, parameter_overrides=parameters)
            try:
                with Spinner(ros_context, first):
                    assert wait_for(lambda: vo_pub.get_subscription_count() > 0, 10.0)
                    for k in range(1, 11):
                        vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step(k), cov))
                    assert wait_for(lambda: first.graph.counts["vo.accepted"] == 10 and len(odometry) == 10, 10.0)
            finally:
                first.destroy_node()
            assert first.history_topics == []  # a fresh node asks for nothing old
            for k in range(11, 21):  # nobody fuses these
                vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step(k), cov))
            resumed = FusionNode(context=ros_context, parameter_overrides=parameters)
            try:
                with Spinner(ros_context, resumed):
                    assert wait_for(lambda: resumed.subscribed and vo_pub.get_subscription_count() > 0, 10.0)
                    # asked where every publisher keeps its measurements; the volatile sun subscribed volatile
                    assert resumed.history_topics == ["/pvo/vo/relative", "/pvo/hydranet/rotation"]
                    assert wait_for(lambda: resumed.graph.counts["vo.accepted"] == 10, 10.0)  # frames 11..20, kept
                    for k in range(21, 26):
                        vo_pub.publish(relative_msg(t0 + k * dt, t0 + (k - 1) * dt, step(k), cov))
                    assert wait_for(lambda: resumed.graph.counts["vo.accepted"] == 15 and len(odometry) == 25, 10.0)
                    counts = dict(resumed.graph.counts)
            finally:
                resumed.destroy_node()
    finally:
        sensor.destroy_node()
        listener.destroy_node()
    assert counts["vo.rejected.before_checkpoint"] == 10 and counts.get("vo.gap", 0) == 0
    z = [pose_to_matrix(m.pose.pose)[2, 3] for m in odometry]
    np.testing.assert_allclose(z[9], 10.0, atol=1e-6)
    # frames 11..20 at 2 m each, then 1 m again: 30 m at frame 20 and 35 m at 25 (the bridge at the last
    # velocity would have read 20 and 25)
    np.testing.assert_allclose(z[10:], [10.0 + 2.0 * k for k in range(1, 11)] + [31.0, 32.0, 33.0, 34.0, 35.0], atol=1e-6)


def corrected_drive(
    read: np.ndarray, exact: np.ndarray, vo_cov: np.ndarray, correction_cov: np.ndarray, frames: int, last: bool = True
) -> list[tuple[str, RelativePose]]:
    """``frames`` VO messages, each motion ``read``, and after every third one a correction ``exact`` over those three
    (``last``: also after the last VO frame), in the order they are published."""
    t0 = 1_317_640_000_000_000_000
    dt = 100_000_000
    messages: list[tuple[str, RelativePose]] = []
    for k in range(1, frames + 1):
        messages.append(("vo", relative_msg(t0 + k * dt, t0 + (k - 1) * dt, read, vo_cov)))
        if k % 3 == 0 and (last or k < frames):
            messages.append(("correction", relative_msg(t0 + k * dt, t0 + (k - 3) * dt, exact, correction_cov)))
    return messages


def fuse_over_dds(ros_context, settings: dict, messages: list[tuple[str, RelativePose]]) -> tuple[FusionNode, list, list]:
    """A fusion node with ``settings`` as parameters fed ``messages`` on `/pvo/vo/relative` and `/pvo/dpc/correction`,
    each correction taken before the next VO motion (as offline): the node, its odometry and its statuses."""
    fusion = FusionNode(
        context=ros_context,
        parameter_overrides=[Parameter("publish_path", value=False)] + [Parameter(k, value=v) for k, v in settings.items()],
    )
    io, odometry, statuses, publisher = fusion_io(ros_context)
    vo_pub = publisher("/pvo/vo/relative")
    correction_pub = publisher("/pvo/dpc/correction")
    frames = sum(kind == "vo" for kind, _ in messages)
    try:
        with Spinner(ros_context, fusion), Spinner(ros_context, io):
            wait_for(lambda: vo_pub.get_subscription_count() > 0 and correction_pub.get_subscription_count() > 0, 10.0)
            wait_for(lambda: fusion.pub_status.get_subscription_count() > 0, 10.0)
            published = 0
            for kind, msg in messages:
                (vo_pub if kind == "vo" else correction_pub).publish(msg)
                if kind == "correction":
                    published += 1
                    assert wait_for(lambda n=published: fusion.graph.counts["vo_bias.correction.learned"] >= n, 10.0)
                else:
                    expected = len(odometry) + 1
                    assert wait_for(lambda n=expected: len(odometry) >= n, 10.0)
            assert wait_for(lambda: len(statuses) >= frames)  # one per VO frame
    finally:
        fusion.destroy_node()
        io.destroy_node()
    return fusion, odometry, statuses


def fuse_offline(settings: dict, messages: list[tuple[str, RelativePose]]) -> np.ndarray:
    """The ROS-free graph's newest pose (4, 4) given ``settings`` and the same messages."""
    from pvo_fusion import RelativeMeasurement

    graph = FusionGraph(from_flat(settings))
    for kind, msg in messages:
        m = RelativeMeasurement(
            stamp_to_nanoseconds(msg.header.stamp),
            stamp_to_nanoseconds(msg.reference_stamp),
            pose_to_matrix(msg.pose.pose),
            covariance_to_matrix(msg.pose.covariance),
        )
        graph.add_vo(m) if kind == "vo" else graph.add_correction(m)
    return graph.pose()


def test_the_fusion_node_learns_the_vo_bias_from_corrections_over_dds(ros_context) -> None:
    """`inputs.correction.vo_bias_windows` set as a node parameter: a VO that reads 3 % long, exact corrections every 3
    frames on `/pvo/dpc/correction`; the status reports the learned bias per frame, and the odometry equals the
    ROS-free graph given the same parameter and messages (which ends far nearer the truth than without it)."""
    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])))  # T_k,k-1: 1 m forward
    bias = np.array([0.0, 0.0, 0.03, 0.0, 0.0, 0.0])
    read = se3_exp(-bias) @ step  # the VO reads 1.03 m
    vo_cov = np.diag([4e-4, 4e-4, 1e-3, 1e-8, 1e-8, 1e-8])
    correction_cov = np.diag([4e-4, 4e-4, 4e-4, 1e-8, 1e-8, 1e-8])
    frames = 30
    messages = corrected_drive(read, step @ step @ step, vo_cov, correction_cov, frames)
    settings = {"inputs.correction.vo_bias_windows": 30.0}
    fusion, odometry, statuses = fuse_over_dds(ros_context, settings, messages)
    # the status of the last VO frame (one per frame): the nine corrections before it learned, the bias per frame the
    # VO's own (each correction exact)
    keys = {kv.key: kv.value for kv in statuses[-1].status[0].values}
    assert keys["count.vo_bias.correction.learned"] == str(frames // 3 - 1)
    assert fusion.graph.counts["vo_bias.correction.learned"] == frames // 3
    np.testing.assert_allclose([float(v) for v in keys["vo_bias.correction"].split()], bias, atol=1e-6)
    learned = fuse_offline(settings, messages)
    np.testing.assert_allclose(pose_to_matrix(odometry[-1].pose.pose), learned, atol=1e-9)
    truth_z = float(frames)
    assert abs(learned[2, 3] - truth_z) < 0.5 * abs(fuse_offline({}, messages)[2, 3] - truth_z)


def test_the_fusion_node_rescales_the_vo_turns_from_corrections_over_dds(ros_context) -> None:
    """`inputs.correction.vo_rotation_scale_windows` set as a node parameter: a VO that reads every turn 8 % long (a
    lens processed as if undistorted), exact corrections every 3 frames; the status reports the scale learned (each turn
    taken 1/1.08 - 1 longer) and the odometry equals the ROS-free graph's with the same parameter and messages."""
    from pvo_core.lie import so3_exp, so3_log

    step = se3_inverse(se3_exp(np.array([0.0, 0.0, 1.0, 0.0, np.radians(2.0), 0.0])))  # 1 m forward, 2 deg left
    read = step.copy()
    read[:3, :3] = so3_exp(1.08 * so3_log(step[:3, :3]))
    vo_cov = np.diag([4e-4, 4e-4, 1e-3, 1e-6, 1e-6, 1e-6])
    correction_cov = np.diag([4e-4, 4e-4, 4e-4, 3e-6, 3e-6, 3e-6])
    # no correction after the last VO frame: its odometry is what the graph says after all the messages
    messages = corrected_drive(read, step @ step @ step, vo_cov, correction_cov, 30, last=False)
    settings = {"inputs.correction.vo_rotation_scale_windows": 1000.0}
    _, odometry, statuses = fuse_over_dds(ros_context, settings, messages)
    keys = {kv.key: kv.value for kv in statuses[-1].status[0].values}
    # nine corrections of 6 deg turns: the prior (~1 deg of turning) shrinks the scale by under half a per cent
    assert float(keys["vo_rotation_scale.correction"]) == pytest.approx(1.0 / 1.08 - 1.0, rel=5e-3)
    assert keys["vo_bias.correction"].split() == ["0"] * 6  # no additive bias asked for
    np.testing.assert_allclose(pose_to_matrix(odometry[-1].pose.pose), fuse_offline(settings, messages), atol=1e-9)
