"""The sun experiment end to end through the nodes: a bag of VO and sun messages -> ``fusion`` over
DDS -> a recorded bag, compared with the ROS-free :func:`~pvo_tools.sun_experiment.run_fusion`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.config import flatten
from pvo_core.lie import rotation_to_quaternion
from pvo_fusion.sun_reference import TabulatedSunReference

from pvo_fusion import RelativeMeasurement, SunMeasurement
from pvo_fusion.config import FusionConfig, from_flat

from . import rosmsgs
from .bagio import SafeBagWriter, iter_messages, open_bag
from .sun_experiment import SunSequence, ordered_events

Array = NDArray[np.float64]
FRAME = "camera_left_optical"
INPUT_TOPICS = ("/pvo/vo/relative", "/pvo/sun/direction")
OUTPUT_TOPICS = ["/pvo/fusion/odometry", "/pvo/fusion/path", "/pvo/fusion/status"]


def write_input_bag(path: Path, vo: list[RelativeMeasurement], sun: list[SunMeasurement], overwrite: bool = True) -> int:
    """The VO and sun measurements as a rosbag2 (MCAP) in arrival order; returns the message count."""
    count = 0
    with SafeBagWriter(path, overwrite=overwrite) as writer:
        writer.add_topic("/pvo/vo/relative", "pvo_msgs/msg/RelativePose")
        writer.add_topic("/pvo/sun/direction", "pvo_msgs/msg/SunDirection")
        for kind, m in ordered_events(vo, sun):
            if kind == "vo":
                assert isinstance(m, RelativeMeasurement)
                msg = rosmsgs.relative_pose(m.stamp, m.reference_stamp, FRAME, m.transform, m.covariance)
                writer.write("/pvo/vo/relative", m.stamp, msg)
            else:
                assert isinstance(m, SunMeasurement)
                writer.write("/pvo/sun/direction", m.stamp, rosmsgs.sun_direction(m.stamp, FRAME, m.direction, m.covariance))
            count += 1
    return count


@dataclass
class NodeRun:
    poses: Array  # (N, 4, 4) from the last /pvo/fusion/path (final fixed-lag estimates + window)
    online_poses: Array  # (N, 4, 4) from /pvo/fusion/odometry
    latencies_ms: list[float]
    odometry_messages: int
    wall_seconds: float


def initial_pose_parameter(pose: Array) -> list[float]:
    w, x, y, z = rotation_to_quaternion(pose[:3, :3])
    return [float(v) for v in (*pose[:3, 3], x, y, z, w)]


def run_through_nodes(
    seq: SunSequence,
    vo: list[RelativeMeasurement],
    sun: list[SunMeasurement],
    work_dir: Path,
    parameters: dict | None = None,
    rate: float = 20.0,
    domain_id: int | None = None,
    timeout_s: float = 600.0,
) -> NodeRun:
    """Play the measurements through a ``fusion`` node in this process and record its output."""
    import rclpy
    from pvo_fusion.fusion_node import FusionNode
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from .player import BagPlayer, PlayOptions
    from .recorder import BagRecorder, RecordOptions
    from .testing import Spinner

    work_dir.mkdir(parents=True, exist_ok=True)
    input_bag = work_dir / "input"
    output_bag = work_dir / "output"
    table = work_dir / "sun_reference.csv"
    write_input_bag(input_bag, vo, sun)
    TabulatedSunReference.write(table, seq.stamps, seq.sun_map())
    values = {
        "prior.source": "given",
        "initial_pose": initial_pose_parameter(seq.ground_truth[0]),
        "inputs.sun.reference": "table",
        "inputs.sun.reference_table": str(table),
        "path_period": 0.0,  # a path per frame: the last one carries every final estimate
        **(parameters or {}),
    }
    # Typed as the node declares them (YAML reads "1e-5" as a string; the typed config accepts it).
    fields = flatten(FusionConfig())
    typed = flatten(from_flat({k: v for k, v in values.items() if k in fields}))
    overrides = [Parameter(name, value=typed.get(name, value)) for name, value in values.items()]
    context = Context()
    rclpy.init(context=context, domain_id=domain_id) if domain_id is not None else rclpy.init(context=context)
    expected = len(vo)
    start = time.perf_counter()
    try:
        fusion = FusionNode(context=context, parameter_overrides=overrides)
        recorder_node = Node("pvo_recorder", context=context)
        player_node = Node("pvo_player", context=context)
        recorder = BagRecorder(recorder_node, output_bag, RecordOptions(topics=OUTPUT_TOPICS, stamp="header", overwrite=True))
        try:
            with Spinner(context, fusion), Spinner(context, recorder_node):
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline and len(recorder.subscribed_topics) < len(OUTPUT_TOPICS):
                    recorder.discover()
                    time.sleep(0.05)
                BagPlayer(player_node, input_bag, PlayOptions(rate=rate, wait_for_subscribers=1, clock=False)).play()
                deadline = time.monotonic() + timeout_s
                while time.monotonic() < deadline and len(fusion.latencies_ms) < expected:
                    time.sleep(0.05)
                # the last path (published after the last odometry) must have reached the recorder
                while time.monotonic() < deadline and recorder.received("/pvo/fusion/path") < expected:
                    time.sleep(0.05)
        finally:
            recorder.close()
            latencies = list(fusion.latencies_ms)
            for node in (fusion, recorder_node, player_node):
                node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    wall = time.perf_counter() - start
    poses, online, count = read_fusion_output(output_bag, seq.stamps)
    return NodeRun(poses, online, latencies, count, wall)


def read_fusion_output(bag: Path, stamps: NDArray[np.int64]) -> tuple[Array, Array, int]:
    """Final poses from the last path message and online poses from the odometry, indexed by frame."""
    from pvo_core.msgconv import pose_to_matrix, stamp_to_nanoseconds

    from .typesys import project_typestore

    store = project_typestore()
    index = {int(s): i for i, s in enumerate(stamps)}
    final = np.full((len(stamps), 4, 4), np.nan)
    online = np.full((len(stamps), 4, 4), np.nan)
    last_path = None
    count = 0
    with open_bag(bag) as reader:
        for connection, _, raw in iter_messages(reader):
            if connection.topic == "/pvo/fusion/path":
                last_path = (connection, raw)
            elif connection.topic == "/pvo/fusion/odometry":
                msg = store.deserialize_cdr(raw, connection.msgtype)
                online[index[stamp_to_nanoseconds(msg.header.stamp)]] = pose_to_matrix(msg.pose.pose)
                count += 1
        if last_path is not None:
            path = store.deserialize_cdr(last_path[1], last_path[0].msgtype)
            for stamped in path.poses:
                final[index[stamp_to_nanoseconds(stamped.header.stamp)]] = pose_to_matrix(stamped.pose)
    online[0] = final[0]
    return final, online, count
