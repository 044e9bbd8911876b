"""Issue 18, defects 2 and 8: the README's commands — start the node, then `pvo bag play` at once — deliver every
frame, and what is published while nobody listens is counted and reported."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

pytestmark = pytest.mark.ros


def test_play_right_after_starting_stereo_vo_delivers_every_frame(ros_context, ros_env, sample_bag: Path, tmp_path: Path) -> None:
    listener = Node("listener", context=ros_context)
    statuses: list[DiagnosticArray] = []
    listener.create_subscription(
        DiagnosticArray, "/pvo/vo/status", statuses.append, QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
    )
    log = (tmp_path / "stereo_vo.log").open("w")
    node = subprocess.Popen(["pvo", "run", "pvo_frontend", "stereo_vo"], env=ros_env, stdout=log, stderr=subprocess.STDOUT)
    try:
        with Spinner(ros_context, listener):
            played = subprocess.run(
                ["pvo", "bag", "play", str(sample_bag), "--rate", "3"], env=ros_env, capture_output=True, text=True, timeout=120
            )
            assert played.returncode == 0, played.stderr
            wait_for(lambda: bool(statuses) and _value(statuses[-1], "processed") == "51", 60)
    finally:
        node.terminate()
        code = node.wait(timeout=30)
        log.close()
        listener.destroy_node()
    text = (tmp_path / "stereo_vo.log").read_text()
    assert code == 0, text[-2000:]  # SIGTERM is a clean shutdown
    # every stereo pair reached the node and was processed (the node's own account at shutdown; our status
    # subscription may match the freshly started node after its first frames)
    summary = "processed 51, lost_frames 0, rejected 0, waiting_for_camera_info 0, missing_images 0, skipped_overload 0"
    assert f"stereo_vo: {summary}, dropped_unpaired 0" in text, text
    assert statuses and _value(statuses[-1], "processed") == "51"

    report = played.stderr.strip().splitlines()[-1]
    assert report.startswith("played 306 messages")  # 6 topics x 51 frames
    # nobody subscribes to the ground truth here: said, with the counts
    assert (
        "published with no subscriber (nobody received them): /ground_truth/odometry (51), /ground_truth/sun_direction (51)"
        in report
    )


def _value(array: DiagnosticArray, key: str) -> str | None:
    return next((kv.value for kv in array.status[0].values if kv.key == key), None)
