"""Long runs of the real node graph for benchmarks: the soak (``pvo bench soak``) — a bag looped through
stereo_vo, the pseudo-sensor nodes (by default the main job's: sun_bcnn, hydranet, dpc_net) and fusion as
processes, every node's memory and CPU time sampled, every frame and every sensor's output accounted for and the
end-to-end latency compared between the start and the end of the run — and the faults (``pvo bench faults``)."""

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
# the soak's sensor nodes (package pvo_pseudosensors): each reads the left images but simulated_sun, which reads the
# ground-truth sun; dpc_net also reads the right images and the VO
SOAK_SENSORS = ("simulated_sun", "sun_bcnn", "hydranet", "dpc_net")
SOAK_DEFAULT_SENSORS = ("sun_bcnn", "hydranet", "dpc_net")  # the main job's graph (`pvo demo` on the synthetic sample)
SENSOR_STATUS = {"sun_bcnn": "/pvo/sun_bcnn/status", "hydranet": "/pvo/hydranet/status", "dpc_net": "/pvo/dpc_net/status"}
SENSOR_COUNTERS = ("images", "published", "rejected")
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


def soak_nodes(sensors: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    """stereo_vo, the ``sensors`` (among `SOAK_SENSORS`) and fusion as (package, executable)."""
    unknown = [name for name in sensors if name not in SOAK_SENSORS]
    if unknown or not sensors:
        raise PvoError(
            f"--sensors {','.join(sensors)!r}: "
            + (f"unknown {', '.join(unknown)}; " if unknown else "none given; ")
            + f"choose among {', '.join(SOAK_SENSORS)}"
        )
    return (("pvo_frontend", "stereo_vo"), *(("pvo_pseudosensors", name) for name in sensors), ("pvo_fusion", "fusion"))


def soak_edges(sensors: tuple[str, ...], listeners: int) -> dict[str, tuple[int, int]]:
    """Every edge of the soak's graph as (publishers, subscribers) at least, ``listeners`` of the benchmark's own
    subscriptions on the left images, the VO and the fused odometry included."""
    image_readers = 1 + sum(name in sensors for name in ("sun_bcnn", "hydranet", "dpc_net"))
    edges = {
        "/stereo/left/image_rect": (0, image_readers + listeners),
        "/pvo/vo/relative": (1, 1 + ("dpc_net" in sensors) + listeners),
        "/pvo/sun/direction": (sum(name in sensors for name in ("simulated_sun", "sun_bcnn")), 1),
        "/pvo/fusion/odometry": (1, 1),
    }
    if "hydranet" in sensors:
        edges["/pvo/hydranet/rotation"] = (1, 1)
    if "dpc_net" in sensors:
        edges["/pvo/dpc/correction"] = (1, 1)
        edges["/stereo/right/image_rect"] = (0, 2)
    if "simulated_sun" in sensors:
        edges["/ground_truth/sun_direction"] = (0, 1)
    return edges


def _wait_connected(player_node: Any, group: Any, listeners: int, edges: dict[str, tuple[int, int]] | None = None) -> None:
    """Until every edge of the graph is connected (``edges``; default: the images and the VO each have
    ``listeners`` subscribers, the nodes plus the benchmark's own listeners, and the fused odometry one), then
    the settle time."""
    from .launch import wait_for_graph

    if edges is None:
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


def parse_cpu_seconds(stat: str, ticks_per_second: float) -> float:
    """User plus system CPU time (s) of a process from its ``/proc/<pid>/stat`` line (fields 14 and 15, counted
    after the command name, which may itself hold spaces and parentheses)."""
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / ticks_per_second


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time (s) a process has used so far (its threads included); NaN when it is gone."""
    try:
        return parse_cpu_seconds(Path(f"/proc/{pid}/stat").read_text(), float(os.sysconf("SC_CLK_TCK")))
    except (OSError, ValueError, IndexError):
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
    sensors: dict[str, dict[str, int]] = field(default_factory=dict)  # sensor node -> its last status's counters
    cpu: dict[str, list[tuple[float, float]]] = field(default_factory=dict)  # node -> (s, CPU seconds used so far)
    fusion: dict[str, str] = field(default_factory=dict)  # the fusion's last status: factors.* and count.* values


def run_soak(
    bag: Path,
    frames: int,
    rate: float,
    work: Path,
    domain_id: int,
    parameters: dict[str, dict[str, Any]],
    sensors: tuple[str, ...] = SOAK_DEFAULT_SENSORS,
) -> SoakResult:
    """Loop ``bag`` until ``frames`` stereo frames were played at ``rate`` x real time through stereo_vo, the
    ``sensors`` and fusion; ``parameters``: node name -> its parameters (dotted names)."""
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

    nodes = soak_nodes(sensors)
    per_pass = dict((t, n) for t, _, n, _ in bag_info(bag).topics).get("/stereo/left/image_rect", 0)
    if per_pass < 2:
        raise PvoError(f"{bag}: no stereo images to loop")
    passes = max(1, math.ceil(frames / per_pass))
    work.mkdir(parents=True, exist_ok=True)
    params = work / "params.yaml"
    params.write_text(
        yaml.safe_dump({name: {"ros__parameters": dict(parameters.get(name, {}))} for _, name in nodes}, sort_keys=False)
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

    sensor_counters: dict[str, dict[str, int]] = {}
    fusion_status: dict[str, str] = {}

    def status_reader(name: str) -> Any:
        def on_status(msg: DiagnosticArray) -> None:
            for status in msg.status:
                sensor_counters.setdefault(name, {}).update(
                    {kv.key: int(kv.value) for kv in status.values if kv.key in SENSOR_COUNTERS}
                )

        return on_status

    def on_fusion_status(msg: DiagnosticArray) -> None:
        for status in msg.status:
            fusion_status.update({kv.key: kv.value for kv in status.values if kv.key.startswith(("factors.", "count."))})

    def on_fused(msg: Odometry) -> None:
        counts["fused"] += 1
        seen = image_seen.pop(stamp(msg), None)
        for old in [s for s in image_seen if s < stamp(msg)]:
            del image_seen[old]  # bounded: frames without an odometry are not kept
        if seen is not None:
            latencies.append((counts["fused"], 1e3 * (time.perf_counter() - seen)))

    rss: dict[str, list[tuple[float, float]]] = {name: [] for _, name in nodes}
    cpu: dict[str, list[tuple[float, float]]] = {name: [] for _, name in nodes}
    start = time.perf_counter()
    try:
        _start_graph(group, params, work / "logs", env, nodes)
        listener = Node("pvo_soak_listener", context=context)
        player_node = Node("pvo_soak_player", context=context)
        listener.create_subscription(Image, "/stereo/left/image_rect", on_image, every)
        listener.create_subscription(RelativePose, "/pvo/vo/relative", on_vo, every)
        listener.create_subscription(Odometry, "/pvo/fusion/odometry", on_fused, every)
        listener.create_subscription(DiagnosticArray, "/pvo/fusion/status", on_fusion_status, every)
        for name in sensors:
            if name in SENSOR_STATUS:
                listener.create_subscription(DiagnosticArray, SENSOR_STATUS[name], status_reader(name), every)
        player = BagPlayer(player_node, bag, PlayOptions(rate=rate, loop=True, passes=passes, topics=INPUTS))
        with Spinner(context, listener):
            _wait_connected(player_node, group, 1, soak_edges(sensors, listeners=1))
            import threading

            stop = threading.Event()

            def sample() -> None:
                while not stop.is_set():
                    for node in group.nodes:
                        now = time.perf_counter() - start
                        rss[node.name].append((now, rss_mb(node.process.pid)))
                        cpu[node.name].append((now, cpu_seconds(node.process.pid)))
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
            time.sleep(1.0)  # the sensors' last status messages
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
        {name: dict(values) for name, values in sensor_counters.items()},
        cpu,
        dict(fusion_status),
    )


def cpu_share(samples: list[tuple[float, float]], after_s: float) -> float:
    """The share of one core (1.0 = one core busy all the time) a process used between its first sample at or
    after ``after_s`` and its last; NaN with fewer than two samples there."""
    kept = [(t, c) for t, c in samples if t >= after_s and not math.isnan(c)]
    if len(kept) < 2 or kept[-1][0] <= kept[0][0]:
        return math.nan
    return (kept[-1][1] - kept[0][1]) / (kept[-1][0] - kept[0][0])


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
    sensors: tuple[str, ...] = ("simulated_sun",),
) -> FaultRun:
    """The sample through stereo_vo, the ``sensors`` (among `SOAK_SENSORS`) and fusion once; ``hook_factory(group,
    params_file, log_dir, env)`` gives the player's fault-injection hook (None: a clean run)."""
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
        _start_graph(group, params_file, log_dir, env, soak_nodes(sensors))
        listener = Node("pvo_faults_listener", context=context)
        player_node = Node("pvo_faults_player", context=context)
        every = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        listener.create_subscription(Odometry, "/pvo/fusion/odometry", on_fused, every)
        hook = hook_factory(group, params_file, log_dir, env) if hook_factory else None
        player = BagPlayer(player_node, bag, PlayOptions(rate=rate, topics=INPUTS, hook=hook, wait_for_subscribers=0))
        with Spinner(context, listener):
            _wait_connected(player_node, group, 0, soak_edges(sensors, listeners=0))
            stats = player.play()
            time.sleep(3.0)  # the last frames through the graph
        listener.destroy_node()
        player_node.destroy_node()
    finally:
        codes = group.stop()
        rclpy.shutdown(context=context)
    return FaultRun(name, poses, covariances, dict(stats.dropped), codes, time.perf_counter() - start)
