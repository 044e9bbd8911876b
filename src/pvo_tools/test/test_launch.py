"""Stopping node processes as ros2 launch does: SIGINT, then SIGTERM (after a stack dump), then SIGKILL."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from pvo_tools.launch import NodeGroup, NodeProcess

# each process says it is ready once its handlers are in place, then idles
# (SIGINT's handler set explicitly: a process started in the background of a shell inherits SIGINT ignored)
OBEYS_SIGINT = (
    "import signal, time; signal.signal(signal.SIGINT, signal.default_int_handler); print('ready', flush=True)\n"
    "while True: time.sleep(0.05)"
)
IGNORES_SIGINT = (
    "import signal, sys, time; signal.signal(signal.SIGINT, signal.SIG_IGN); signal.signal(signal.SIGUSR1, signal.SIG_IGN)\n"
    "signal.signal(signal.SIGTERM, lambda *_: sys.exit(0)); print('ready', flush=True)\nwhile True: time.sleep(0.05)"
)
IGNORES_BOTH = (
    "import signal, time\nfor s in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1): signal.signal(s, signal.SIG_IGN)\n"
    "print('ready', flush=True)\nwhile True: time.sleep(0.05)"
)


def start(group: NodeGroup, name: str, code: str, tmp_path: Path) -> None:
    log = tmp_path / f"{name}.log"
    with log.open("w") as out:
        process = subprocess.Popen([sys.executable, "-c", code], stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    group.nodes.append(NodeProcess(name, process, log))
    deadline = time.monotonic() + 20
    while "ready" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)


def test_a_node_deaf_to_sigint_gets_sigterm_and_one_deaf_to_both_is_killed(tmp_path: Path) -> None:
    group = NodeGroup()
    for name, code in (("polite", OBEYS_SIGINT), ("stubborn", IGNORES_SIGINT), ("hung", IGNORES_BOTH)):
        start(group, name, code, tmp_path)
    codes = group.stop(timeout_s=4.0, sigterm_after_s=1.0)
    assert codes["polite"] != 0 and "polite" not in group.escalated  # KeyboardInterrupt: stopped by SIGINT itself
    assert codes["stubborn"] == 0 and group.escalated == ["stubborn", "hung"]
    assert group.killed == ["hung"] and codes["hung"] == -9
    assert all(node.process.poll() is not None for node in group.nodes)


def test_a_pvo_node_writes_its_stacks_on_sigusr1_and_still_stops_cleanly(tmp_path: Path, ros_env) -> None:
    """run_node registers the stack dump a launcher asks for before escalating; the node keeps running after it."""
    code = (
        "import rclpy.node\nfrom pvo_ros.runner import run_node\n"
        "class Idle(rclpy.node.Node):\n"
        "    def __init__(self):\n        super().__init__('idle')\n        print('ready', flush=True)\n"
        "run_node(Idle, 'idle')"
    )
    log = tmp_path / "idle.log"
    with log.open("w") as out:
        process = subprocess.Popen([sys.executable, "-c", code], stdout=out, stderr=subprocess.STDOUT, env=ros_env)
    deadline = time.monotonic() + 60
    while "ready" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # into the spin
    process.send_signal(subprocess.signal.SIGUSR1)
    while "most recent call first" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert process.poll() is None  # a stack dump, not an exit
    process.send_signal(subprocess.signal.SIGINT)
    assert process.wait(timeout=30) == 0
    text = log.read_text()
    assert "most recent call first" in text and "spin" in text  # where the node was: in its spin


def test_a_shutdown_racing_the_executors_next_wait_is_a_clean_exit(tmp_path: Path, ros_env) -> None:
    """SIGINT shutting the context down after the executor checked it and before its next wait set: rcl raises
    "the given context is not valid" (seen once in CI as a fusion node's exit 1); run_node exits 0 on it. The race is
    made certain by shutting the context down inside the wait set's construction."""
    code = (
        "import rclpy, rclpy.node, rclpy.executors as ex\nfrom pvo_ros.runner import run_node\n"
        "original = ex._rclpy.WaitSet\ncalls = []\n"
        "def racing(*args, **kwargs):\n"
        "    calls.append(1)\n"
        "    if len(calls) == 3:\n        rclpy.try_shutdown()\n"
        "    return original(*args, **kwargs)\n"
        "ex._rclpy.WaitSet = racing\n"
        "class Idle(rclpy.node.Node):\n"
        "    def __init__(self):\n        super().__init__('idle')\n        self.create_timer(0.01, lambda: None)\n"
        "run_node(Idle, 'idle')\nprint('returned', len(calls), flush=True)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ros_env, timeout=60)
    assert done.returncode == 0, done.stderr[-1500:]
    assert "returned 3" in done.stdout
