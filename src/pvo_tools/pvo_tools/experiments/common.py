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
    """Whether ``folder`` holds a complete `pvo sim` sequence this renderer would draw the same (an experiment
    renders one of an older revision anew: the same configuration renders different images)."""
    from pvo_sim.render import rendered_by_this_renderer

    return rendered_by_this_renderer(folder)


def recorded_seed(folder: Path) -> int | None:
    """The world seed a `pvo sim` sequence's sim.yaml records (None where it records none)."""
    import yaml

    seed = ((yaml.safe_load((folder / "sim.yaml").read_text()) or {}).get("config") or {}).get("seed")
    return seed if isinstance(seed, int) else None


def another_world(folder: Path, seed: int, option: str) -> ValueError | None:
    """The one-line error for a folder of this renderer that holds a drive through another world than ``seed``'s
    (``option``: the one that names a folder of its own), or None."""
    recorded = recorded_seed(folder)
    if recorded is None or recorded == seed:
        return None
    return ValueError(
        f"{folder}: rendered through another world (seed {recorded}, not {seed}): give {option} a folder of its own"
    )


TRAJECTORY_METRICS = ("m_ate_trans", "m_ate_rot_deg", "seg_trans_percent", "seg_rot_deg_per_m")


def trajectory_tables(
    results: dict[str, dict[str, dict[str, float]]],
    baseline: str,
    labels: list[str],
    figures: dict[str, float],
    figure_name: Any,
) -> list[str]:
    """Markdown: per sequence and estimate the :func:`fusion_figures`, then each of ``labels``' mean relative
    change against ``baseline`` (negative = better), also stored in ``figures`` under
    ``figure_name(label)`` + ``.<metric>_change``."""
    from pvo_core.metrics import mean_relative_change

    lines = [
        "| sequence | estimate | m-ATE trans (m) | m-ATE rot (deg) | seg trans (%) | seg rot (deg/m) |",
        "|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        for label, m in rows.items():
            lines.append(
                f"| {name} | {label} | {m['m_ate_trans']:.3f} | {m['m_ate_rot_deg']:.3f} | {m['seg_trans_percent']:.3f} | "
                f"{m['seg_rot_deg_per_m']:.5f} |"
            )
    names = list(results)
    lines += ["", f"Mean relative change against the {baseline} (negative = better):", ""]
    lines += ["| estimate | m-ATE trans | m-ATE rot | seg trans | seg rot |", "|---|---|---|---|---|"]
    for label in labels:
        changes = {
            key: mean_relative_change([results[n][label][key] for n in names], [results[n][baseline][key] for n in names])
            for key in TRAJECTORY_METRICS
        }
        for key, value in changes.items():
            figures[f"{figure_name(label)}.{key}_change"] = value
        lines.append(
            f"| {label} | {100 * changes['m_ate_trans']:+.1f} % | {100 * changes['m_ate_rot_deg']:+.1f} % | "
            f"{100 * changes['seg_trans_percent']:+.1f} % | {100 * changes['seg_rot_deg_per_m']:+.1f} % |"
        )
    return [*lines, ""]
