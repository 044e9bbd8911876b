"""The `pvo` command: one entry point for pvo's tools (`pvo --help`). It only parses, calls and prints:
each command lives in its own module under :mod:`pvo_tools.commands`."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading

from pvo_core.allocator import keep_large_blocks
from pvo_core.errors import DataFormatError

from .commands import COMMANDS
from .errors import PvoError

EPILOG = "Run 'pvo COMMAND --help' for the options of each command."


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pvo", description="pvo: pseudo-sensor visual odometry tools.", epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"pvo_tools.commands.{name}").register(sub)
    return parser


_TERMINATED = []


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM (kill, timeout) cleans up like Ctrl-C: context managers remove partial outputs."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once is enough
    _TERMINATED.append(signum)
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:2] in (["sim", "corpus"], ["sim", "mirror"], ["vo", "calibrate"]):  # `pvo sim OUT`, `pvo vo SEQUENCE`
        argv = [f"{argv[0]}-{argv[1]}", *argv[2:]]  # take a folder; these are commands
    args = build_parser().parse_args(argv)
    args.argv = argv  # the command line as given (model cards record how their weights were made)
    keep_large_blocks()  # per-frame numpy temporaries reuse the heap instead of faulting in fresh pages
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminate)
    try:
        return int(args.handler(args) or 0)
    except (PvoError, DataFormatError, ValueError) as error:
        print(f"pvo: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pvo: interrupted", file=sys.stderr)
        if _TERMINATED:
            # Everything is cleaned up; leave at once: an interrupt landing in the interpreter's own shutdown
            # would otherwise turn the exit status into a SIGINT death.
            sys.stderr.flush()
            sys.stdout.flush()
            os._exit(130)
        return 130


if __name__ == "__main__":
    sys.exit(main())
