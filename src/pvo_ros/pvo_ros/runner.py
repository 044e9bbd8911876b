"""``main()`` of every pvo node: init, spin, a clean shutdown on SIGINT/SIGTERM, one error line for bad parameters."""

from __future__ import annotations

import faulthandler
import re
import signal
import sys
from collections.abc import Callable
from types import FrameType
from typing import Any

EXIT_BAD_PARAMETER = 2
SPIN_PERIOD_S = 0.1
"""Longest wait of one executor turn: how soon a stop request is seen while no message arrives."""
SHUTDOWN_LIMIT_S = 20.0
"""A node asked to stop that has not exited after this long writes every thread's stack and exits with status 1."""

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequest:
    """SIGINT/SIGTERM set a flag that the spin loop checks between executor turns.

    rclpy's own handlers shut the context down from a separate thread; when that lands while the executor
    builds its wait set, the wake-up can be lost and the node waits forever with no timeout (seen about once
    in 150 SIGTERMs under load). Here the signal only asks; the loop ends after the callback in progress,
    and ``close()`` still runs with a valid context. A second signal restores the default action, so a node
    stuck in its cleanup still dies on the next Ctrl-C or kill.
    """

    def __init__(self) -> None:
        self.signal: int | None = None
        for number in _STOP_SIGNALS:
            signal.signal(number, self._request)

    def _request(self, number: int, frame: FrameType | None) -> None:
        self.signal = number
        for other in _STOP_SIGNALS:
            signal.signal(other, signal.default_int_handler if other == signal.SIGINT else signal.SIG_DFL)

    @property
    def requested(self) -> bool:
        return self.signal is not None


def run_node(factory: Callable[[], Any], name: str, args: list[str] | None = None) -> int:
    """Build the node with ``factory`` after ``rclpy.init(args)`` and spin it until asked to stop.

    A ``ValueError`` while building (a wrong parameter, a missing file named by one) prints
    ``<name>: error: <reason>`` on stderr and exits with status 2. SIGINT and SIGTERM end the spin after the
    callback in progress (:class:`StopRequest`); the node's ``close()`` runs, if it has one, before the node
    is destroyed and the context shut down. Returns 0 after a clean shutdown; a shutdown that hangs for
    :data:`SHUTDOWN_LIMIT_S` leaves every thread's stack on stderr and exits with status 1.
    """
    import rclpy
    from pvo_core.allocator import keep_large_blocks
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    keep_large_blocks()  # per-frame numpy temporaries reuse the heap instead of faulting in fresh pages
    # SIGUSR1 writes every thread's Python stack to stderr (the node's log): what a launcher sends a node that
    # did not stop on SIGINT, before it escalates, so that a hang leaves its place behind
    faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)
    stop = StopRequest()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's RCLError: --ros-args it cannot parse (a malformed -p rule, a bad file)
        print(f"{name}: error: {_rcl_reason(exc)}", file=sys.stderr)
        sys.exit(EXIT_BAD_PARAMETER)
    try:
        node = factory()
    except ValueError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(EXIT_BAD_PARAMETER)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop.requested and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # a context shut down from elsewhere (rclpy.shutdown in-process) makes rcl raise "the given context is
        # not valid" while building the wait set: a shutdown, not a failure; anything while still running is
        if rclpy.ok():
            raise
    finally:
        faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
        close = getattr(node, "close", None)
        if callable(close):
            close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()
    return 0


def _rcl_reason(error: BaseException) -> str:
    """rcl's message without the C source locations it appends (", at /project/src/parse.c:435")."""
    return re.sub(r",? at /\S+:\d+", "", str(error).splitlines()[0] if str(error) else type(error).__name__).strip()
