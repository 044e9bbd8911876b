"""`pvo experiment list | <name> ...`: the thesis experiments (one module each in :mod:`pvo_tools.experiments`)."""

from __future__ import annotations

import argparse
from typing import Any

from ..experiments import EXPERIMENTS, load


def register(sub: Any) -> None:
    exp = sub.add_parser("experiment", help="thesis experiments on real data (`pvo experiment list`)")
    kinds = exp.add_subparsers(dest="experiment", required=True, metavar="WHICH")
    listing = kinds.add_parser("list", help="list the experiments")
    listing.set_defaults(handler=list_experiments)
    for name in EXPERIMENTS:
        module = load(name)
        parser = kinds.add_parser(name, help=module.TITLE)
        module.register(parser)
        parser.set_defaults(handler=module.run)


def list_experiments(args: argparse.Namespace) -> int:
    width = max(len(name) for name in EXPERIMENTS)
    for name in EXPERIMENTS:
        print(f"{name:<{width}}  {load(name).TITLE}")
    return 0
