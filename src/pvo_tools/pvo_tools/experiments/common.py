"""What every experiment command starts with: its output folder, the command line it records, progress lines."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


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


def fusion_figures(truth: Any, estimate: Any) -> dict[str, float]:
    """m-ATE (translation m, rotation deg; eqs. 6.31-6.32) and the thesis's mean segment errors (%, deg/m) of
    camera-to-world poses ``estimate`` (N, 4, 4) against ``truth``."""
    import numpy as np

    from pvo_core import metrics

    trajectory = metrics.mean_trajectory_errors(truth, estimate)
    segments = metrics.thesis_segment_errors(truth, estimate)
    return {
        "m_ate_trans": trajectory.mean_translation,
        "m_ate_rot_deg": float(np.degrees(trajectory.rotation.mean())),
        "seg_trans_percent": segments.translation_percent,
        "seg_rot_deg_per_m": segments.rotation_deg_per_m,
    }


def rendered_by_this_revision(folder: Path) -> bool:
    """Whether ``folder`` holds a complete `pvo sim` sequence of this renderer's revision (an experiment renders
    an older one anew: the same configuration renders different images)."""
    import yaml
    from pvo_sim.render import RENDERER_REVISION

    meta = folder / "sim.yaml"
    return meta.is_file() and (yaml.safe_load(meta.read_text()) or {}).get("renderer_revision") == RENDERER_REVISION
