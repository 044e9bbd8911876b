"""``main()`` of every pvo node: init, spin, a clean shutdown on SIGINT/SIGTERM, one error line for bad parameters."""

from __future__ import annotations

import faulthandler
import signal
import sys
from collections.abc import Callable
from typing import Any

EXIT_BAD_PARAMETER = 2


def run_node(factory: Callable[[], Any], name: str, args: list[str] | None = None) -> int:
    """Build the node with ``factory`` after ``rclpy.init(args)`` and spin it until shutdown.

    A ``ValueError`` while building (a wrong parameter, a missing file named by one) prints
    ``<name>: error: <reason>`` on stderr and exits with status 2. SIGINT and SIGTERM stop the spin
    (rclpy's signal handlers shut the context down); the node's ``close()`` runs, if it has one, before
    the node is destroyed. Returns 0 after a clean shutdown.
    """
    import rclpy
    from pvo_core.allocator import keep_large_blocks
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    keep_large_blocks()  # per-frame numpy temporaries reuse the heap instead of faulting in fresh pages
    # SIGUSR1 writes every thread's Python stack to stderr (the node's log): what a launcher sends a node that
    # did not stop on SIGINT, before it escalates, so that a hang leaves its place behind
    faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.ALL)
    try:
        node = factory()
    except ValueError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(EXIT_BAD_PARAMETER)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # a signal that shuts the context down between the executor's check and its next wait set makes rcl
        # raise "the given context is not valid": a shutdown, not a failure; anything while still running is
        if rclpy.ok():
            raise
    finally:
        close = getattr(node, "close", None)
        if callable(close):
            close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
