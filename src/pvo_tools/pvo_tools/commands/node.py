"""`pvo node list`: nodes on the live graph."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    node = sub.add_parser("node", help="inspect nodes on the live graph")
    node.set_defaults(handler=run)
    verbs = node.add_subparsers(dest="verb", required=True, metavar="VERB")
    nlist = verbs.add_parser("list", help="list nodes")
    nlist.add_argument("--wait", type=float, default=2.5, help="discovery time (s)")


def run(args: argparse.Namespace) -> int:
    from .. import graph

    node = graph.make_node("pvo_cli")
    try:
        print("\n".join(graph.node_list(node, args.wait)))
    finally:
        graph.shutdown(node)
    return 0
