"""`pvo topic list|info|echo|hz`: topics on the live graph."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import PvoError


def register(sub: Any) -> None:
    topic = sub.add_parser("topic", help="inspect topics on the live graph")
    topic.set_defaults(handler=run)
    verbs = topic.add_subparsers(dest="verb", required=True, metavar="VERB")
    lst = verbs.add_parser("list", help="list topics")
    lst.add_argument("--show-types", "-t", action="store_true")
    lst.add_argument("--wait", type=float, default=2.5, help="discovery time (s)")
    info = verbs.add_parser("info", help="type and publisher/subscription counts")
    info.add_argument("topic")
    info.add_argument(
        "--wait", type=float, default=5.0, help="the longest wait for the topic to appear (s; it answers as soon as it does)"
    )
    echo = verbs.add_parser("echo", help="print messages as YAML")
    echo.add_argument("topic")
    echo.add_argument("--once", action="store_true", help="print one message and exit")
    echo.add_argument("--count", "-n", type=int, help="print N messages and exit")
    echo.add_argument("--timeout", type=float, help="give up after S seconds")
    echo.add_argument("--full", action="store_true", help="do not truncate long arrays")
    echo.add_argument("--wait", type=float, default=5.0, help="time to wait for the topic to appear")
    hz = verbs.add_parser("hz", help="print the publishing rate")
    hz.add_argument("topic")
    hz.add_argument("--window", "-w", type=int, default=100)
    hz.add_argument("--duration", type=float, help="stop after S seconds")
    hz.add_argument("--header", action="store_true", help="rate from header stamps instead of receive times")
    hz.add_argument("--wait", type=float, default=5.0)


def run(args: argparse.Namespace) -> int:
    from .. import graph

    node = graph.make_node("pvo_cli")
    try:
        if args.verb == "list":
            print("\n".join(graph.topic_list(node, args.show_types, args.wait)))
        elif args.verb == "info":
            print("\n".join(graph.topic_info(node, args.topic, args.wait)))
        elif args.verb == "echo":
            count = 1 if args.once else args.count
            received = graph.topic_echo(node, args.topic, count, args.wait, args.full, args.timeout)
            if count is not None and received < count:
                raise PvoError(f"received {received} of {count} messages on '{args.topic}' before the timeout")
        else:
            graph.topic_hz(node, args.topic, args.window, args.duration, args.wait, args.header)
    finally:
        graph.shutdown(node)
    return 0
