"""The sun experiment end to end through the nodes: a bag of VO and sun messages -> ``fusion`` over
DDS -> a recorded bag, compared with the ROS-free :func:`~pvo_tools.experiments.sun_sim.run_fusion`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.config import flatten
from pvo_core.msgconv import pose_to_xyz_xyzw
from pvo_core.readers import KittiSunSequence
from pvo_core.results import RunResult
from pvo_fusion.sun_reference import TabulatedSunReference

from pvo_core import metrics
from pvo_fusion import RelativeMeasurement, SunMeasurement, ordered_events, sun_events
from pvo_fusion.config import FusionConfig, from_flat

from .. import rosmsgs
from ..bagio import SafeBagWriter
from ..errors import PvoError
from ..overrides import parse_overrides
from ..recorded import read_recorded
from .sun_sim import experiment_config, prepare_sequence, run_fusion

Array = NDArray[np.float64]
FRAME = "camera_left_optical"
OUTPUT_TOPICS = ["/pvo/fusion/odometry", "/pvo/fusion/path", "/pvo/fusion/status"]


def write_input_bag(path: Path, vo: list[RelativeMeasurement], sun: list[SunMeasurement], overwrite: bool = True) -> int:
    """The VO and sun measurements as a rosbag2 (MCAP) in arrival order; returns the message count."""
    count = 0
    with SafeBagWriter(path, overwrite=overwrite) as writer:
        writer.add_topic("/pvo/vo/relative", "pvo_msgs/msg/RelativePose")
        writer.add_topic("/pvo/sun/direction", "pvo_msgs/msg/SunDirection")
        for kind, m in ordered_events(vo, sun_events(sun)):
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


def run_through_nodes(
    seq: KittiSunSequence,
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

    from ..player import BagPlayer, PlayOptions
    from ..recorder import BagRecorder, RecordOptions
    from ..testing import Spinner

    work_dir.mkdir(parents=True, exist_ok=True)
    input_bag = work_dir / "input"
    output_bag = work_dir / "output"
    table = work_dir / "sun_reference.csv"
    write_input_bag(input_bag, vo, sun)
    TabulatedSunReference.write(table, seq.stamps, seq.sun_map())
    values = {
        "prior.source": "given",
        "initial_pose": pose_to_xyz_xyzw(seq.ground_truth[0]),
        "inputs.sun.reference": "table",
        "inputs.sun.reference_table": str(table),
        "path_period": 0.0,  # a path per frame: the last one carries every final estimate
        "path_max_poses": 0,
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
    recorded = read_recorded(output_bag, ["/pvo/fusion/path", "/pvo/fusion/odometry"])
    if "/pvo/fusion/path" not in recorded or "/pvo/fusion/odometry" not in recorded:
        raise PvoError(f"{output_bag}: the fusion node published no path or no odometry")
    poses, _ = recorded["/pvo/fusion/path"].at(seq.stamps)
    online, _ = recorded["/pvo/fusion/odometry"].at(seq.stamps)
    online[0] = poses[0]
    return NodeRun(poses, online, latencies, len(recorded["/pvo/fusion/odometry"].stamps), wall)


def compare_through_nodes(args: Any, data: Path) -> int:
    """`pvo experiment sun-sim --through-nodes SEQ`: the node's figures against the ROS-free run's."""

    name = args.through_nodes
    seq, vo, sun = prepare_sequence(data, name, 10.0, args.seed, args.frames)
    overrides = parse_overrides(args.param)
    ros_free = run_fusion(seq, vo, sun, experiment_config(overrides))
    print(f"sequence {name}: {len(seq.stamps)} frames, {len(sun)} GT-Sun-10 measurements; playing at {args.rate:g}x", flush=True)
    nodes = run_through_nodes(seq, vo, sun, args.out / f"nodes_{name}", overrides, rate=args.rate)
    a, b = metrics.armse(seq.ground_truth, ros_free.poses), metrics.armse(seq.ground_truth, nodes.poses)
    print(f"{'':<12}{'trans [m]':>12}{'EN [m]':>12}{'rot [1e-3]':>12}")
    for label, m in (("ROS-free", a), ("nodes", b)):
        print(f"{label:<12}{m['trans']:>12.6f}{m['trans_en']:>12.6f}{1e3 * m['rot']:>12.6f}")
    diff = metrics.max_pose_difference(nodes.poses, ros_free.poses)
    # Online (newest-state) estimates match where no sun measurement shares the frame: when a frame's sun
    # message reaches the node before its VO, the node publishes after fusing both (the ROS-free run before).
    sun_frames = {int(m.stamp) for m in sun}
    plain = [k for k in range(1, len(seq.stamps)) if int(seq.stamps[k]) not in sun_frames]
    online = metrics.max_pose_difference(nodes.online_poses[plain], ros_free.online_poses[plain])
    print(
        f"max |pose difference|: final {diff:.2e}, online (frames without sun) {online:.2e}; "
        f"odometry messages {nodes.odometry_messages}/{len(vo)}"
    )
    if nodes.latencies_ms:
        lat = metrics.latency_summary(nodes.latencies_ms)
        print(
            f"node latency VO in -> odometry out: median {lat['median_ms']:.2f} ms, "
            f"p95 {lat['p95_ms']:.2f} ms, max {lat['max_ms']:.2f} ms"
        )
    record = RunResult(
        "experiment/sun-sim-through-nodes",
        name,
        figures={
            **{f"ros_free.{k}": v for k, v in a.items()},
            **{f"nodes.{k}": v for k, v in b.items()},
            "max_pose_difference_final": diff,
            "max_pose_difference_online_without_sun": online,
            "odometry_messages": nodes.odometry_messages,
            "vo_messages": len(vo),
            "wall_s": nodes.wall_seconds,
            **({f"latency.{k}": v for k, v in metrics.latency_summary(nodes.latencies_ms).items()}),
        },
        inputs={
            "data": str(data),
            "frames": str(len(seq.stamps)),
            "rate": str(args.rate),
            "parameters": " ".join(args.param or []),
        },
        notes={"armse": metrics.ARMSE_DEFINITION},
    )
    path = record.write(args.out / f"nodes_{name}")
    print(f"wall time {nodes.wall_seconds:.1f} s; bags and {path.name} in {args.out / f'nodes_{name}'}")
    return 0 if nodes.odometry_messages == len(vo) and diff < 1e-6 else 1
