"""Long runs of the real node graph for benchmarks: the soak (``pvo bench soak``) — a bag looped through
stereo_vo + simulated_sun + sun_bcnn + fusion as processes, every node's memory sampled, every frame accounted
for and the end-to-end latency compared between the start and the end of the run — and the faults
(``pvo bench faults``)."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import PvoError

NODES = (("pvo_frontend", "stereo_vo"), ("pvo_pseudosensors", "simulated_sun"), ("pvo_fusion", "fusion"))
# the soak adds every learned pseudo-sensor node that exists; sun_bcnn's estimates join simulated_sun's on
# /pvo/sun/direction (the fusion takes both against the same reference)
SOAK_NODES = (*NODES, ("pvo_pseudosensors", "sun_bcnn"))
INPUTS = [
    "/stereo/left/image_rect",
    "/stereo/right/image_rect",
    "/stereo/left/camera_info",
    "/stereo/right/camera_info",
    "/ground_truth/sun_direction",
]


GRAPH_SETTLE_S = 2.0  # after discovery, for every publisher/subscriber pair to match


def _start_graph(
    group: Any, params_file: Path, log_dir: Path, env: dict[str, str], nodes: tuple[tuple[str, str], ...] = NODES
) -> None:
    for package, executable in nodes:
        group.start(package, executable, params_file, log_dir, env)


def _wait_connected(player_node: Any, group: Any, listeners: int) -> None:
    """Until the images and the VO each have ``listeners`` subscribers (the nodes, plus the benchmark's own
    listeners) and the fused odometry one, then the settle time."""
    from .launch import wait_for_graph

    edges = {"/stereo/left/image_rect": (0, listeners), "/pvo/vo/relative": (1, listeners), "/pvo/fusion/odometry": (1, 1)}
    wait_for_graph(player_node, edges, timeout_s=60.0, check=group.check)
    time.sleep(GRAPH_SETTLE_S)


def rss_mb(pid: int) -> float:
    """Resident set size of a process (MB) from /proc; NaN when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


@dataclass
class SoakResult:
    frames_played: int
    vo_messages: int
    fused_messages: int
    seconds: float
    rss: dict[str, list[tuple[float, float]]] = field(default_factory=dict)  # node -> (s, MB)
    latencies_ms: list[tuple[int, float]] = field(default_factory=list)  # (frame index, ms)
    exit_codes: dict[str, int] = field(default_factory=dict)
    sun_bcnn: dict[str, int] = field(default_factory=dict)  # its last status's counters: images, published, rejected


