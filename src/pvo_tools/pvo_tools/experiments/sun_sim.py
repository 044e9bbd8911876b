"""Thesis Table 5.2, simulated-sun rows: the thesis baseline's real stereo VO fused with GT-Sun-0/10/20/30.

For each KITTI odometry sequence (00-10 without 03) the viso2-s VO (:func:`pvo_core.readers.read_kitti_sun_sequence`)
is fused in :class:`pvo_fusion.FusionGraph` (:func:`pvo_fusion.run_offline`) with simulated sun measurements
(every 10th frame, :class:`pvo_pseudosensors.simulated_sun.SimulatedSunSensor`) made from the ground-truth
sun vectors. The map-frame sun direction is taken from the ground-truth pose (``s_map(t_k) = C_map,k s_k``),
standing in for the ephemeris: the files carry no latitude/longitude. Each sequence's VO covariances are
calibrated on the *other* sequences (leave one out, :func:`pvo_fusion.calibrate_vo` over the 10-frame span
between two sun measurements). Metrics: :data:`pvo_core.metrics.ARMSE_DEFINITION`.
"""

from __future__ import annotations

import argparse
import sys
import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pvo_core.readers import SEQUENCE_DRIVES, KittiSunSequence, read_kitti_sun_sequence
from pvo_core.results import RunResult
from pvo_fusion.sun_reference import TabulatedSunReference
from pvo_pseudosensors.simulated_sun import SimulatedSunConfig, SimulatedSunSensor

from pvo_core import metrics
from pvo_fusion import (
    CalibrationSequence,
    FusionConfig,
    FusionGraph,
    OfflineResult,
    RelativeMeasurement,
    SunMeasurement,
    VOCalibration,
    calibrate_vo,
    ordered_events,
    run_offline,
    sun_events,
    vo_measurements,
)
from pvo_fusion.config import from_flat

from ..overrides import parse_overrides
from ..paths import data_directory

TITLE = "Table 5.2: viso2-s VO on KITTI 00-10 fused with simulated sun (GT-Sun-0/10/20/30)"
NOISE_LEVELS = (0.0, 10.0, 20.0, 30.0)
SUN_EVERY = 10
BASELINE_MAX_SPEED = 1000.0  # m/s: above the viso2-s failures of sequence 01 (358 m/s), see experiment_config


def calibration_input(seq: KittiSunSequence) -> CalibrationSequence:
    return CalibrationSequence(seq.name, seq.ground_truth, seq.motions, seq.covariances)


def sequence_vo(seq: KittiSunSequence, calibration: VOCalibration | None) -> list[RelativeMeasurement]:
    return vo_measurements(seq.stamps, seq.motions, seq.covariances, calibration)


def sun_measurements(seq: KittiSunSequence, mean_error_deg: float, seed: int) -> list[SunMeasurement]:
    """GT-Sun-N: a noisy measurement at every 10th frame (frame 0 included)."""
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=mean_error_deg, every_n=SUN_EVERY, seed=seed))
    out = []
    for stamp, truth in zip(seq.stamps, seq.sun_camera, strict=True):
        result = sensor.measure(truth)
        if result is not None:
            out.append(SunMeasurement(int(stamp), result[0], result[1]))
    return out


def sun_seed(base_seed: int, name: str, mean_error_deg: float) -> int:
    """The GT-Sun noise seed of one sequence and noise level: a numbered sequence ("05", "0014") keeps the seed every
    earlier figure was drawn with; any other name ("03bm", a validation drive) its CRC-32 in place of the number."""
    number = int(name) if name.isdigit() else 100_000 + zlib.crc32(name.encode())
    return int(base_seed) * 100_000 + number * 1000 + round(mean_error_deg * 10)


def prepare_sequence(
    data_dir: Path, name: str, mean_error_deg: float = 10.0, seed: int = 0, frames: int | None = None
) -> tuple[KittiSunSequence, list[RelativeMeasurement], list[SunMeasurement]]:
    """One sequence ready to fuse: its VO calibrated on the other sequences (leave one out) and its
    GT-Sun measurements; ``frames`` keeps only the first N frames (after the calibration)."""
    seq = read_kitti_sun_sequence(data_dir, name)
    others = (calibration_input(read_kitti_sun_sequence(data_dir, n)) for n in SEQUENCE_DRIVES if n != name)
    calibration = calibrate_vo(others, SUN_EVERY)
    if frames:
        seq = seq.clipped(frames)
    return seq, sequence_vo(seq, calibration), sun_measurements(seq, mean_error_deg, sun_seed(seed, name, mean_error_deg))


def experiment_config(overrides: dict | None = None) -> FusionConfig:
    """The fusion configuration of the experiment: prior from the first ground-truth pose, tabulated sun reference,
    and the baseline VO fused as it is, failures included, as the thesis did: sequence 01's viso2-s run has six
    motions at up to 358 m/s, which the default plausibility bound (100 m/s) would reject."""
    values = {"prior.source": "given", "inputs.sun.reference": "table", "inputs.vo.max_speed": BASELINE_MAX_SPEED}
    values.update(overrides or {})
    return from_flat(values)


