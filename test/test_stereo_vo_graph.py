"""The stereo_vo node over DDS: the sample bag in -> relative poses out; bad input reported, not fatal."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from pvo_core.msgconv import pose_to_matrix, stamp_to_nanoseconds
from pvo_core.readers import KittiSequence
from pvo_frontend.stereo_vo_node import StereoVONode
from pvo_frontend.vo import StereoVO
from pvo_tools.player import BagPlayer, PlayOptions
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from pvo_msgs.msg import RelativePose

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)


def test_sample_bag_through_stereo_vo(ros_context, sample_bag: Path, pvo_data: Path) -> None:
    vo_node = StereoVONode(context=ros_context)
    listener = Node("listener", context=ros_context)
    player_node = Node("player", context=ros_context)
    relative: list[RelativePose] = []
    odometry: list[Odometry] = []
    statuses: list[DiagnosticArray] = []
    listener.create_subscription(RelativePose, "/pvo/vo/relative", relative.append, RELIABLE)
    listener.create_subscription(Odometry, "/pvo/vo/odometry", odometry.append, RELIABLE)
    listener.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    try:
        with Spinner(ros_context, vo_node), Spinner(ros_context, listener):
            # three times real time; reliable queues mean the node must not lose a frame
            BagPlayer(player_node, sample_bag, PlayOptions(rate=3.0, wait_for_subscribers=1, clock=False)).play()
            wait_for(lambda: len(statuses) >= 51 and len(relative) >= 50)
    finally:
        for node in (vo_node, listener, player_node):
            node.destroy_node()

    assert len(statuses) == 51
    assert [s.status[0].message for s in statuses if s.status[0].level != DiagnosticStatus.OK] == []
    assert len(relative) == 50 and len(odometry) == 50
    stamps = [stamp_to_nanoseconds(m.header.stamp) for m in relative]
    references = [stamp_to_nanoseconds(m.reference_stamp) for m in relative]
    assert references[1:] == stamps[:-1] and all(b > a for a, b in itertools.pairwise(stamps))
    for msg in relative:
        cov = np.asarray(msg.pose.covariance).reshape(6, 6)
        assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
        assert msg.header.frame_id == "camera_left_optical" and not msg.rotation_only

    # the node computes exactly what the ROS-free object computes on the same images
    root = pvo_data / "kitti/sequences/06"
    sequence = KittiSequence(root, rate_hz=10.0)
    vo = StereoVO(sequence.camera(1226, 370))
    frame_stamps = [references[0], *stamps]
    expected = [vo.process(*sequence.load_pair(i), frame_stamps[i] * 1e-9) for i in range(len(sequence))]
    for msg, result in zip(relative, expected[1:], strict=True):
        assert np.allclose(pose_to_matrix(msg.pose.pose), result.transform, atol=1e-9)
        assert np.allclose(np.asarray(msg.pose.covariance).reshape(6, 6), result.covariance, rtol=1e-9, atol=1e-15)
    assert np.allclose(pose_to_matrix(odometry[-1].pose.pose), expected[-1].pose, atol=1e-9)


def make_image(stamp_ns: int, width: int, height: int, seed: int) -> Image:
    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.height, msg.width, msg.encoding, msg.step = height, width, "mono8", width
    msg.data = np.random.default_rng(seed).integers(0, 255, width * height, dtype=np.uint8).tobytes()
    return msg


def make_info(width: int, height: int, tx: float) -> CameraInfo:
    msg = CameraInfo()
    msg.width, msg.height = width, height
    msg.p = [500.0, 0.0, width / 2, tx, 0.0, 500.0, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def test_bad_input_is_reported_and_the_node_keeps_running(ros_context) -> None:
    vo_node = StereoVONode(context=ros_context, parameter_overrides=[Parameter("max_pending_frames", value=1)])
    io = Node("io", context=ros_context)
    statuses: list[DiagnosticArray] = []
    io.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    pub = {
        name: io.create_publisher(
            kind, f"/stereo/{name.replace('_info', '/camera_info').replace('_image', '/image_rect')}", RELIABLE
        )
        for name, kind in (("left_image", Image), ("right_image", Image), ("left_info", CameraInfo), ("right_info", CameraInfo))
    }
    try:
        with Spinner(ros_context, vo_node, io):
            # both directions discovered: the node's inputs and our status subscription (under load the
            # reverse match can lag, and a status published before it is lost)
            wait_for(lambda: all(p.get_subscription_count() > 0 for p in pub.values()), 10)
            wait_for(lambda: vo_node.pub_status.get_subscription_count() > 0, 10)
            # 1. two pairs before any camera_info: one is kept (max_pending_frames 1), the older dropped and reported
            for k in (1, 2):
                pub["left_image"].publish(make_image(k * 1_000_000_000, 320, 240, 2 * k))
                pub["right_image"].publish(make_image(k * 1_000_000_000, 320, 240, 2 * k + 1))
            wait_for(lambda: len(statuses) >= 1, 10)
            # 2. camera_info: the kept pair is processed
            pub["left_info"].publish(make_info(320, 240, 0.0))
            pub["right_info"].publish(make_info(320, 240, -50.0))
            wait_for(lambda: len(statuses) >= 2, 10)
            # 3. a pair of mismatched sizes
            pub["left_image"].publish(make_image(3_000_000_000, 320, 240, 7))
            pub["right_image"].publish(make_image(3_000_000_000, 300, 240, 8))
            wait_for(lambda: len(statuses) >= 3, 10)
            # 4. a pair going back in time
            pub["left_image"].publish(make_image(1_500_000_000, 320, 240, 9))
            pub["right_image"].publish(make_image(1_500_000_000, 320, 240, 10))
            wait_for(lambda: len(statuses) >= 4, 10)
    finally:
        vo_node.destroy_node()
        io.destroy_node()
    assert len(statuses) == 4
    dropped, first, mismatched, backwards = (s.status[0] for s in statuses)
    assert dropped.level == DiagnosticStatus.WARN
    assert dropped.message == "frame dropped: no camera_info on /stereo/left/camera_info and /stereo/right/camera_info"
    assert first.level == DiagnosticStatus.OK and first.message == "first frame"
    assert mismatched.level == DiagnosticStatus.ERROR and "differ in size" in mismatched.message
    assert backwards.level == DiagnosticStatus.ERROR and "backwards" in backwards.message


def test_the_path_is_bounded_and_published_once_per_path_period(ros_context) -> None:
    """Issue 18, defect 5: /pvo/vo/path no longer grows and republishes the whole trajectory every frame."""
    from nav_msgs.msg import Path as PathMessage

    overrides = [Parameter("path_period", value=0.3), Parameter("path_max_poses", value=4)]
    vo_node = StereoVONode(context=ros_context, parameter_overrides=overrides)
    io = Node("io", context=ros_context)
    paths: list[PathMessage] = []
    statuses: list[DiagnosticArray] = []
    io.create_subscription(PathMessage, "/pvo/vo/path", paths.append, RELIABLE)
    io.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    left = io.create_publisher(Image, "/stereo/left/image_rect", RELIABLE)
    right = io.create_publisher(Image, "/stereo/right/image_rect", RELIABLE)
    infos = [io.create_publisher(CameraInfo, f"/stereo/{side}/camera_info", RELIABLE) for side in ("left", "right")]
    try:
        with Spinner(ros_context, vo_node, io):
            wait_for(lambda: left.get_subscription_count() > 0 and vo_node.pub_path.get_subscription_count() > 0, 10)
            wait_for(lambda: vo_node.pub_status.get_subscription_count() > 0, 10)
            infos[0].publish(make_info(160, 120, 0.0))
            infos[1].publish(make_info(160, 120, -50.0))
            for k in range(12):  # noise images: every frame after the first is lost, its motion predicted
                left.publish(make_image(k * 100_000_000, 160, 120, 2 * k))
                right.publish(make_image(k * 100_000_000, 160, 120, 2 * k + 1))
            wait_for(lambda: len(statuses) >= 12, 20)
            time.sleep(0.2)
    finally:
        vo_node.destroy_node()
        io.destroy_node()
    assert len(statuses) == 12
    # estimates at frames 1..11, one path per 0.3 s of message time: at frames 1, 4, 7 and 10
    assert [stamp_to_nanoseconds(p.header.stamp) for p in paths] == [k * 100_000_000 for k in (1, 4, 7, 10)]
    assert [len(p.poses) for p in paths] == [1, 4, 4, 4]


def probe_node_relative_poses(ros_context, sample_bag: Path, before_play: Any = None) -> list[RelativePose]:
    """The sample bag through a stereo_vo node with probe.model = probe_kitti: its /pvo/vo/relative messages.
    ``before_play(vo_node, player_node)`` runs once both spin, before the bag plays."""
    vo_node = StereoVONode(context=ros_context, parameter_overrides=[Parameter("probe.model", value="probe_kitti")])
    listener = Node("listener", context=ros_context)
    player_node = Node("player", context=ros_context)
    relative: list[RelativePose] = []
    listener.create_subscription(RelativePose, "/pvo/vo/relative", relative.append, RELIABLE)
    try:
        with Spinner(ros_context, vo_node), Spinner(ros_context, listener):
            if before_play is not None:
                before_play(vo_node, player_node)
            BagPlayer(player_node, sample_bag, PlayOptions(rate=2.0, wait_for_subscribers=1, clock=False)).play()
            wait_for(lambda: len(relative) >= 50)
    finally:
        for node in (vo_node, listener, player_node):
            node.destroy_node()
    assert len(relative) == 50
    return relative


def test_stereo_vo_with_probe_model_over_dds(ros_context, sample_bag: Path, pvo_data: Path) -> None:
    """probe.model set on the node (the shipped probe_kitti): the relative poses over DDS are what the
    ROS-free VO with that model computes, and differ from the plain VO's."""
    from pvo_frontend.vo import from_flat

    relative = probe_node_relative_poses(ros_context, sample_bag)
    stamps = [stamp_to_nanoseconds(m.reference_stamp) for m in relative[:1]] + [
        stamp_to_nanoseconds(m.header.stamp) for m in relative
    ]
    sequence = KittiSequence(pvo_data / "kitti/sequences/06", rate_hz=10.0)
    with_probe = StereoVO(sequence.camera(1226, 370), from_flat({"probe.model": "probe_kitti"}))
    plain = StereoVO(sequence.camera(1226, 370))
    expected = [with_probe.process(*sequence.load_pair(i), stamps[i] * 1e-9) for i in range(len(sequence))]
    baseline = [plain.process(*sequence.load_pair(i), stamps[i] * 1e-9) for i in range(len(sequence))]
    for msg, result in zip(relative, expected[1:], strict=True):
        assert np.allclose(pose_to_matrix(msg.pose.pose), result.transform, atol=1e-9)
    assert not np.allclose(expected[-1].pose, baseline[-1].pose, atol=1e-6)  # the model changed the estimate