def run_soak(
    bag: Path,
    frames: int,
    rate: float,
    work: Path,
    domain_id: int,
    sun_direction: list[float],
    overrides: dict[str, dict[str, Any]] | None = None,
) -> SoakResult:
    """Loop ``bag`` until ``frames`` stereo frames were played at ``rate`` x real time through the graph;
    ``overrides``: node name -> parameters."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from pvo_msgs.msg import RelativePose

    from .baginfo import bag_info
    from .launch import NodeGroup
    from .player import BagPlayer, PlayOptions
    from .testing import Spinner

    per_pass = dict((t, n) for t, _, n, _ in bag_info(bag).topics).get("/stereo/left/image_rect", 0)
    if per_pass < 2:
        raise PvoError(f"{bag}: no stereo images to loop")
    passes = max(1, math.ceil(frames / per_pass))
    work.mkdir(parents=True, exist_ok=True)
    params = work / "params.yaml"
    params.write_text(
        yaml.safe_dump(
            {
                "stereo_vo": {"ros__parameters": {**(overrides or {}).get("stereo_vo", {})}},
                "simulated_sun": {"ros__parameters": {**(overrides or {}).get("simulated_sun", {})}},
                "sun_bcnn": {"ros__parameters": {**(overrides or {}).get("sun_bcnn", {})}},
                "fusion": {
                    "ros__parameters": {
                        "inputs.sun.reference": "fixed",
                        "inputs.sun.reference_direction": sun_direction,
                        **(overrides or {}).get("fusion", {}),
                    }
                },
            }
        )
    )
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    group = NodeGroup()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    image_seen: dict[int, float] = {}
    latencies: list[tuple[int, float]] = []
    counts = {"vo": 0, "fused": 0}
    every = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)

    def stamp(msg: Any) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def on_image(msg: Image) -> None:
        image_seen[stamp(msg)] = time.perf_counter()

    def on_vo(msg: RelativePose) -> None:
        counts["vo"] += 1

    sun_counters: dict[str, int] = {}

    def on_sun_status(msg: DiagnosticArray) -> None:
        for status in msg.status:
            sun_counters.update({kv.key: int(kv.value) for kv in status.values if kv.key in ("images", "published", "rejected")})

    def on_fused(msg: Odometry) -> None:
        counts["fused"] += 1
        seen = image_seen.pop(stamp(msg), None)
        for old in [s for s in image_seen if s < stamp(msg)]:
            del image_seen[old]  # bounded: frames without an odometry are not kept
        if seen is not None:
            latencies.append((counts["fused"], 1e3 * (time.perf_counter() - seen)))

    rss: dict[str, list[tuple[float, float]]] = {name: [] for _, name in SOAK_NODES}
    start = time.perf_counter()
    try:
        _start_graph(group, params, work / "logs", env, SOAK_NODES)
        listener = Node("pvo_soak_listener", context=context)
        player_node = Node("pvo_soak_player", context=context)
        listener.create_subscription(Image, "/stereo/left/image_rect", on_image, every)
        listener.create_subscription(RelativePose, "/pvo/vo/relative", on_vo, every)
        listener.create_subscription(Odometry, "/pvo/fusion/odometry", on_fused, every)
        listener.create_subscription(DiagnosticArray, "/pvo/sun_bcnn/status", on_sun_status, every)
        player = BagPlayer(player_node, bag, PlayOptions(rate=rate, loop=True, passes=passes, topics=INPUTS))
        with Spinner(context, listener):
            _wait_connected(player_node, group, listeners=2)
            import threading

            stop = threading.Event()

            def sample() -> None:
                while not stop.is_set():
                    for node in group.nodes:
                        rss[node.name].append((time.perf_counter() - start, rss_mb(node.process.pid)))
                    stop.wait(5.0)

            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            stats = player.play()
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and counts["fused"] < stats.per_topic.get("/stereo/left/image_rect", 0) - 1:
                group.check()
                time.sleep(0.1)
            stop.set()
            sampler.join()
        listener.destroy_node()
        player_node.destroy_node()
    finally:
        codes = group.stop()
        rclpy.shutdown(context=context)
    return SoakResult(
        stats.per_topic.get("/stereo/left/image_rect", 0),
        counts["vo"],
        counts["fused"],
        time.perf_counter() - start,
        rss,
        latencies,
        codes,
        dict(sun_counters),
    )


# ----------------------------------------------------------------------------------------------- faults
@dataclass
class FaultRun:
    """One run of a sample with a fault: the fused online poses and their covariances by stamp (ns)."""

    name: str
    poses: dict[int, Any]
    covariances: dict[int, Any]
    dropped: dict[str, int]
    exit_codes: dict[str, int]
    seconds: float


def run_fault(
    name: str,
    bag: Path,
    work: Path,
    domain_id: int,
    params: dict[str, dict[str, Any]],
    rate: float,
    hook_factory: Any = None,
) -> FaultRun:
    """The sample through the graph once; ``hook_factory(group, params_file, log_dir, env)`` gives the player's
    fault-injection hook (None: a clean run)."""
    import rclpy
    from nav_msgs.msg import Odometry
    from pvo_core.msgconv import covariance_to_matrix, pose_to_matrix
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from .launch import NodeGroup
    from .player import BagPlayer, PlayOptions
    from .testing import Spinner

    work.mkdir(parents=True, exist_ok=True)
    state = work / "fusion_state.json"
    state.unlink(missing_ok=True)
    params = {**params, "fusion": {**params.get("fusion", {}), "state_file": str(state.resolve())}}
    params_file = work / "params.yaml"
    params_file.write_text(yaml.safe_dump({n: {"ros__parameters": v} for n, v in params.items()}))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    log_dir = work / "logs"
    group = NodeGroup()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    poses: dict[int, Any] = {}
    covariances: dict[int, Any] = {}

    def on_fused(msg: Odometry) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        poses[stamp] = pose_to_matrix(msg.pose.pose)
        covariances[stamp] = covariance_to_matrix(msg.pose.covariance)

    start = time.perf_counter()
    try:
        _start_graph(group, params_file, log_dir, env)
        listener = Node("pvo_faults_listener", context=context)
        player_node = Node("pvo_faults_player", context=context)
        every = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        listener.create_subscription(Odometry, "/pvo/fusion/odometry", on_fused, every)
        hook = hook_factory(group, params_file, log_dir, env) if hook_factory else None
        player = BagPlayer(player_node, bag, PlayOptions(rate=rate, topics=INPUTS, hook=hook, wait_for_subscribers=0))
        with Spinner(context, listener):
            _wait_connected(player_node, group, listeners=1)
            stats = player.play()
            time.sleep(3.0)  # the last frames through the graph
        listener.destroy_node()
        player_node.destroy_node()
    finally:
        codes = group.stop()
        rclpy.shutdown(context=context)
    return FaultRun(name, poses, covariances, dict(stats.dropped), codes, time.perf_counter() - start)
