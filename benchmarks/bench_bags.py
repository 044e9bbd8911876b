"""Benchmarks of the data path (figures printed, nothing asserted).

- conversion throughput of the real KITTI 06 clip (frames/s), MCAP+zstd and sqlite3;
- `bag play` sustained rate at --rate 10 with a subscriber receiving every stereo pair over DDS.

Run: source scripts/env.sh && python benchmarks/bench_bags.py
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path

import rclpy
from pvo_core.readers import KittiSequence
from pvo_tools.convert import convert_kitti
from pvo_tools.player import BagPlayer, PlayOptions
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

REPO = Path(__file__).resolve().parents[1]
TOPICS = ("/stereo/left/image_rect", "/stereo/right/image_rect")
DATA = Path(os.environ.get("PVO_DATA_DIR", REPO.parent / "shared" / "data"))


def bench_conversion(tmp: Path) -> None:
    root = DATA / "kitti/sequences/06"
    for storage in ("mcap", "sqlite3"):
        sequence = KittiSequence(root, rate_hz=10.0, poses_file=root / "poses_frames000-050.txt")
        summary = convert_kitti(sequence, tmp / f"conv_{storage}", storage=storage, show_progress=False)
        print(
            f"convert kitti 06 clip [{storage:7s}]: {summary.frames} frames in {summary.seconds:.2f} s = "
            f"{summary.frames / summary.seconds:.1f} frames/s, {summary.bytes / 1e6:.1f} MB"
        )


def bench_play(bag: Path, rate: float, repeats: int) -> None:
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = Context()
    rclpy.init(context=context, domain_id=97)
    listener = Node("bench_listener", context=context)
    player_node = Node("bench_player", context=context)
    received: list[float] = []
    qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
    listener.create_subscription(Image, "/stereo/right/image_rect", lambda _raw: received.append(time.monotonic()), qos, raw=True)
    listener.create_subscription(Image, "/stereo/left/image_rect", lambda _raw: None, qos, raw=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(listener)
    stop = threading.Event()
    thread = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.01) for _ in iter(stop.is_set, True)], daemon=True)
    thread.start()
    player = BagPlayer(player_node, bag, PlayOptions(rate=rate, wait_for_subscribers=1, clock=True, topics=list(TOPICS)))
    pairs = 0
    start = time.monotonic()
    for _ in range(repeats):
        stats = player.play()
        pairs += stats.per_topic.get("/stereo/left/image_rect", 0)
    elapsed = time.monotonic() - start
    deadline = time.monotonic() + 10
    while len(received) < pairs and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    thread.join()
    executor.shutdown()
    rclpy.shutdown(context=context)
    recorded_s = 5.196 * repeats
    print(
        f"bag play --rate {rate:g}: {pairs} stereo pairs (1226x370 mono8) in {elapsed:.2f} s = {pairs / elapsed:.1f} pairs/s "
        f"(target {10 * rate:.0f}/s, ideal {recorded_s / rate:.2f} s); subscriber received {len(received)}/{pairs}"
    )


def main() -> None:
    if not (DATA / "kitti").is_dir():
        raise SystemExit(f"real data not found at {DATA} (set PVO_DATA_DIR)")
    with tempfile.TemporaryDirectory() as tmp:
        bench_conversion(Path(tmp))
    bench_play(REPO / "bags" / "kitti06_sample", rate=10.0, repeats=3)
    bench_play(REPO / "bags" / "kitti06_sample", rate=50.0, repeats=3)


if __name__ == "__main__":
    main()
