"""pvo_ros: parameters declared from config dataclasses, refused or applied at run time, and the runner."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass

import pytest

pytestmark = pytest.mark.ros


@dataclass(frozen=True)
class Inner:
    gain: float = 1.5
    names: tuple[str, ...] = ("a", "b")


@dataclass(frozen=True)
class Algorithm:
    inner: Inner = Inner()
    iterations: int = 3

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {self.iterations}")


@dataclass(frozen=True)
class NodeSettings:
    frame: str = "odom"
    publish: bool = True


def _node(context, overrides=None, runtime=None):
    from rclpy.node import Node

    from pvo_ros import ConfigParameters, ParameterPolicy

    node = Node("toy", context=context, parameter_overrides=overrides or [])
    algorithm = ConfigParameters(node, Algorithm(), "toy")
    settings = ConfigParameters(node, NodeSettings(), "toy")
    ParameterPolicy(node, [algorithm, settings], runtime=runtime)
    return node, algorithm, settings


def test_every_leaf_becomes_a_typed_dotted_parameter(ros_context) -> None:
    from rclpy.parameter import Parameter

    from pvo_ros import config_fields, declared_parameter_names

    node, algorithm, settings = _node(ros_context, [Parameter("inner.gain", value=2.5), Parameter("frame", value="map")])
    assert (
        declared_parameter_names(node)
        == config_fields(Algorithm, NodeSettings)
        == {
            "inner.gain",
            "inner.names",
            "iterations",
            "frame",
            "publish",
        }
    )
    assert algorithm.value == Algorithm(Inner(2.5, ("a", "b")), 3)
    assert settings.value.frame == "map"
    node.destroy_node()


def test_a_wrong_start_up_value_names_the_parameter(ros_context) -> None:
    from rclpy.parameter import Parameter

    with pytest.raises(ValueError, match="iterations must be >= 1, got 0"):
        _node(ros_context, [Parameter("iterations", value=0)])


def test_runtime_changes_are_refused_with_a_reason_or_applied_when_declared_safe(ros_context) -> None:
    from rclpy.parameter import Parameter

    applied: list[NodeSettings] = []
    node, algorithm, settings = _node(ros_context, runtime={"publish": applied.append})
    refused = node.set_parameters([Parameter("iterations", value=5)])[0]
    assert not refused.successful
    assert refused.reason == "toy: iterations is read at start-up; restart the node to change it"
    assert algorithm.value.iterations == 3
    ok = node.set_parameters([Parameter("publish", value=False)])[0]
    assert ok.successful
    assert settings.value.publish is False and applied == [settings.value]
    node.destroy_node()


def test_runner_prints_one_error_line_and_exits_2_for_a_bad_parameter(ros_env) -> None:
    code = (
        "from pvo_ros import run_node\n"
        "def make():\n"
        "    raise ValueError('gain must be positive, got -1')\n"
        "run_node(make, 'toy')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == "toy: error: gain must be positive, got -1"


def test_runner_shuts_down_cleanly_on_sigterm(ros_env) -> None:
    import signal
    import time

    code = (
        "from pvo_ros import run_node\n"
        "from rclpy.node import Node\n"
        "class Toy(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('toy')\n"
        "        print('ready', flush=True)\n"
        "    def close(self):\n"
        "        print('closed', flush=True)\n"
        "run_node(Toy, 'toy')\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert out.strip() == "closed"


def test_a_signal_only_asks_the_callback_in_progress_finishes_and_close_still_publishes(ros_env) -> None:
    """SIGTERM inside a callback: the callback completes (its publish after the signal succeeds), the spin ends
    after it, and close() publishes on a context that is still valid; rclpy's own handler would have shut the
    context down from another thread, failing both publishes (and, racing the executor's wait set, sometimes
    leaving the node waiting forever)."""
    code = (
        "import os, signal, time\n"
        "from pvo_ros import run_node\n"
        "from rclpy.node import Node\n"
        "from std_msgs.msg import String\n"
        "class Toy(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('toy')\n"
        "        self.said = self.create_publisher(String, 'said', 10)\n"
        "        self.create_timer(0.05, self.tick)\n"
        "        self.ticks = 0\n"
        "    def tick(self):\n"
        "        self.ticks += 1\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        time.sleep(0.3)\n"
        "        self.said.publish(String(data='after the signal'))\n"
        "        print('published', flush=True)\n"
        "    def close(self):\n"
        "        self.said.publish(String(data='closing'))\n"
        "        print('closed after', self.ticks, 'tick(s)', flush=True)\n"
        "run_node(Toy, 'toy')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-1500:]
    assert done.stdout.split("\n")[:2] == ["published", "closed after 1 tick(s)"], done.stdout + done.stderr[-1500:]


def test_no_exception_escapes_a_callback_and_it_is_counted_and_reported(ros_context) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from pvo_tools.testing import Spinner, wait_for
    from rclpy.node import Node
    from std_msgs.msg import Header

    from pvo_ros import PvoNode, reliable

    received: list[int] = []

    class Toy(PvoNode[Algorithm, None]):
        def __init__(self) -> None:
            super().__init__("toy", Algorithm(), context=ros_context)
            self.create_subscription(Header, "/toy/in", self._on, reliable(10))

        def _on(self, msg: Header) -> None:
            if msg.frame_id == "bad":
                raise RuntimeError("boom")
            received.append(msg.stamp.sec)

    toy = Toy()
    io = Node("io", context=ros_context)
    statuses: list[DiagnosticArray] = []
    io.create_subscription(DiagnosticArray, "/pvo/toy/status", statuses.append, reliable(10))
    pub = io.create_publisher(Header, "/toy/in", reliable(10))
    try:
        with Spinner(ros_context, toy, io):
            assert wait_for(lambda: pub.get_subscription_count() > 0 and toy.pub_status.get_subscription_count() > 0, 10)
            for sec, frame in ((1, "ok"), (2, "bad"), (3, "ok"), (4, "bad"), (5, "ok")):
                msg = Header(frame_id=frame)
                msg.stamp.sec = sec
                pub.publish(msg)
            assert wait_for(lambda: len(received) == 3 and len(statuses) == 2, 10)
    finally:
        toy.destroy_node()
        io.destroy_node()
    assert received == [1, 3, 5]
    assert toy.callback_errors["/toy/in"] == 2
    assert statuses[-1].status[0].message == "/toy/in: unexpected error: RuntimeError: boom"
    assert {kv.key: kv.value for kv in statuses[-1].status[0].values} == {"callback_errors./toy/in": "2"}


def test_problem_log_logs_each_new_reason_and_a_repeated_one_once() -> None:
    from pvo_ros import ProblemLog

    lines: list[str] = []

    class Logger:
        def warning(self, text: str) -> None:
            lines.append(text)

    log = ProblemLog(Logger(), repeat_every=3)
    for k in range(4):
        log(f"frame at {k}.5 s rejected: image size 10x10 differs")
    log("frame at 9.0 s rejected: stamp goes backwards: 9.0 s after 10.0 s")
    assert lines == [
        "frame at 0.5 s rejected: image size 10x10 differs",
        "frame at 3.5 s rejected: image size 10x10 differs (seen 3 times before)",
        "frame at 9.0 s rejected: stamp goes backwards: 9.0 s after 10.0 s",
    ]
