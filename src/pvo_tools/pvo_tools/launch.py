"""Running nodes of the graph as processes (what a launch file would do): start from the install's
``lib/<package>/<executable>`` with a parameter file, watch them, wait for the graph's connections, stop them
with SIGINT and collect their exit status and log."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import PvoError
from .graph import find_executable

#: How long a node may take to stop after SIGINT before it is killed: generous, since five nodes finishing their
#: queues on two loaded cores took over 15 s once, and a kill is for a node that hangs.
STOP_TIMEOUT_S = 30.0


@dataclass
class NodeProcess:
    name: str
    process: subprocess.Popen
    log: Path
    expected_dead: bool = False

    def tail(self, lines: int = 5) -> str:
        try:
            text = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return " | ".join(text[-lines:])


@dataclass
class NodeGroup:
    """Node processes started together; ``check()`` raises if one has died, ``stop()`` ends them all."""

    nodes: list[NodeProcess] = field(default_factory=list)
    packages: dict[str, str] = field(default_factory=dict)
    killed: list[str] = field(default_factory=list)  # nodes the last stop() had to kill
    escalated: list[str] = field(default_factory=list)  # nodes the last stop() sent SIGTERM (SIGINT not obeyed)

    def start(
        self, package: str, executable: str, params_file: Path | None, log_dir: Path, env: Mapping[str, str], suffix: str = ""
    ) -> None:
        self.packages[executable] = package
        path = find_executable(package, executable)
        args = [str(path), "--ros-args"]
        if params_file is not None:
            args += ["--params-file", str(params_file)]
        log_dir.mkdir(parents=True, exist_ok=True)
        log = log_dir / f"{executable}{suffix}.log"
        with log.open("w") as out:
            process = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, env=dict(env), start_new_session=True)
        self.nodes.append(NodeProcess(executable, process, log))

    def restart(self, name: str, params_file: Path | None, log_dir: Path, env: Mapping[str, str], kill: bool = True) -> None:
        """Kill a node (SIGKILL: a crash, not a shutdown) and start it again with the same parameters."""
        for index, node in enumerate(self.nodes):
            if node.name == name:
                if node.process.poll() is None:
                    node.process.send_signal(signal.SIGKILL if kill else signal.SIGINT)
                    node.process.wait(timeout=15)
                package = self.packages[name]
                del self.nodes[index]
                self.start(package, name, params_file, log_dir, env, suffix=f".{int(time.monotonic() * 1000)}")
                return
        raise PvoError(f"no node {name} to restart")

    def kill(self, name: str) -> None:
        """SIGKILL a node (a crash); it stays dead until :meth:`restart`."""
        for node in self.nodes:
            if node.name == name and node.process.poll() is None:
                node.process.send_signal(signal.SIGKILL)
                node.process.wait(timeout=15)
                node.expected_dead = True

    def check(self) -> None:
        for node in self.nodes:
            code = node.process.poll()
            if code is not None and not node.expected_dead:
                raise PvoError(f"node {node.name} died (exit status {code}): {node.tail() or 'no output'} (log {node.log})")

    def stop(self, timeout_s: float = STOP_TIMEOUT_S, sigterm_after_s: float | None = None) -> dict[str, int]:
        """SIGINT to every node still running, then wait; as ros2 launch does, a node still running after
        ``sigterm_after_s`` (default half of ``timeout_s``) gets SIGUSR1 (pvo nodes write their threads' stacks
        to their log) and SIGTERM (named in ``escalated``), and SIGKILL after ``timeout_s`` (named in ``killed``).
        Exit status per node."""
        self.killed, self.escalated = [], []
        for node in self.nodes:
            if node.process.poll() is None:
                node.process.send_signal(signal.SIGINT)
        start = time.monotonic()
        term_at = start + (timeout_s / 2 if sigterm_after_s is None else min(sigterm_after_s, timeout_s))
        deadline = start + timeout_s
        codes: dict[str, int] = {}
        for node in self.nodes:
            try:
                codes[node.name] = node.process.wait(timeout=max(term_at - time.monotonic(), 0.1))
                continue
            except subprocess.TimeoutExpired:
                pass
            self.escalated.append(node.name)
            node.process.send_signal(signal.SIGUSR1)
            time.sleep(0.2)  # the stacks written before the handlers start shutting down
            node.process.send_signal(signal.SIGTERM)
            try:
                codes[node.name] = node.process.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                os.killpg(node.process.pid, signal.SIGKILL)
                self.killed.append(node.name)
                codes[node.name] = node.process.wait()
        return codes


def wait_for_graph(
    node: Any,
    expected: Mapping[str, tuple[int, int]],
    timeout_s: float,
    check: Callable[[], None] = lambda: None,
) -> None:
    """Wait until every topic has at least (publishers, subscribers) as seen from ``node``'s graph view;
    ``PvoError`` naming the topics still short after ``timeout_s``. ``check`` runs on each poll (e.g. that no
    node process has died)."""
    deadline = time.monotonic() + timeout_s
    while True:
        check()
        short = [
            f"{topic} ({node.count_publishers(topic)}/{pubs} publishers, {node.count_subscribers(topic)}/{subs} subscribers)"
            for topic, (pubs, subs) in expected.items()
            if node.count_publishers(topic) < pubs or node.count_subscribers(topic) < subs
        ]
        if not short:
            return
        if time.monotonic() > deadline:
            raise PvoError(f"the graph did not connect in {timeout_s:g} s: {'; '.join(short)}")
        time.sleep(0.1)


def wait_until(
    condition: Callable[[], bool],
    timeout_s: float,
    check: Callable[[], None] = lambda: None,
    stalled: Callable[[], object] | None = None,
    stall_s: float = 5.0,
) -> bool:
    """Poll ``condition`` every 50 ms until true (True), or ``timeout_s`` passes, or — with ``stalled`` — its
    value (e.g. message counts) has not changed for ``stall_s`` (False)."""
    deadline = time.monotonic() + timeout_s
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        check()
        if condition():
            return True
        if stalled is not None:
            now = stalled()
            if now != last:
                last, since = now, time.monotonic()
            elif time.monotonic() - since > stall_s:
                return condition()
        time.sleep(0.05)
    return condition()
