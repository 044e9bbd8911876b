"""What every experiment command starts with: its output folder, the command line it records, progress lines."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class ExperimentRun:
    """The output folder (created), the command line as given, whether to print progress, the start time."""

    out: Path
    command: str
    quiet: bool = False
    started: float = field(default_factory=time.perf_counter)

    @classmethod
    def start(cls, args: argparse.Namespace) -> ExperimentRun:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        return cls(out, "pvo " + shlex.join(getattr(args, "argv", sys.argv[1:])), bool(getattr(args, "quiet", False)))

    def say(self, line: str) -> None:
        """A progress line on stderr (unless quiet)."""
        if not self.quiet:
            print(line, file=sys.stderr, flush=True)

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.started
