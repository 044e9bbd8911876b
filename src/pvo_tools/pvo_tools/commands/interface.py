"""`pvo interface show TYPE`: a message definition."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    iface = sub.add_parser("interface", help="show message definitions")
    iface.set_defaults(handler=run)
    verbs = iface.add_subparsers(dest="verb", required=True, metavar="VERB")
    show = verbs.add_parser("show", help="print a .msg definition")
    show.add_argument("type", help="e.g. pvo_msgs/msg/RelativePose")


def run(args: argparse.Namespace) -> int:
    from .. import graph

    print(graph.interface_show(args.type))
    return 0
