"""The real-data sun experiment (thesis Table 5.2, simulated-sun rows) on the thesis baseline's VO.

For each KITTI odometry sequence (00-10 without 03) the thesis baseline's real stereo VO
(``kitti/viso2s-vo/baseline/<drive>.mat``: per-frame motions and covariances) is fused in
:class:`pvo_fusion.FusionGraph` with simulated sun measurements (every 10th frame, GT-Sun-0/10/20/30,
:mod:`pvo_pseudosensors.simulated_sun`) made from the ground-truth sun vectors in
``kitti/sun/kitti_sun_test_XX.csv``. The map-frame sun direction is taken from the ground-truth pose
(``s_map(t_k) = C_map,k s_k``), standing in for the ephemeris: the files carry no latitude/longitude.

VO covariance calibration: the viso2-s covariances are overconfident (ANEES 5-20). Each sequence is
fused with per-degree-of-freedom variance scales learned on the *other* sequences (leave one sequence
out, as the thesis trains Sun-BCNN): ``scale_i = mean_k(e_k,i^2 / Sigma_k,ii)`` over their 10-frame motions
(the span between two sun measurements; over one frame KITTI's ground-truth noise rivals the VO error),
``Sigma_k`` the per-frame covariances carried through the span, so that each dof's NEES is 1 there on
the training data. Sequences 01 and 04 ship no covariances; they get the static per-frame covariance
``diag(mean_k e_k,i^2) / 10`` learned the same way on the others.

ARMSE (the thesis's tables do not spell it out; this is the reading of its CRMSE plots, Figs 5.8 and
5.10): per frame k the error of the estimate against ground truth in the map frame — translation
``|r_k - r_k,gt|``, translation in the horizontal (east-north) plane using the first two map axes,
rotation ``|Log(C_k C_k,gt^T)|`` (axis-angle) — the cumulative RMSE ``CRMSE(k) = sqrt(mean_{i<=k} e_i^2)``,
and ``ARMSE = mean_k CRMSE(k)``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import nearest_rotations, se3_adjoint, se3_inverse, se3_log
from pvo_core.metrics import se3_inverse_batch
from pvo_fusion.sun_reference import TabulatedSunReference
from pvo_pseudosensors.simulated_sun import SimulatedSunConfig, SimulatedSunSensor

from pvo_fusion import FusionGraph, RelativeMeasurement, SunMeasurement
from pvo_fusion.config import FusionConfig, from_flat

Array = NDArray[np.float64]

SEQUENCE_DRIVES = {
    "00": "2011_10_03_drive_0027",
    "01": "2011_10_03_drive_0042",
    "02": "2011_10_03_drive_0034",
    "04": "2011_09_30_drive_0016",
    "05": "2011_09_30_drive_0018",
    "06": "2011_09_30_drive_0020",
    "07": "2011_09_30_drive_0027",
    "08": "2011_09_30_drive_0028",
    "09": "2011_09_30_drive_0033",
    "10": "2011_09_30_drive_0034",
}
NOISE_LEVELS = (0.0, 10.0, 20.0, 30.0)
SUN_EVERY = 10
FRAME_PERIOD_NS = 100_000_000  # KITTI 10 Hz; the .mat files carry no times
FIRST_STAMP_NS = 1_000_000_000

ARMSE_DEFINITION = (
    "ARMSE = mean over frames k of CRMSE(k) = sqrt(mean_{i<=k} e_i^2), e_k the error against ground truth in the map "
    "frame: trans |r_k - r_gt,k| (m); EN-plane: first two map (ENU) axes only; rot |Log(C_k C_gt,k^T)| (axis-angle, "
    "x1e-3). Estimates are the fixed-lag smoother's final ones."
)


@dataclass
class SunSequence:
    """One KITTI sequence: ground truth T_map,cam (N,4,4), VO poses (N,4,4), VO covariances, sun vectors."""

    name: str
    drive: str
    ground_truth: Array
    vo_poses: Array
    covariances: Array | None  # (N-1, 6, 6) ROS order [rho; phi], left perturbation of T_k,k-1
    sun_camera: Array  # (N, 3) unit vectors, camera frame
    stamps: NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        self.stamps = FIRST_STAMP_NS + FRAME_PERIOD_NS * np.arange(len(self.ground_truth), dtype=np.int64)

    @property
    def motions(self) -> Array:
        """VO motions T_k,k-1 (N-1, 4, 4)."""
        return se3_inverse_batch(self.vo_poses[1:]) @ self.vo_poses[:-1]

    def sun_map(self) -> Array:
        """Ground-truth sun direction in the map frame per frame (N, 3): C_map,k s_k."""
        return np.einsum("nij,nj->ni", self.ground_truth[:, :3, :3], self.sun_camera)


def clip_sequence(seq: SunSequence, frames: int) -> SunSequence:
    """The first ``frames`` frames of a sequence."""
    if frames < 2:
        raise ValueError(f"a clip needs at least 2 frames, got {frames}")
    n = min(frames, len(seq.ground_truth))
    covs = None if seq.covariances is None else seq.covariances[: n - 1]
    return SunSequence(seq.name, seq.drive, seq.ground_truth[:n], seq.vo_poses[:n], covs, seq.sun_camera[:n])


def load_sun_sequence(data_dir: Path, name: str) -> SunSequence:
    """Read ``kitti/viso2s-vo/baseline/<drive>.mat`` and ``kitti/sun/kitti_sun_test_<name>.csv``."""
    from scipy.io import loadmat

    if name not in SEQUENCE_DRIVES:
        raise ValueError(f"sequence {name!r} is not one of {', '.join(SEQUENCE_DRIVES)}")
    drive = SEQUENCE_DRIVES[name]
    mat_path = data_dir / "kitti" / "viso2s-vo" / "baseline" / f"{drive}.mat"
    sun_path = data_dir / "kitti" / "sun" / f"kitti_sun_test_{name}.csv"
    for path in (mat_path, sun_path):
        if not path.is_file():
            raise ValueError(f"{path}: no such file (see shared/data/SOURCES.md)")
    mat = loadmat(str(mat_path))
    gt = np.ascontiguousarray(np.moveaxis(mat["poses_gt"], 2, 0), dtype=float)
    est = np.ascontiguousarray(np.moveaxis(mat["poses_est"], 2, 0), dtype=float)
    covariances = np.asarray(mat["Sigma_21"], dtype=float) if "Sigma_21" in mat else None
    rows = []
    for number, line in enumerate(sun_path.read_text().splitlines(), 1):
        parts = line.split(",")
        if len(parts) != 4:
            raise ValueError(f"{sun_path}:{number}: expected relpath,sx,sy,sz")
        rows.append([float(v) for v in parts[1:]])
    sun = np.asarray(rows, dtype=float)
    if len(sun) != len(gt) or len(est) != len(gt):
        raise ValueError(f"{name}: {len(gt)} ground-truth poses, {len(est)} VO poses and {len(sun)} sun vectors differ")
    if covariances is not None and covariances.shape != (len(gt) - 1, 6, 6):
        raise ValueError(f"{mat_path}: Sigma_21 has shape {covariances.shape}, expected ({len(gt) - 1}, 6, 6)")
    sun /= np.linalg.norm(sun, axis=1, keepdims=True)
    # The files' rotations are orthonormal to ~4e-13 only: composed over 4541 frames with inverse =
    # transpose (GTSAM) or with a general inverse, the same VO drifts 2.6e-7 m apart. Project them onto SO(3).
    for poses in (gt, est):
        poses[:, :3, :3] = nearest_rotations(poses[:, :3, :3])
    return SunSequence(name, drive, gt, est, covariances, sun)


# --------------------------------------------------------------------------- VO covariance calibration
@dataclass(frozen=True)
class VOCalibration:
    """Per-dof variance scales (ROS order) for sequences with covariances, a static covariance for the rest."""

    scale: Array
    static_covariance: Array
    trained_on: tuple[str, ...]


def span_errors(seq: SunSequence, span: int, covariances: Array | None = None) -> tuple[Array, Array | None]:
    """Left errors (ROS order) of the VO's composite motions T_k,k-span against ground truth, and their
    first-order covariances from the per-frame ones (each left perturbation carried through by the adjoint)."""
    motions = seq.motions
    covs = seq.covariances if covariances is None else covariances
    errors, propagated = [], []
    for k in range(span, len(seq.ground_truth), span):
        composite = np.eye(4)
        sigma = np.zeros((6, 6))
        for j in range(k - span, k):
            if covs is not None:
                adjoint = se3_adjoint(motions[j])
                sigma = adjoint @ sigma @ adjoint.T + covs[j]
            composite = motions[j] @ composite
        truth = se3_inverse(seq.ground_truth[k]) @ seq.ground_truth[k - span]
        errors.append(se3_log(composite @ se3_inverse(truth)))
        propagated.append(sigma)
    return np.array(errors), (np.array(propagated) if covs is not None else None)


def calibrate_vo(train: Iterable[SunSequence], span: int = SUN_EVERY) -> VOCalibration:
    """Variance scales that make the VO consistent over ``span``-frame motions on the training sequences.

    Over one frame KITTI's own ground-truth noise is as large as the VO's error; over the span between
    two sun measurements the VO's drift dominates, and that drift is what the fusion must weigh.
    """
    ratios: list[Array] = []
    squared: list[Array] = []
    names: list[str] = []
    for seq in train:
        errors, propagated = span_errors(seq, span)
        squared.append(errors**2 / span)
        names.append(seq.name)
        if propagated is not None:
            ratios.append(errors**2 / np.diagonal(propagated, axis1=1, axis2=2))
    if not ratios:
        raise ValueError("VO calibration needs at least one training sequence with covariances")
    return VOCalibration(
        scale=np.concatenate(ratios).mean(axis=0),
        static_covariance=np.diag(np.concatenate(squared).mean(axis=0)),
        trained_on=tuple(names),
    )


def vo_measurements(seq: SunSequence, calibration: VOCalibration | None) -> list[RelativeMeasurement]:
    """One RelativeMeasurement T_k,k-1 per frame k >= 1 (covariances calibrated when given)."""
    motions = seq.motions
    if seq.covariances is not None:
        covs = seq.covariances
        if calibration is not None:
            s = np.sqrt(calibration.scale)
            covs = covs * np.outer(s, s)
    else:
        if calibration is None:
            raise ValueError(f"sequence {seq.name} has no VO covariances: a calibration is needed")
        covs = np.broadcast_to(calibration.static_covariance, (len(motions), 6, 6))
    return [
        RelativeMeasurement(int(seq.stamps[k + 1]), int(seq.stamps[k]), motions[k], np.array(covs[k]))
        for k in range(len(motions))
    ]


def sun_measurements(seq: SunSequence, mean_error_deg: float, seed: int) -> list[SunMeasurement]:
    """GT-Sun-N: a noisy measurement at every 10th frame (frame 0 included)."""
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=mean_error_deg, every_n=SUN_EVERY, seed=seed))
    out = []
    for k, truth in enumerate(seq.sun_camera):
        result = sensor.measure(truth)
        if result is not None:
            out.append(SunMeasurement(int(seq.stamps[k]), result[0], result[1]))
    return out


def sun_seed(base_seed: int, name: str, mean_error_deg: float) -> int:
    return int(base_seed) * 100_000 + int(name) * 1000 + round(mean_error_deg * 10)


def prepare_sequence(
    data_dir: Path, name: str, mean_error_deg: float = 10.0, seed: int = 0, frames: int | None = None
) -> tuple[SunSequence, list[RelativeMeasurement], list[SunMeasurement]]:
    """One sequence ready to fuse: its VO calibrated on the other sequences (leave one out) and its
    GT-Sun measurements; ``frames`` keeps only the first N frames (after the calibration)."""
    seq = load_sun_sequence(data_dir, name)
    calibration = calibrate_vo(load_sun_sequence(data_dir, n) for n in SEQUENCE_DRIVES if n != name)
    if frames:
        seq = clip_sequence(seq, frames)
    return seq, vo_measurements(seq, calibration), sun_measurements(seq, mean_error_deg, sun_seed(seed, name, mean_error_deg))


def experiment_config(overrides: dict | None = None) -> FusionConfig:
    """The fusion configuration of the experiment: prior from the first ground-truth pose, tabulated sun reference."""
    values = {"prior.source": "given", "inputs.sun.reference": "table"}
    values.update(overrides or {})
    return from_flat(values)


def ordered_events(
    vo: list[RelativeMeasurement], sun: list[SunMeasurement]
) -> list[tuple[str, RelativeMeasurement | SunMeasurement]]:
    """Measurements in arrival order: each frame's VO, then the frame's sun measurement (frame 0's sun first)."""
    by_stamp = {m.stamp: m for m in sun}
    events: list[tuple[str, RelativeMeasurement | SunMeasurement]] = []
    if vo and vo[0].reference_stamp in by_stamp:
        events.append(("sun", by_stamp.pop(vo[0].reference_stamp)))
    for m in vo:
        events.append(("vo", m))
        if m.stamp in by_stamp:
            events.append(("sun", by_stamp.pop(m.stamp)))
    return events


@dataclass
class RunResult:
    poses: Array  # (N, 4, 4) final fixed-lag estimates
    online_poses: Array  # (N, 4, 4) newest-state estimate right after each frame's VO
    covariances: Array | None  # (N, 6, 6) online marginal covariances (ROS order, left) when asked
    seconds: float
    counts: dict[str, int]
    factors: dict[str, int]


def run_fusion(
    seq: SunSequence,
    vo: list[RelativeMeasurement],
    sun: list[SunMeasurement] | None,
    config: FusionConfig,
    covariance_every: int = 0,
) -> RunResult:
    """Fuse one sequence; ``sun=None`` runs VO alone through the same graph.

    ``covariance_every``: query the newest state's marginal covariance at every N-th frame (0: never);
    that time is not counted in ``seconds``.
    """
    graph = FusionGraph(config, TabulatedSunReference(seq.stamps, seq.sun_map()))
    graph.set_initial_pose(seq.ground_truth[0])
    events = ordered_events(vo, sun or [])
    add: dict[str, Callable] = {"vo": graph.add_vo, "sun": graph.add_sun}
    n = len(seq.stamps)
    index = {int(s): i for i, s in enumerate(seq.stamps)}
    final = np.full((n, 4, 4), np.nan)
    online = np.full((n, 4, 4), np.nan)
    covariances = np.full((n, 6, 6), np.nan) if covariance_every > 0 else None
    online[0] = seq.ground_truth[0]
    cov_seconds = 0.0
    start = time.perf_counter()
    for kind, m in events:
        add[kind](m)
        if kind == "vo" and graph.newest_stamp == m.stamp:
            k = index[m.stamp]
            online[k] = graph.pose()
            if covariances is not None and k % covariance_every == 0:
                t0 = time.perf_counter()
                covariances[k] = graph.covariance()
                cov_seconds += time.perf_counter() - t0
        for p in graph.drain_finished():
            final[index[p.stamp]] = p.pose
    for p in graph.trajectory():
        final[index[p.stamp]] = p.pose
    seconds = time.perf_counter() - start - cov_seconds
    return RunResult(final, online, covariances, seconds, dict(graph.counts), dict(graph.factor_counts))


# --------------------------------------------------------------------------- metrics
def crmse(errors: Array) -> Array:
    """Cumulative RMSE curve sqrt(mean_{i<=k} e_i^2)."""
    e = np.asarray(errors, dtype=float)
    return np.sqrt(np.cumsum(e**2) / np.arange(1, len(e) + 1))


def trajectory_errors(gt: Array, est: Array) -> dict[str, Array]:
    """Per-frame map-frame errors: translation (m), EN-plane translation (m), rotation angle (rad)."""
    from scipy.spatial.transform import Rotation

    diff = est[:, :3, 3] - gt[:, :3, 3]
    relative = np.einsum("nij,nkj->nik", est[:, :3, :3], gt[:, :3, :3])
    return {
        "trans": np.linalg.norm(diff, axis=1),
        "trans_en": np.linalg.norm(diff[:, :2], axis=1),
        "rot": np.linalg.norm(Rotation.from_matrix(relative).as_rotvec(), axis=1),
    }


def armse(gt: Array, est: Array) -> dict[str, float]:
    """Translational, EN-plane translational (m) and rotational (rad) ARMSE, plus the plain RMSEs."""
    errors = trajectory_errors(gt, est)
    out = {name: float(crmse(e).mean()) for name, e in errors.items()}
    out.update({f"{name}_rmse": float(np.sqrt(np.mean(e**2))) for name, e in errors.items()})
    return out


def pose_anees(gt: Array, est: Array, covariances: Array) -> float:
    """ANEES per dof of absolute poses: left errors Log(T_gt T_est^-1) against ROS-order left covariances
    (frames whose covariance was not queried, NaN, are skipped)."""
    from pvo_core.metrics import anees

    idx = [k for k in range(1, len(gt)) if np.all(np.isfinite(covariances[k]))]
    errors = np.array([se3_log(gt[k] @ se3_inverse(est[k])) for k in idx])
    return anees(errors, covariances[idx])


# --------------------------------------------------------------------------- the experiment
@dataclass
class SequenceReport:
    name: str
    length_km: float
    frames: int
    covariance_source: str
    calibration_scale: list[float]
    rows: dict[str, dict[str, float]]  # "VO" / "GT-Sun-10" -> metrics
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
    loaded = {name: load_sun_sequence(data_dir, name) for name in sorted(set(names) | set(SEQUENCE_DRIVES))}
    config = experiment_config(overrides)
    reports = []
    for name in names:
        seq = loaded[name]
        calibration = calibrate_vo(s for n, s in loaded.items() if n != name)
        vo = vo_measurements(seq, calibration)
        rows: dict[str, dict[str, float]] = {}
        seconds: dict[str, float] = {}
        counts: dict[str, dict[str, int]] = {}
        for level in [None, *levels]:
            label = row_name(level)
            trial_metrics = []
            for trial in range(1 if level is None else trials):
                sun = None if level is None else sun_measurements(seq, level, sun_seed(seed + trial, name, level))
                result = run_fusion(seq, vo, sun, config, covariance_every=anees_every if trial == 0 else 0)
                trial_metrics.append(armse(seq.ground_truth, result.poses))
                if result.covariances is not None:
                    trial_metrics[-1]["anees"] = pose_anees(seq.ground_truth, result.online_poses, result.covariances)
            metrics = {key: float(np.mean([m[key] for m in trial_metrics if key in m])) for key in trial_metrics[0]}
            rows[label] = metrics
            seconds[label] = result.seconds
            counts[label] = {**result.counts, **{f"factors.{k}": v for k, v in result.factors.items()}}
            if progress:
                progress(
                    f"{name} {label:>11}: trans {metrics['trans']:8.3f} m, EN {metrics['trans_en']:8.3f} m, "
                    f"rot {1e3 * metrics['rot']:7.2f} e-3, {result.seconds:5.2f} s"
                )
        length = float(np.sum(np.linalg.norm(np.diff(seq.ground_truth[:, :3, 3], axis=0), axis=1))) / 1000.0
        reports.append(
            SequenceReport(
                name,
                length,
                len(seq.stamps),
                "Sigma_21 x calibrated scale" if seq.covariances is not None else "static (learned on the other sequences)",
                [float(v) for v in calibration.scale],
                rows,
                seconds,
                counts,
            )
        )
    return reports


def format_table(reports: list[SequenceReport], levels: Iterable[float] = NOISE_LEVELS) -> str:
    """The thesis's Table 5.2 layout (simulated-sun rows) plus the mean relative change."""
    names = [r.name for r in reports]
    labels = ["Without Sun", *[row_name(level) for level in levels]]
    lines = []
    head = f"{'Sequence':<22}" + "".join(f"{n:>9}" for n in names) + f"{'mean chg':>10}"
    lines.append(head)
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
            change = ""
            if label != "Without Sun":
                rel = [r.rows[label][key] / r.rows["Without Sun"][key] - 1.0 for r in reports]
                change = f"{100 * float(np.mean(rel)):>+9.1f}%"
            lines.append(f"  {label:<20}" + "".join(f"{v:>9.2f}" for v in values) + f"{change:>10}")
    if all("anees" in r.rows[labels[0]] for r in reports):
        lines.append("ANEES per dof (online pose vs its marginal covariance, every 10th frame)")
        for label in labels:
            lines.append(f"  {label:<20}" + "".join(f"{r.rows[label]['anees']:>9.2f}" for r in reports))
    lines.append("")
    lines.append(ARMSE_DEFINITION)
    lines.append("mean chg = mean over the sequences of the relative change against Without Sun.")
    return "\n".join(lines)


def summary(reports: list[SequenceReport], levels: Iterable[float] = NOISE_LEVELS) -> dict[str, dict[str, float]]:
    """Mean relative change per level and metric (negative = better)."""
    out: dict[str, dict[str, float]] = {}
    for level in levels:
        label = row_name(level)
        out[label] = {
            key: float(np.mean([r.rows[label][key] / r.rows["Without Sun"][key] - 1.0 for r in reports]))
            for key in ("trans", "trans_en", "rot")
        }
    return out


def write_outputs(out_dir: Path, reports: list[SequenceReport], table: str, levels: Iterable[float] = NOISE_LEVELS) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    payload = {
        "definition": ARMSE_DEFINITION,
        "mean_relative_change": summary(reports, levels),
        "sequences": [r.__dict__ for r in reports],
    }
    (out_dir / "results.json").write_text(json.dumps(payload, indent=2))
    (out_dir / "report.md").write_text("# pvo experiment sun-sim\n\n```\n" + table + "\n```\n")