def run_fusion(
    seq: KittiSunSequence,
    vo: list[RelativeMeasurement],
    sun: list[SunMeasurement] | None,
    config: FusionConfig,
    covariance_every: int = 0,
    on_vo: Callable[[int, FusionGraph], None] | None = None,
    rotations: Sequence[RelativeMeasurement] = (),
) -> OfflineResult:
    """Fuse one sequence; ``sun=None`` runs VO alone through the same graph; ``rotations`` (relative rotations, as
    HydraNet's) join it, each just before the VO of its frame."""
    graph = FusionGraph(config, TabulatedSunReference(seq.stamps, seq.sun_map()))
    graph.set_initial_pose(seq.ground_truth[0])
    others = sun_events(sun or []) + [("rotation", r) for r in rotations]
    return run_offline(graph, seq.stamps, ordered_events(vo, others, before=("rotation",)), covariance_every, on_vo)


@dataclass
class SequenceReport:
    name: str
    length_km: float
    frames: int
    covariance_source: str
    calibration_scale: list[float]
    rows: dict[str, dict[str, float]]  # "Without Sun" / "GT-Sun-10" -> metrics
    seconds: dict[str, float]
    counts: dict[str, dict[str, int]]


def row_name(level: float | None) -> str:
    return "Without Sun" if level is None else f"GT-Sun-{level:g}"


def run_experiment(
    data_dir: Path,
    sequences: Iterable[str] = tuple(SEQUENCE_DRIVES),
    levels: Iterable[float] = NOISE_LEVELS,
    seed: int = 0,
    overrides: dict | None = None,
    anees_every: int = 10,
    progress: Callable[[str], None] | None = None,
    trials: int = 1,
) -> list[SequenceReport]:
    """Every sequence: VO alone, then each noise level averaged over ``trials`` seeded noise realisations
    (ANEES from the first trial)."""
    if trials < 1:
        raise ValueError(f"--trials must be >= 1, got {trials}")
    names = list(sequences)
    levels = list(levels)
    loaded = {name: read_kitti_sun_sequence(data_dir, name) for name in sorted(set(names) | set(SEQUENCE_DRIVES))}
    config = experiment_config(overrides)
    reports = []
    for name in names:
        seq = loaded[name]
        calibration = calibrate_vo((calibration_input(s) for n, s in loaded.items() if n != name), SUN_EVERY)
        vo = sequence_vo(seq, calibration)
        rows: dict[str, dict[str, float]] = {}
        seconds: dict[str, float] = {}
        counts: dict[str, dict[str, int]] = {}
        for level in [None, *levels]:
            label = row_name(level)
            trial_metrics = []
            for trial in range(1 if level is None else trials):
                sun = None if level is None else sun_measurements(seq, level, sun_seed(seed + trial, name, level))
                result = run_fusion(seq, vo, sun, config, covariance_every=anees_every if trial == 0 else 0)
                trial_metrics.append(metrics.armse(seq.ground_truth, result.poses))
                if result.covariances is not None:
                    trial_metrics[-1]["anees"] = metrics.pose_anees(seq.ground_truth, result.online_poses, result.covariances)
            rows[label] = metrics.average_figures(trial_metrics)
            seconds[label] = result.seconds
            counts[label] = {**result.counts, **{f"factors.{k}": v for k, v in result.factors.items()}}
            if progress:
                m = rows[label]
                progress(
                    f"{name} {label:>11}: trans {m['trans']:8.3f} m, EN {m['trans_en']:8.3f} m, "
                    f"rot {1e3 * m['rot']:7.2f} e-3, {result.seconds:5.2f} s"
                )
        reports.append(
            SequenceReport(
                name,
                float(metrics.path_distances(seq.ground_truth)[-1]) / 1000.0,
                len(seq.stamps),
                "Sigma_21 x calibrated scale" if seq.covariances is not None else "static (learned on the other sequences)",
                [float(v) for v in calibration.scale],
                rows,
                seconds,
                counts,
            )
        )
    return reports


def summary(reports: list[SequenceReport], levels: Iterable[float] = NOISE_LEVELS) -> dict[str, dict[str, float]]:
    """Mean relative change against VO alone per level and metric (negative = better)."""
    baseline = row_name(None)
    return {
        row_name(level): {
            key: metrics.mean_relative_change(
                [r.rows[row_name(level)][key] for r in reports], [r.rows[baseline][key] for r in reports]
            )
            for key in ("trans", "trans_en", "rot")
        }
        for level in levels
    }


