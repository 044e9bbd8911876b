"""Graph-level tests over DDS (loopback, a fresh context and domain per test, no launch).

Convert the real KITTI 06 clip -> play it -> subscribers receive every stereo pair with identical
bytes and stamps and /clock advancing; play -> record -> the recorded bag equals the source; the
`pvo` CLI against live publishers.
"""

from __future__ import annotations

import itertools
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pvo_core.readers import KittiSequence
from pvo_tools.bagrecover import recover_bag
from pvo_tools.convert import convert_kitti
from pvo_tools.player import BagPlayer, PlayOptions
from pvo_tools.recorder import BagRecorder, RecordOptions
from pvo_tools.testing import Spinner
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from std_msgs.msg import String

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
IMAGE_TOPICS = ("/stereo/left/image_rect", "/stereo/right/image_rect")


@pytest.fixture(scope="session")
def kitti06_bag(pvo_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = pvo_data / "kitti/sequences/06"
    out = tmp_path_factory.mktemp("kitti06") / "bag"
    sequence = KittiSequence(
        root, rate_hz=10.0, poses_file=root / "poses_frames000-050.txt", sun_file=pvo_data / "kitti/sun/kitti_sun_test_06.csv"
    )
    convert_kitti(sequence, out, epoch=1317384506.0, show_progress=False)
    return out


def bag_messages(bag: Path, topics: set[str]) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {topic: [] for topic in topics}
    with Reader(bag) as reader:
        for connection, stamp, raw in reader.messages():
            if connection.topic in topics:
                out[connection.topic].append((stamp, bytes(raw)))
    return out


@pytest.fixture
def nodes(ros_context) -> Iterator[list[Node]]:
    created: list[Node] = []
    yield created
    for node in created:
        node.destroy_node()


def test_play_delivers_every_stereo_pair_unchanged(ros_context, nodes, kitti06_bag: Path) -> None:
    listener = Node("listener", context=ros_context)
    player_node = Node("player", context=ros_context)
    nodes += [listener, player_node]
    received: dict[str, list[bytes]] = {topic: [] for topic in IMAGE_TOPICS}
    clock: list[int] = []
    for topic in IMAGE_TOPICS:
        listener.create_subscription(Image, topic, lambda raw, topic=topic: received[topic].append(raw), RELIABLE, raw=True)
    listener.create_subscription(Clock, "/clock", lambda m: clock.append(m.clock.sec * 10**9 + m.clock.nanosec), RELIABLE)
    with Spinner(ros_context, listener):
        stats = BagPlayer(player_node, kitti06_bag, PlayOptions(rate=4.0, wait_for_subscribers=1)).play()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and min(len(v) for v in received.values()) < 51:
            time.sleep(0.05)
    assert stats.messages == 306
    expected = bag_messages(kitti06_bag, set(IMAGE_TOPICS))
    for topic in IMAGE_TOPICS:
        assert len(received[topic]) == 51, topic
        assert received[topic] == [raw for _, raw in expected[topic]]  # identical bytes, hence stamps
    assert len(clock) >= 51 and all(b >= a for a, b in itertools.pairwise(clock))
    assert clock[-1] - clock[0] == pytest.approx(5.0e9, rel=0.05)
    assert clock[0] == expected[IMAGE_TOPICS[0]][0][0]


def play_into_recorder(
    ros_context, nodes: list[Node], bag: Path, out: Path, topics: list[str], expected: int
) -> tuple[BagRecorder, Node]:
    """``bag`` played at 4x into a recorder of ``topics`` (header stamps) writing ``out``, until it holds ``expected``
    messages (10 s at most); the recorder is left open."""
    recorder_node = Node("recorder", context=ros_context)
    player_node = Node("player", context=ros_context)
    nodes += [recorder_node, player_node]
    recorder = BagRecorder(recorder_node, out, RecordOptions(topics=topics, stamp="header"))
    player = BagPlayer(player_node, bag, PlayOptions(rate=4.0, wait_for_subscribers=1, clock=False))
    with Spinner(ros_context, recorder_node):
        player.play()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and sum(recorder.writer.counts.values()) < expected:
            time.sleep(0.05)
    return recorder, recorder_node


def test_play_then_record_reproduces_the_bag(ros_context, nodes, kitti06_bag: Path, tmp_path: Path) -> None:
    topics = [
        *IMAGE_TOPICS,
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
        "/ground_truth/odometry",
        "/ground_truth/sun_direction",
    ]
    recorder, _ = play_into_recorder(ros_context, nodes, kitti06_bag, tmp_path / "recorded", topics, 306)
    counts = recorder.close()
    assert counts == dict.fromkeys(topics, 51)
    source = bag_messages(kitti06_bag, set(topics))
    recorded = bag_messages(tmp_path / "recorded", set(topics))
    for topic in topics:
        assert recorded[topic] == source[topic], topic  # same stamps, same bytes, same order
    with Reader(tmp_path / "recorded") as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        definitions = {c.topic: c.msgdef.data for c in reader.connections}
    assert types["/ground_truth/sun_direction"] == "pvo_msgs/msg/SunDirection"
    assert "float64[4] covariance" in definitions["/ground_truth/sun_direction"]


def test_cli_play_reaches_a_subscriber(ros_context, nodes, ros_env, sample_bag: Path) -> None:
    listener = Node("listener", context=ros_context)
    nodes.append(listener)
    received: list[bytes] = []
    listener.create_subscription(Image, "/stereo/left/image_rect", received.append, RELIABLE, raw=True)
    with Spinner(ros_context, listener):
        result = subprocess.run(
            [
                "pvo",
                "bag",
                "play",
                str(sample_bag),
                "--rate",
                "5",
                "--topics",
                "/stereo/left/image_rect",
                "--wait-for-subscribers",
                "1",
            ],
            env=ros_env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(received) < 51:
            time.sleep(0.05)
    assert result.returncode == 0, result.stderr
    assert "played 51 messages" in result.stderr
    assert received == [raw for _, raw in bag_messages(sample_bag, {"/stereo/left/image_rect"})["/stereo/left/image_rect"]]


def test_cli_against_a_live_publisher(ros_context, nodes, ros_env) -> None:
    talker = Node("talker", namespace="/demo", context=ros_context)
    nodes.append(talker)
    publisher = talker.create_publisher(String, "/chatter", 10)
    count = [0]

    def tick() -> None:
        count[0] += 1
        publisher.publish(String(data=f"hello {count[0]}"))

    talker.create_timer(0.1, tick)
    with Spinner(ros_context, talker):
        echo = subprocess.run(
            ["pvo", "topic", "echo", "/chatter", "--count", "2"], env=ros_env, capture_output=True, text=True, timeout=60
        )
        hz = subprocess.run(
            ["pvo", "topic", "hz", "/chatter", "--duration", "3.5"], env=ros_env, capture_output=True, text=True, timeout=60
        )
        listing = subprocess.run(
            ["pvo", "topic", "list", "-t", "--wait", "8"], env=ros_env, capture_output=True, text=True, timeout=60
        )
        info = subprocess.run(["pvo", "topic", "info", "/chatter"], env=ros_env, capture_output=True, text=True, timeout=60)
        node_list = subprocess.run(
            ["pvo", "node", "list", "--wait", "8"], env=ros_env, capture_output=True, text=True, timeout=60
        )
        missing = subprocess.run(
            ["pvo", "topic", "echo", "/nothing", "--wait", "0.5"], env=ros_env, capture_output=True, text=True, timeout=60
        )
    assert echo.returncode == 0, echo.stderr
    blocks = [b.strip() for b in echo.stdout.split("---") if b.strip()]
    assert len(blocks) == 2 and all(b.startswith("data: 'hello ") for b in blocks)
    rates = [float(line.split(":")[1]) for line in hz.stdout.splitlines() if line.startswith("average rate")]
    assert rates and rates[-1] == pytest.approx(10.0, rel=0.2)
    assert "/chatter [std_msgs/msg/String]" in listing.stdout
    assert "Type: std_msgs/msg/String" in info.stdout and "Publisher count: 1" in info.stdout
    assert "/demo/talker" in node_list.stdout.splitlines()
    assert missing.returncode == 2 and "unknown topic '/nothing'" in missing.stderr


def test_loop_restamps_each_pass_so_stamps_keep_increasing(ros_context, tmp_path: Path) -> None:
    """Issue 18: a looped bag is a valid long run — header stamps and /clock increase across passes."""
    from pvo_tools.bagio import SafeBagWriter
    from pvo_tools.typesys import project_typestore
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CameraInfo

    types = project_typestore().types
    bag = tmp_path / "small"
    with SafeBagWriter(bag) as writer:
        writer.add_topic("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo")
        for k in range(5):
            stamp = 1_000_000_000 + k * 100_000_000
            time_msg = types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
            info = types["sensor_msgs/msg/CameraInfo"](
                header=types["std_msgs/msg/Header"](stamp=time_msg, frame_id="c"),
                height=10,
                width=10,
                distortion_model="",
                d=np.zeros(0),
                k=np.zeros(9),
                r=np.zeros(9),
                p=np.zeros(12),
                binning_x=0,
                binning_y=0,
                roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )
            writer.write("/stereo/left/camera_info", stamp, info)
    listener = Node("listener", context=ros_context)
    player_node = Node("player", context=ros_context)
    stamps: list[int] = []
    clocks: list[int] = []
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    listener.create_subscription(
        CameraInfo, "/stereo/left/camera_info", lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), qos
    )
    listener.create_subscription(Clock, "/clock", lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 100)
    try:
        with Spinner(ros_context, listener):
            stats = BagPlayer(player_node, bag, PlayOptions(rate=10.0, loop=True, passes=3)).play()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and len(stamps) < 15:
                time.sleep(0.02)
    finally:
        listener.destroy_node()
        player_node.destroy_node()
    assert stats.passes == 3 and stats.messages == 15
    expected = [1_000_000_000 + k * 100_000_000 for k in range(15)]  # each pass one frame interval after the last
    assert stamps == expected
    assert all(b > a for a, b in itertools.pairwise(clocks))


def test_a_recording_cut_off_is_kept_named_and_recovered(
    ros_context, nodes, kitti06_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """What a recorder killed mid-recording (SIGKILL, power lost) leaves on disk — its hidden partial bag, no footer,
    no metadata.yaml — is kept by the next recording to that path, named with the command that saves it, and
    `pvo bag recover` gives back the messages it holds byte for byte."""
    topics = [*IMAGE_TOPICS, "/stereo/left/camera_info", "/stereo/right/camera_info"]
    recorder, recorder_node = play_into_recorder(ros_context, nodes, kitti06_bag, tmp_path / "recorded", topics, 4 * 51)
    # the disk as a kill would leave it: the writer still open, its footer and metadata.yaml never written
    (live,) = tmp_path.glob(".recorded.partial-*")
    killed = tmp_path / ".again.partial-999999999-deadbeef"  # a pid that cannot exist: a dead recorder's
    shutil.copytree(live / "recorded", killed / "again")
    recorder.close()
    assert not (killed / "again" / "metadata.yaml").exists()
    capsys.readouterr()
    BagRecorder(recorder_node, tmp_path / "again", RecordOptions(topics=topics)).close()
    left = killed / "again"
    assert f"`pvo bag recover {left} -o NEW` saves what it holds" in capsys.readouterr().err
    assert left.is_dir()  # kept: a recording cannot be made again
    recovery = recover_bag(left, tmp_path / "saved")
    assert recovery.chunks_read >= 1 and recovery.problems  # the cut is named
    source = bag_messages(kitti06_bag, set(topics))
    saved = bag_messages(tmp_path / "saved", set(topics))
    assert sum(len(v) for v in saved.values()) == sum(recovery.messages.values()) > 0
    for topic in topics:
        assert saved[topic] == source[topic][: len(saved[topic])], topic