def test_stereo_vo_reads_imu_data_for_a_probe_model_with_imu_predictors(ros_context, sample_bag: Path, pvo_data: Path) -> None:
    """probe_kitti has IMU predictors: with /imu/data at the frames' stamps (the raw drive's IMU) the node's
    relative poses are the ROS-free VO's with those readings, and differ from its images-only ones."""
    from pvo_core.readers import read_klt_tracks
    from pvo_frontend.vo import from_flat
    from pvo_tools.bagio import iter_messages, open_bag
    from sensor_msgs.msg import Imu

    with open_bag(sample_bag) as reader:
        left = [c for c in reader.connections if c.topic == "/stereo/left/image_rect"]
        stamps = [t for _, t, _ in iter_messages(reader, left)]
    drive = read_klt_tracks(pvo_data / "kitti/raw-derived/2011_09_30_drive_0020_sync_KLT.mat")  # odometry 06
    readings = np.column_stack([drive.angular_rate, drive.specific_force])[: len(stamps)]

    def publish_imu(vo_node: StereoVONode, player_node: Node) -> None:
        publisher = player_node.create_publisher(Imu, "/imu/data", QoSProfile(depth=400, reliability=ReliabilityPolicy.RELIABLE))
        wait_for(lambda: publisher.get_subscription_count() >= 1)
        for stamp, reading in zip(stamps, readings, strict=True):
            msg = Imu()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            w, a = msg.angular_velocity, msg.linear_acceleration
            w.x, w.y, w.z = (float(v) for v in reading[:3])
            a.x, a.y, a.z = (float(v) for v in reading[3:])
            publisher.publish(msg)
        wait_for(lambda: len(vo_node._imu) >= len(stamps))

    relative = probe_node_relative_poses(ros_context, sample_bag, publish_imu)
    sequence = KittiSequence(pvo_data / "kitti/sequences/06", rate_hz=10.0)
    with_imu = StereoVO(sequence.camera(1226, 370), from_flat({"probe.model": "probe_kitti"}))
    images_only = StereoVO(sequence.camera(1226, 370), from_flat({"probe.model": "probe_kitti"}))
    expected = [with_imu.process(*sequence.load_pair(i), stamps[i] * 1e-9, readings[i]) for i in range(len(sequence))]
    without = [images_only.process(*sequence.load_pair(i), stamps[i] * 1e-9) for i in range(len(sequence))]
    for msg, result in zip(relative, expected[1:], strict=True):
        assert np.allclose(pose_to_matrix(msg.pose.pose), result.transform, atol=1e-9)
    assert not np.allclose(expected[-1].pose, without[-1].pose, atol=1e-9)  # the readings were used


def test_a_missing_probe_model_stops_the_node_at_start_with_one_line(ros_context, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"PROBE model .*missing: no such directory"):
        StereoVONode(context=ros_context, parameter_overrides=[Parameter("probe.model", value=str(tmp_path / "missing"))])
