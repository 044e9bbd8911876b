"""`pvo run PACKAGE EXECUTABLE [args]`: like `ros2 run`, from the install's lib/<package>/."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    run_parser = sub.add_parser("run", help="run an executable of a package (like `ros2 run`)")
    run_parser.add_argument("package")
    run_parser.add_argument("executable")
    run_parser.add_argument("args", nargs=argparse.REMAINDER, help="arguments for the executable (e.g. --ros-args ...)")
    run_parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from .. import graph

    graph.run(args.package, args.executable, args.args)
    return 0