def format_table(reports: list[SequenceReport], levels: Iterable[float] = NOISE_LEVELS) -> str:
    """The thesis's Table 5.2 layout (simulated-sun rows) plus the mean relative change."""
    levels = list(levels)
    names = [r.name for r in reports]
    labels = [row_name(None), *[row_name(level) for level in levels]]
    changes = summary(reports, levels)
    lines = [f"{'Sequence':<22}" + "".join(f"{n:>9}" for n in names) + f"{'mean chg':>10}"]
    lines.append(f"{'Length [km]':<22}" + "".join(f"{r.length_km:>9.1f}" for r in reports))
    sections = [
        ("Trans. ARMSE [m]", "trans", 1.0),
        ("Trans. ARMSE (EN-plane) [m]", "trans_en", 1.0),
        ("Rot. ARMSE (x1e-3) [axis-angle]", "rot", 1e3),
    ]
    for title, key, factor in sections:
        lines.append(title)
        for label in labels:
            values = [r.rows[label][key] * factor for r in reports]
            change = f"{100 * changes[label][key]:>+9.1f}%" if label in changes else ""
            lines.append(f"  {label:<20}" + "".join(f"{v:>9.2f}" for v in values) + f"{change:>10}")
    if all("anees" in r.rows[labels[0]] for r in reports):
        lines.append("ANEES per dof (online pose vs its marginal covariance, every 10th frame)")
        for label in labels:
            lines.append(f"  {label:<20}" + "".join(f"{r.rows[label]['anees']:>9.2f}" for r in reports))
    lines.append("")
    lines.append(metrics.ARMSE_DEFINITION)
    lines.append("mean chg = mean over the sequences of the relative change against Without Sun.")
    return "\n".join(lines)


def run_record(reports: list[SequenceReport], levels: Iterable[float], inputs: dict[str, str]) -> RunResult:
    """The run-result record: mean changes as figures, every sequence's rows as tables."""
    changes = summary(reports, levels)
    figures = {f"{label}.{key}_change": value for label, row in changes.items() for key, value in row.items()}
    tables = {f"sequence {r.name}": r.rows for r in reports}
    details = {
        f"sequence {r.name} details": {
            "info": {
                "length_km": r.length_km,
                "frames": r.frames,
                "covariance_source": r.covariance_source,
                "calibration_scale": r.calibration_scale,
            },
            "seconds": r.seconds,
            **{f"counts {label}": c for label, c in r.counts.items()},
        }
        for r in reports
    }
    return RunResult(
        "experiment/sun-sim",
        "sun-sim",
        figures=figures,
        tables={**tables, **details},
        inputs=inputs,
        notes={"armse": metrics.ARMSE_DEFINITION},
    )


# --------------------------------------------------------------------------- the command
def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    parser.add_argument("--sequences", nargs="+", default=None, help="sequences (default: 00 01 02 04 05 06 07 08 09 10)")
    parser.add_argument("--levels", nargs="+", type=float, default=None, help="mean sun errors in degrees (default 0 10 20 30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated sun noise (default 0)")
    parser.add_argument("--trials", type=int, default=1, help="noise realisations averaged per level (seeds SEED..SEED+N-1)")
    parser.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="fusion parameter, e.g. -p window.lag=20")
    parser.add_argument("--no-anees", action="store_true", help="skip the marginal covariances (faster)")
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/sun-sim"), help="output directory (default runs/sun-sim)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no per-run lines")
    parser.add_argument(
        "--through-nodes",
        metavar="SEQ",
        help="instead: run SEQ with GT-Sun-10 as a bag through the fusion node over DDS and compare with the ROS-free run",
    )
    parser.add_argument("--frames", type=int, help="with --through-nodes: only the first N frames")
    parser.add_argument("--rate", type=float, default=20.0, help="with --through-nodes: playback rate (default 20x real time)")


def run(args: argparse.Namespace) -> int:
    data = data_directory(args.data)
    if args.through_nodes:
        from .sun_sim_nodes import compare_through_nodes

        return compare_through_nodes(args, data)
    sequences = args.sequences or list(SEQUENCE_DRIVES)
    levels = args.levels if args.levels is not None else list(NOISE_LEVELS)
    overrides = parse_overrides(args.param)
    say = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    start = time.perf_counter()
    anees_every = 0 if args.no_anees else 10
    reports = run_experiment(data, sequences, levels, args.seed, overrides, anees_every, progress=say, trials=args.trials)
    table = format_table(reports, levels)
    if args.trials > 1:
        seeds = f"{args.seed}..{args.seed + args.trials - 1}"
        table += f"\nEach GT-Sun row is the mean over {args.trials} noise realisations (seeds {seeds})."
    print(table)
    for label, change in summary(reports, levels).items():
        print(
            f"{label}: mean change trans {100 * change['trans']:+.1f} %, "
            f"EN {100 * change['trans_en']:+.1f} %, rot {100 * change['rot']:+.1f} %"
        )
    inputs = {
        "data": str(data),
        "sequences": " ".join(sequences),
        "levels": " ".join(f"{v:g}" for v in levels),
        "seed": str(args.seed),
        "trials": str(args.trials),
        "parameters": " ".join(args.param or []),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    run_record(reports, levels, inputs).write(args.out)
    (args.out / "report.md").write_text("# pvo experiment sun-sim\n\n```\n" + table + "\n```\n")
    print(f"wrote {args.out}/metrics.json and report.md ({time.perf_counter() - start:.1f} s)")
    return 0
