"""Fuzzing the stereo_vo node's inputs over DDS (issue 18): every bad image, stamp or camera_info is rejected
with its reason in /pvo/vo/status, frames that never arrive are counted, and the node keeps processing."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from fuzzing import set_stamp, wait_for
from pvo_frontend.stereo_vo_node import StereoVONode
from pvo_tools.testing import Spinner
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
W, H = 160, 120
SECOND = 1_000_000_000


def image(stamp: int, seed: int, width: int = W, height: int = H, encoding: str = "mono8") -> Image:
    msg = Image()
    set_stamp(msg.header.stamp, stamp)
    channels = 3 if encoding in ("rgb8", "bgr8") else 1
    msg.height, msg.width, msg.encoding, msg.step = height, width, encoding, width * channels
    msg.data = np.random.default_rng(seed).integers(0, 255, width * height * channels, dtype=np.uint8).tobytes()
    return msg


def info(stamp: int, tx: float, p00: float = 120.0) -> CameraInfo:
    msg = CameraInfo()
    set_stamp(msg.header.stamp, stamp)
    msg.width, msg.height = W, H
    msg.p = [p00, 0.0, W / 2, tx, 0.0, 120.0, H / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def stereo_publishers(io: Node) -> tuple:
    """Publishers of the left and right images and camera_info, in that order."""
    return (
        io.create_publisher(Image, "/stereo/left/image_rect", RELIABLE),
        io.create_publisher(Image, "/stereo/right/image_rect", RELIABLE),
        io.create_publisher(CameraInfo, "/stereo/left/camera_info", RELIABLE),
        io.create_publisher(CameraInfo, "/stereo/right/camera_info", RELIABLE),
    )


def bad_pairs(t: int) -> list[tuple[str, Image, Image, str]]:
    """(name, left, right, words the rejection must contain), each at stamp t (after frames up to t - 1 s)."""
    empty = image(t, 1)
    empty.data = b""
    short = image(t, 2)
    short.data = bytes(short.data)[: W * H // 2]
    zero = image(t, 3)
    zero.width = 0
    return [
        ("unknown encoding", image(t, 4, encoding="yuv422"), image(t, 5), "unsupported image encoding 'yuv422'"),
        ("empty image", empty, image(t, 6), "image data of 0 bytes does not match"),
        ("truncated image", short, image(t, 7), f"image data of {W * H // 2} bytes does not match"),
        ("zero width", zero, image(t, 8), "does not match 0x120"),
        ("size differs from camera_info", image(t, 9, 100, 80), image(t, 10, 100, 80), "differs from camera_info 160x120"),
        ("pair of different sizes", image(t, 11), image(t, 12, 100, 80), "stereo images differ in size"),
        ("rgb left, grey right", image(t, 13, encoding="rgb8"), image(t, 14), "left 160x120 rgb8, right 160x120 mono8"),
    ]


def test_every_bad_input_is_rejected_with_its_reason_and_missing_frames_are_counted(ros_context) -> None:
    vo_node = StereoVONode(context=ros_context)
    io = Node("io", context=ros_context)
    statuses: list[DiagnosticArray] = []
    io.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    left, right, left_info, right_info = stereo_publishers(io)

    def frame(stamp: int, seed: int, with_images: bool = True) -> None:
        left_info.publish(info(stamp, 0.0))
        right_info.publish(info(stamp, -60.0))
        if with_images:
            left.publish(image(stamp, 2 * seed))
            right.publish(image(stamp, 2 * seed + 1))

    expected: list[str] = []
    try:
        with Spinner(ros_context, vo_node, io):
            assert wait_for(lambda: left.get_subscription_count() > 0 and right_info.get_subscription_count() > 0)
            assert wait_for(lambda: vo_node.pub_status.get_subscription_count() > 0)
            for k in range(3):
                frame(k * SECOND, k)
            assert wait_for(lambda: len(statuses) == 3)
            for name, bad_left, bad_right, words in bad_pairs(10 * SECOND):
                left_info.publish(info(10 * SECOND, 0.0))
                left.publish(bad_left)
                right.publish(bad_right)
                expected.append(words)
                count = len(expected) + 3
                assert wait_for(lambda count=count: len(statuses) == count), name
                stamp = 10 * SECOND
                for msg in (bad_left, bad_right):
                    set_stamp(msg.header.stamp, stamp)
            # a stamp already processed, and one going back in time
            frame(2 * SECOND, 20)
            expected.append("repeated frame")
            # the 2 s pair complete before the 1 s one is sent: left and right are separate topics, and a left
            # image of 1 s arriving before the right of 2 s would be dropped as stale when that pair completes
            assert wait_for(lambda: len(statuses) == len(expected) + 3)
            frame(1 * SECOND, 21)
            expected.append("stamp goes backwards")
            assert wait_for(lambda: len(statuses) == len(expected) + 3)
            # frame 4 s announces itself but its images never arrive; 5 s is complete
            frame(4 * SECOND, 4, with_images=False)
            frame(5 * SECOND, 5)
            assert wait_for(lambda: len(statuses) == len(expected) + 4)
            # counted when the 5 s pair arrives, or when the 4 s camera_info arrives after it
            assert wait_for(lambda: vo_node.counts["missing_images"] == 1)
    finally:
        vo_node.destroy_node()
        io.destroy_node()
    rejections = [s.status[0] for s in statuses[3 : 3 + len(expected)]]
    for status, words in zip(rejections, expected, strict=True):
        assert status.level == b"\x02" and words in status.message, (words, status.message)
    last = {kv.key: kv.value for kv in statuses[-1].status[0].values}
    assert last["rejected"] == str(len(expected)) and last["processed"] == str(len(expected) + 4)
    # the bad 10 s frames announced themselves too; only 4 s had neither images nor a rejection
    assert last["lost"] in ("True", "False") and int(last["lost_frames"]) >= 1
    assert vo_node.counts["missing_images"] == 1


def test_bad_camera_info_is_rejected_and_a_good_one_starts_the_node(ros_context) -> None:
    vo_node = StereoVONode(context=ros_context)
    io = Node("io", context=ros_context)
    statuses: list[DiagnosticArray] = []
    io.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    left, right, left_info, right_info = stereo_publishers(io)
    nan_info = info(0, 0.0)
    nan_info.p = [float("nan")] * 12
    wrong_size = copy.deepcopy(info(0, -60.0))  # a right camera of another size
    wrong_size.width = 200
    try:
        with Spinner(ros_context, vo_node, io):
            assert wait_for(lambda: left.get_subscription_count() > 0 and right_info.get_subscription_count() > 0)
            assert wait_for(lambda: vo_node.pub_status.get_subscription_count() > 0)
            # every right here is bad, whichever left the node pairs it with
            nan_right = info(0, -60.0)
            nan_right.p = [float("nan")] * 12
            for bad_left, bad_right in (
                (nan_info, nan_right),
                (info(0, 0.0, p00=0.0), info(0, 60.0)),
                (info(0, 0.0), info(0, 60.0)),
                (info(0, 0.0), wrong_size),
            ):
                left_info.publish(bad_left)
                right_info.publish(bad_right)
                left.publish(image(0, 1))
                right.publish(image(0, 2))
            wait_for(lambda: vo_node.vo is not None, 2.0)
            assert vo_node.vo is None
            left_info.publish(info(SECOND, 0.0))
            right_info.publish(info(SECOND, -60.0))
            assert wait_for(lambda: vo_node.vo is not None)
            left.publish(image(SECOND, 3))
            right.publish(image(SECOND, 4))
            assert wait_for(lambda: any(s.status[0].message == "first frame" for s in statuses))
    finally:
        vo_node.destroy_node()
        io.destroy_node()
    assert vo_node.vo.camera.baseline == pytest.approx(0.5)


def test_under_overload_a_frame_behind_the_clock_is_skipped_and_said(ros_context) -> None:
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock

    overrides = [Parameter("use_sim_time", value=True), Parameter("max_lag", value=0.5)]
    vo_node = StereoVONode(context=ros_context, parameter_overrides=overrides)
    io = Node("io", context=ros_context)
    statuses: list[DiagnosticArray] = []
    io.create_subscription(DiagnosticArray, "/pvo/vo/status", statuses.append, RELIABLE)
    clock = io.create_publisher(Clock, "/clock", 10)
    pubs = {
        topic: io.create_publisher(kind, topic, RELIABLE)
        for topic, kind in (
            ("/stereo/left/image_rect", Image),
            ("/stereo/right/image_rect", Image),
            ("/stereo/left/camera_info", CameraInfo),
            ("/stereo/right/camera_info", CameraInfo),
        )
    }

    def tick(seconds: int) -> None:
        msg = Clock()
        set_stamp(msg.clock, seconds * SECOND)
        clock.publish(msg)
        wait_for(lambda: vo_node.get_clock().now().nanoseconds == seconds * SECOND, 5.0)

    def frame(stamp: int, seed: int) -> None:
        pubs["/stereo/left/camera_info"].publish(info(stamp, 0.0))
        pubs["/stereo/right/camera_info"].publish(info(stamp, -60.0))
        pubs["/stereo/left/image_rect"].publish(image(stamp, seed))
        pubs["/stereo/right/image_rect"].publish(image(stamp, seed + 1))

    try:
        with Spinner(ros_context, vo_node, io):
            assert wait_for(lambda: all(p.get_subscription_count() > 0 for p in pubs.values()))
            assert wait_for(lambda: clock.get_subscription_count() > 0 and vo_node.pub_status.get_subscription_count() > 0)
            tick(100)
            frame(100 * SECOND, 1)
            assert wait_for(lambda: len(statuses) == 1)
            tick(200)
            frame(101 * SECOND, 3)  # 99 s behind: the node cannot have kept up
            assert wait_for(lambda: len(statuses) == 2)
            frame(200 * SECOND, 5)
            assert wait_for(lambda: len(statuses) == 3)
    finally:
        vo_node.destroy_node()
        io.destroy_node()
    assert statuses[1].status[0].message == "frame skipped: 99.00 s behind the clock (overload)"
    assert vo_node.counts["skipped_overload"] == 1 and vo_node.counts["processed"] == 2
