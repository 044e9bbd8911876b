"""DPC-Net's corrections applied to this project's stereo VO on one sequence (no I/O beyond reading it).

Two ways to apply them: ``fusion`` — the VO's frame-to-frame transforms and the corrected Δp-frame transforms
as factors of the fixed-lag smoother (:class:`pvo_fusion.FusionGraph`), the pose-graph relaxation of thesis
§6.4.5; ``overwrite`` — the authors' shipped code: every Δp-th pose overwritten by the corrected transform, the
VO chained in between (:func:`pvo_pseudosensors.dpc_net.infer.overwrite_trajectory`).
"""

from __future__ import annotations

import copy
import subprocess
import sys
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
FIRST_STAMP_NS = 1_000_000_000  # the fusion's stamps start at 1 s (a zero stamp reads as unset in ROS)
METHODS = ("fusion", "overwrite")
#: the thesis's lens (Table 6.2) and the calibration error of Table 6.1's rig (calib.txt's focal length)
LENS = (-0.3, 0.2, 0.01)
FOCAL_SCALE = 1.03
RIGS = ("clean", "lens", "calib")


@dataclass(frozen=True)
class Drive:
    """A long sequence rendered along a KITTI drive: its name, the drive, the drive's first frame used, frames
    (None: the caller's choice), and the renderer's seed and heading (deg) — a different world along the same
    motion. ``mirror_of``: not rendered but the named drive (of the same list) mirrored left-right
    (:mod:`pvo_sim.mirror`), its every right turn a left turn."""

    name: str
    drive: str
    start: int
    frames: int | None
    seed: int
    heading: float
    mirror_of: str = ""


#: a drive's world K > 0 (``pvo dpc-net drives --world K``) is seeded this many times K above its own world
WORLD_SEED_STRIDE = 1000


def in_world(drives: Sequence[Drive], world: int) -> tuple[Drive, ...]:
    """The same drives (motion, heading, frames, mirrors) through world ``world``: 0 their own, K > 0 another world
    along each (its seed + WORLD_SEED_STRIDE * K)."""
    if world < 0:
        raise ValueError(f"--world must be >= 0, got {world}")
    return tuple(replace(d, seed=d.seed + WORLD_SEED_STRIDE * world) for d in drives)


#: the experiment's test drives (KITTI 05, 06, 07: no training or validation sequence drove them; windows of one
#: drive overlap by at most 140 frames)
_TEST_STARTS = (("05a", "05", 0), ("06", "06", 0), ("07", "07", 0), ("05b", "05", 900), ("05c", "05", 1760))
TEST_DRIVES: tuple[Drive, ...] = tuple(
    Drive(name, drive, start, None, 900 + i, 37 * i % 360) for i, (name, drive, start) in enumerate(_TEST_STARTS)
)
#: long drives rendered like the test drives: what the fusion's weighing is chosen on (`pvo dpc-net calibrate
#: --drives`), at the length the test figures are measured over — along the corpora's validation drives (KITTI 04,
#: 10) and along KITTI 03, which no corpus split drives: a country road at 7 m/s that turns through 276 deg in
#: 80 s, where 10's turns are a few tight ones across an empty square and 04 is straight. All three turn right on
#: the whole, so each is also mirrored left-right ("m"): a correction that helps one turn direction and harms the
#: other is seen on validation, not first on the test drives.
#: Since stop 38 each drive also a second time through another world (seed and heading): a weighing chosen on four
#: worlds (and their mirror images, which share them) was still the four worlds'.
_VALIDATION_RENDERED = (
    Drive("10a", "10", 0, 1000, 950, 200),
    Drive("10b", "10", 201, 1000, 951, 311),
    Drive("04", "04", 0, 271, 952, 77),
    Drive("03", "03", 0, 801, 953, 142),
    Drive("10c", "10", 100, 1000, 954, 50),
    Drive("10d", "10", 150, 1000, 955, 120),
    Drive("04b", "04", 0, 271, 956, 170),
    Drive("03b", "03", 0, 801, 957, 290),
)
VALIDATION_DRIVES: tuple[Drive, ...] = _VALIDATION_RENDERED + tuple(
    replace(d, name=f"{d.name}m", mirror_of=d.name) for d in _VALIDATION_RENDERED
)


@dataclass
class CorrectedSequence:
    """vo: the VO's camera-to-odom poses (N, 4, 4); corrected: after the corrections, online (the newest state
    as the fusion node publishes it; the overwrite is causal, so both are the same there) and smoothed (after
    the fixed lag); corrections: what the model predicted; accepted: corrections the fusion took; warnings: the
    model card's rig check (what could not be verified); gated_for_s: the longest time (s) over which the fusion's
    gate took none of the corrections (0 with the overwrite)."""

    vo: Array
    corrected: Array
    corrected_online: Array
    corrections: Any
    accepted: int
    warnings: list[str] = field(default_factory=list)
    gated_for_s: float = 0.0


def rig_sequences(manifest: Any, card: Any, split: str = "validation") -> list[Any]:
    """The sequences of ``split`` of a corpus manifest that are the model's rig: its presets (the card's), none of
    another camera (the conditions DPC-Net's training leaves out, ``ModelEntry.off_rig``)."""
    from pvo_pseudosensors.registry import models

    off_rig = set(models()["dpc-net"].off_rig)
    presets = set((card.corpus or {}).get("presets") or [])
    return [s for s in manifest.split(split) if not set(s.conditions) & off_rig and (not presets or s.preset in presets)]


def render_drives(
    drives: Sequence[Drive],
    data: Path,
    out: Path,
    frames: int | None = None,
    jobs: int = 2,
    say: Any = print,
    rigs: Sequence[str] = RIGS,
) -> dict[str, list[Path]]:
    """``drives`` rendered clean and through :data:`LENS` into ``out/clean`` and ``out/lens`` (urban, 1x, KITTI
    geometry at 620x188; `pvo sim` in ``jobs`` parallel processes; complete ones of this renderer revision kept),
    and the clean ones with calib.txt's focal length x :data:`FOCAL_SCALE` in ``out/calib`` (:func:`miscalibrate`).
    ``frames``: for a drive whose own is None; ``rigs``: the rigs wanted (:data:`RIGS`; ``calib`` needs the clean
    renders, so it renders them too). A drive with ``mirror_of`` is that drive's folder mirrored (made again when
    its source was rendered since). Returns the folders per rig asked for."""
    from pvo_sim.mirror import mirror_sequence

    from .experiments.common import another_world, rendered_by_this_revision

    unknown = sorted(set(rigs) - set(RIGS))
    if unknown or not rigs:
        raise ValueError(f"rigs must be some of {', '.join(RIGS)}, got {', '.join(rigs) or 'none'}")
    rendered = [rig for rig in ("clean", "lens") if rig in rigs or (rig == "clean" and "calib" in rigs)]
    commands, folders = [], {rig: [] for rig in RIGS}
    names = {d.name for d in drives if not d.mirror_of}
    for drive in drives:
        if drive.mirror_of:
            if drive.mirror_of not in names:
                raise ValueError(f"drive {drive.name} mirrors {drive.mirror_of}, which is not among the drives rendered")
            folders.update({rig: [*folders[rig], out / rig / drive.name] for rig in rendered})
            continue
        count = drive.frames or frames
        if not count:
            raise ValueError(f"drive {drive.name}: no frame count")
        for rig in rendered:
            folder = out / rig / drive.name
            folders[rig].append(folder)
            if rendered_by_this_revision(folder):
                if (error := another_world(folder, drive.seed, "OUT")) is not None:
                    raise error
                continue
            command = [sys.executable, "-m", "pvo_tools.cli", "sim", str(folder), "--poses"]
            command += [str((data / "kitti" / "poses" / f"{drive.drive}.txt").resolve()), "--start", str(drive.start)]
            command += ["--frames", str(count), "--supersample", "1", "--seed", str(drive.seed), "-q", "--overwrite"]
            command += ["--heading", f"{drive.heading:g}", "--start-time", "2011-09-30T10:30:00Z"]
            if rig == "lens":
                command += ["--distortion", *map(str, LENS)]
            commands.append((f"{rig}/{drive.name}", command))
    if commands:
        say(f"rendering {len(commands)} sequences ({jobs} at a time) ...")

    def render(item: tuple[str, list[str]]) -> None:
        label, command = item
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"rendering {label} failed: {(done.stderr.strip().splitlines() or ['?'])[-1]}")
        say(f"  {label} rendered")

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        list(pool.map(render, commands))
    for drive in (d for d in drives if d.mirror_of):
        for rig in rendered:
            source, mirrored = out / rig / drive.mirror_of, out / rig / drive.name
            done = mirrored / "poses.txt"
            if not done.is_file() or done.stat().st_mtime < (source / "poses.txt").stat().st_mtime:
                mirror_sequence(source, mirrored, overwrite=True)
                say(f"  {rig}/{drive.name} mirrored from {drive.mirror_of}")
    if "calib" in rigs:
        for folder in folders["clean"]:
            folders["calib"].append(miscalibrate(folder, out / "calib" / folder.name, FOCAL_SCALE))
    return {rig: paths for rig, paths in folders.items() if rig in rigs}


#: Files of a rendered drive that a wrong calib.txt leaves as they are (linked into the miscalibrated rig).
UNCHANGED_SENSORS = ("sun.csv", "gps.csv", "imu.csv")


def miscalibrate(source: Path, out: Path, focal_scale: float) -> Path:
    """``source``'s sequence (its images, poses and the sensors a calibration does not change — sun, GPS, IMU —
    linked) with ``calib.txt``'s focal length (and so the P1 baseline term, -f b) times ``focal_scale``, and its
    ``sim.yaml`` saying so: what `pvo sim --focal-scale` writes for the same images."""
    import yaml
    from pvo_core.readers.kitti import read_kitti_calibration

    out.mkdir(parents=True, exist_ok=True)
    for name in ("image_0", "image_1", "poses.txt", "times.txt", *UNCHANGED_SENSORS):
        link = out / name
        if not link.exists() and (name not in UNCHANGED_SENSORS or (source / name).exists()):  # sensors: when recorded
            link.symlink_to((source / name).resolve())
    lines = []
    for key, matrix in read_kitti_calibration(source / "calib.txt").items():
        scaled = matrix.copy()
        scaled[0, 0] *= focal_scale
        scaled[1, 1] *= focal_scale
        scaled[0, 3] *= focal_scale
        lines.append(f"{key}: " + " ".join(f"{v:.12e}" for v in scaled.reshape(-1)))
    (out / "calib.txt").write_text("\n".join(lines) + "\n")
    meta = yaml.safe_load((source / "sim.yaml").read_text())
    meta["config"]["degradations"]["focal_scale"] = focal_scale
    (out / "sim.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return out


def vo_run(root: Path, rate_hz: float = 10.0, config: Any = None) -> Any:
    """This project's stereo VO over the KITTI-layout sequence at ``root``: ``config`` (a ``VOConfig``; a model's
    is :func:`model_vo`), the defaults when None."""
    from pvo_core.readers import KittiSequence
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig

    sequence = KittiSequence(root, rate_hz=None if (Path(root) / "times.txt").is_file() else rate_hz)
    return run_sequence(sequence, config or VOConfig()), sequence


def model_vo(card: Any) -> Any:
    """The VO whose errors the model of ``card`` learned (its card's rig record names it): the one to correct."""
    from pvo_pseudosensors.dpc_net.data import card_vo_config

    return card_vo_config(card.input.get("rig"))


def correct_sequence(
    root: Path,
    model: Any,
    card: Any,
    method: str = "fusion",
    vo_calibration: Any = None,
    run: Any = None,
    rate_hz: float = 10.0,
    allow_any_rig: bool = False,
    cache_dir: Path | None = None,
    corrections: Any = None,
) -> CorrectedSequence:
    """The VO of the sequence at ``root`` (``run``: a `run_sequence` result already made, else it is run) with
    ``model``'s corrections applied by ``method`` (``corrections``: those already predicted for this run, else
    they are). ``vo_calibration``: per-axis scales of the VO's covariances
    (:func:`pvo_fusion.calibrate_vo`), None for the VO's own. The model's rig is checked first
    (:func:`pvo_pseudosensors.dpc_net.rig.check_rig`: ``ValueError`` on another rig unless ``allow_any_rig``). The VO
    run here is the model's (:func:`model_vo`); a ``run`` given must be of that VO."""
    from pvo_pseudosensors.dpc_net.infer import overwrite_trajectory, predict_corrections
    from pvo_pseudosensors.dpc_net.rig import check_rig

    from pvo_fusion import FusionGraph, RelativeMeasurement, ordered_events, run_offline, vo_measurements
    from pvo_fusion.config import from_flat

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    warnings = check_rig(card.input.get("rig"), root, allow_any_rig)
    sequence = None
    if run is None:
        run, sequence = vo_run(root, rate_hz, model_vo(card))
    if corrections is None:
        corrections = predict_corrections(model, card, root, run.poses, cache_dir)
    if method == "overwrite":
        poses = overwrite_trajectory(run.poses, corrections)
        return CorrectedSequence(run.poses, poses, poses, corrections, len(corrections.first), warnings)
    if sequence is None:
        from pvo_core.readers import KittiSequence

        sequence = KittiSequence(root, rate_hz=None if (Path(root) / "times.txt").is_file() else rate_hz)
    stamps = FIRST_STAMP_NS + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
    relative = run.relative()
    vo = vo_measurements(stamps, relative["transforms"], relative["covariances"], vo_calibration)
    others = [
        ("correction", RelativeMeasurement(int(stamps[b]), int(stamps[a]), t, c))
        for a, b, t, c in zip(corrections.first, corrections.last, corrections.transforms, corrections.covariances, strict=True)
    ]
    graph = FusionGraph(from_flat({"prior.source": "given"} | card_vo_fusion(card)))
    graph.set_initial_pose(np.eye(4))
    fused = run_offline(graph, stamps, ordered_events(vo, others))
    accepted = int(fused.counts.get("correction.accepted", 0))
    gated = fused.gated_for_s.get("correction", 0.0)
    return CorrectedSequence(run.poses, fused.poses, fused.online_poses, corrections, accepted, warnings, gated)


@dataclass
class SpanChoice:
    """The VO calibration span chosen for the fusion: ``span`` (frames), and per candidate span the mean relative
    change of the fused m-ATE (translation, rotation) against the VO alone on the held-out validation sequences;
    ``folds``: 2 (scales learned on one half, measured on the other) or 1 (one sequence: in sample)."""

    span: int
    changes: dict[int, tuple[float, float]]
    sequences: int
    folds: int
    vo_calibration: Any = None  # pvo_fusion.VOCalibration at ``span`` learned on every validation sequence


def choose_vo_span(model: Any, card: Any, sequences: list[Any], spans: list[int]) -> SpanChoice:
    """The span over which the VO's covariances are made consistent (:func:`pvo_fusion.calibrate_vo`) that lets
    the fusion with ``model``'s corrections lower the m-ATE most on validation ``sequences`` (corpus entries with
    poses): a VO bias grows with the span faster than its frame-to-frame noise, so the span sets how far the
    fusion trusts the VO against the corrections. Two-fold: the scales are learned on every other sequence and
    the fusion measured on the rest, and the other way round. The criterion is the mean of the translation and
    rotation changes."""
    from pvo_core.trajectory import read_kitti_poses

    from pvo_fusion import CalibrationSequence, calibrate_vo

    from .experiments.common import fusion_figures

    if not sequences:
        raise ValueError("choosing the VO span needs at least one validation sequence")
    if not spans or min(spans) < 1:
        raise ValueError(f"VO spans must be positive frame counts, got {spans}")
    prepared = {}
    for sequence in sequences:
        run, _ = vo_run(sequence.root, config=model_vo(card))
        truth = read_kitti_poses(sequence.root / "poses.txt")
        relative = run.relative()
        calibration = CalibrationSequence(sequence.name, truth, relative["transforms"], relative["covariances"])
        prepared[sequence.name] = (sequence, run, truth, calibration)
    names = sorted(prepared)
    folds = [(names[1::2], names[0::2]), (names[0::2], names[1::2])] if len(names) > 1 else [(names, names)]
    changes: dict[int, tuple[float, float]] = {}
    for span in spans:
        trans, rot = [], []
        for train, held in folds:
            calibration = calibrate_vo([prepared[n][3] for n in train], span)
            for name in held:
                sequence, run, truth, _ = prepared[name]
                fused = correct_sequence(sequence.root, model, card, "fusion", calibration, run=run)
                alone, corrected = (
                    fusion_figures(truth, truth[0] @ run.poses),
                    fusion_figures(truth, truth[0] @ fused.corrected_online),
                )
                trans.append(corrected["m_ate_trans"] / max(alone["m_ate_trans"], 1e-12) - 1.0)
                rot.append(corrected["m_ate_rot_deg"] / max(alone["m_ate_rot_deg"], 1e-12) - 1.0)
        changes[span] = (float(np.mean(trans)), float(np.mean(rot)))
    best = min(spans, key=lambda s: sum(changes[s]))
    calibration = calibrate_vo([prepared[n][3] for n in names], best)
    return SpanChoice(best, changes, len(names), len(folds) if len(names) > 1 else 1, calibration)


def card_vo_calibration(card: Any) -> Any:
    """The VO calibration a card carries (`pvo dpc-net calibrate --vo-spans`: per-axis scales at its VO span, learned
    on its validation split), as a :class:`pvo_fusion.VOCalibration`; None when it has none."""
    from pvo_fusion.calibration import VOCalibration

    calibration = card.calibration or {}
    if "vo_scale" not in calibration:
        return None
    scale = np.asarray(calibration["vo_scale"], dtype=float)
    static = np.asarray(calibration.get("vo_static_covariance", np.diag(np.ones(6))), dtype=float)
    if scale.shape != (6,) or not np.all(np.isfinite(scale)) or np.any(scale <= 0.0) or static.shape != (6, 6):
        raise ValueError(f"the model card's vo_scale must be 6 positive numbers (x y z rx ry rz), got {calibration['vo_scale']}")
    return VOCalibration(scale, static, ("model card",))


def card_vo_bias(card: Any) -> float:
    """The corrections over which the fusion learns the VO's translation bias from them (`pvo dpc-net calibrate
    --drives` chose it: ``calibration.vo_bias_windows``; ``inputs.correction.vo_bias_windows`` of the fusion); 0 for
    none, and when the card fuses nothing."""
    calibration = card.calibration or {}
    windows = float(calibration.get("vo_bias_windows") or 0.0)
    if not np.isfinite(windows) or windows < 0.0:
        raise ValueError(f"the model card's vo_bias_windows must be a number of corrections >= 0, got {windows}")
    return windows if calibration.get("fused_axes") else 0.0


def card_vo_fusion(card: Any) -> dict[str, float]:
    """The fusion parameters (flat, ``inputs.correction.*``) with which the VO learns its bias from the card's
    corrections, as `pvo dpc-net calibrate --drives` chose: the translation bias (``vo_bias_windows``), the turns'
    scale (``calibration.vo_rotation_scale``: windows and gain) and the steps' scale
    (``calibration.vo_translation_scale_windows``); {} for none, and when the card fuses nothing. ``ValueError`` naming
    the entry for a malformed one."""
    calibration = card.calibration or {}
    parameters: dict[str, float] = {}
    bias = card_vo_bias(card)
    if bias:
        parameters["inputs.correction.vo_bias_windows"] = bias
    scale = calibration.get("vo_rotation_scale") or {}
    if scale and calibration.get("fused_axes"):
        windows, gain = float(scale.get("windows", 0.0)), float(scale.get("gain", 0.0))
        if not (windows > 0.0 and np.isfinite(gain) and 0.0 < gain <= 1.0):
            raise ValueError(f"the model card's vo_rotation_scale needs windows > 0 and a gain in (0, 1], got {dict(scale)}")
        parameters["inputs.correction.vo_rotation_scale_windows"] = windows
        parameters["inputs.correction.vo_rotation_scale_gain"] = gain
    steps = float(calibration.get("vo_translation_scale_windows") or 0.0)
    if steps and calibration.get("fused_axes"):
        if not (steps > 0.0 and np.isfinite(steps)):
            raise ValueError(f"the model card's vo_translation_scale_windows must be a number of corrections > 0, got {steps}")
        parameters["inputs.correction.vo_translation_scale_windows"] = steps
    return parameters


def describe_vo_fusion(parameters: Mapping[str, float]) -> str:
    """How the fusion debiases the VO with :func:`card_vo_fusion`'s parameters, in words ('' for not at all)."""
    parts = []
    if parameters.get("inputs.correction.vo_bias_windows"):
        parts.append(
            f"the VO's translation bias learned from the corrections (over ~{parameters['inputs.correction.vo_bias_windows']:g})"
        )
    if parameters.get("inputs.correction.vo_rotation_scale_windows"):
        parts.append(
            f"its turns rescaled by {parameters['inputs.correction.vo_rotation_scale_gain']:g} of the scale they teach "
            f"(over ~{parameters['inputs.correction.vo_rotation_scale_windows']:g})"
        )
    steps = parameters.get("inputs.correction.vo_translation_scale_windows")
    if steps:
        parts.append(f"the VO's steps rescaled by the scale the corrections teach (over ~{steps:g})")
    return "; ".join(parts)


#: the fused-axis sets a drive calibration tries, within the model variant's axes; "validated": those the
#: correction improved on the validation windows (``residual.corrected_*``)
AXIS_SETS: dict[str, tuple[str, ...] | None] = {
    "validated": None,
    "all": ("x", "y", "z", "rx", "ry", "rz"),
    "translation": ("x", "y", "z"),
    "rotation": ("rx", "ry", "rz"),
}
#: the numbers of corrections over which a drive calibration's debiased candidates learn the VO's translation bias
#: (stop 64: rule 18 fixed 30, about 9 s of driving at Δp 3 and 10 Hz, before any figure of it; rule 21 a 3x grid
#: around it; both lens and focal cards chose 10 on their sixteen drives)
VO_BIAS_WINDOWS = (10.0, 30.0, 100.0)
#: the gains of the VO's turn scale a drive calibration tries (each a twin of every translation-debiased weighing that
#: fuses rotation), and the scale's time constant (corrections; the validation drives of stop 65 read 100, 1000 and
#: all alike within a point)
VO_ROTATION_SCALE_GAINS = (0.5, 0.75, 1.0)
VO_ROTATION_SCALE_WINDOWS = 1000.0
#: the time constants (corrections) of the VO's step scale a drive calibration tries, each a twin of every weighing
#: that fuses the translation, in place of the additive translation bias (stop 65's prototype: 100 on the focal drives)
VO_TRANSLATION_SCALE_WINDOWS = (100.0,)
#: the VO spans a drive calibration tries by default (frames)
DRIVE_SPANS = (3, 30, 100, 250)
Candidate = TypeVar("Candidate")


def drives_lowered(changes: Any) -> int:
    """How many drives a fusion lowered on both m-ATEs: ``changes`` the relative changes (drives, 2) against the VO."""
    return int(np.all(np.asarray(changes, dtype=float).reshape(-1, 2) < 0.0, axis=1).sum())


HARM_TOLERANCE = 0.05
"""How much a fusion may raise one validation drive's m-ATE (relative, either m-ATE) and still be chosen: the
issue's own "no harm" bound (within 5 %). With 0 every drive must be lowered, the rule until stop 63, which grows
stricter with every drive added and on sixteen lens drives kept a weighing that raised one drive by 86 % over one
whose worst drive rose 3.7 %."""


def fusion_accepted(changes: Any, harm_tolerance: float = HARM_TOLERANCE) -> bool:
    """Whether a fusion may be chosen: both mean m-ATE changes below zero and no drive's change at or above
    ``harm_tolerance`` (0: every drive lowered). ``changes``: relative changes (drives, 2) against the VO alone."""
    if harm_tolerance < 0.0 or not np.isfinite(harm_tolerance):
        raise ValueError(f"the harm tolerance must be a finite fraction >= 0, got {harm_tolerance}")
    values = np.asarray(changes, dtype=float).reshape(-1, 2)
    return bool(len(values)) and bool(np.all(values < harm_tolerance)) and bool(np.all(values.mean(axis=0) < 0.0))


def select_fusion(changes: Mapping[Candidate, Any], harm_tolerance: float = HARM_TOLERANCE) -> Candidate | None:
    """The candidate whose fusion lowered both the translational and the rotational mean m-ATE and raised no drive's
    by ``harm_tolerance`` or more (each value: relative changes (drives, 2) against the VO alone; 0: every drive
    lowered), the lowest mean sum among them; None when none did — then nothing is fused, as a correction that
    harmed one validation drive cannot be told from one that harms a user's."""
    accepted = {key: np.asarray(c, dtype=float) for key, c in changes.items() if fusion_accepted(c, harm_tolerance)}
    if not accepted:
        return None
    return min(accepted, key=lambda key: float(accepted[key].mean(axis=0).sum()))


def worst_change(changes: Any) -> float:
    """The largest relative m-ATE change of any drive on either m-ATE (> 0: that drive was made worse)."""
    values = np.asarray(changes, dtype=float)
    return float(values.max()) if values.size else 0.0


def nearest_fusion(candidates: Mapping[str, Mapping[str, Any]]) -> tuple[str, dict[str, list[float]]] | None:
    """When no candidate lowered every drive: the one that lowered both m-ATEs on the most drives (ties: the lowest
    mean sum), with the drives it did not lower and their changes (translation, rotation) - what a user reads to see
    how near the rule came. ``candidates``: :attr:`FusionChoice.candidates`. None without candidates."""
    if not candidates:
        return None

    def lowered(candidate: Mapping[str, Any]) -> int:
        return drives_lowered(list(candidate["per_drive"].values()))

    label = max(candidates, key=lambda key: (lowered(candidates[key]), -sum(candidates[key]["mean"])))
    worse = {drive: list(c) for drive, c in candidates[label]["per_drive"].items() if not all(v < 0.0 for v in c)}
    return label, worse


def describe_nearest(candidates: Mapping[str, Mapping[str, Any]]) -> str | None:
    """One line on :func:`nearest_fusion`: the candidate, how many drives it lowered, the others' changes (%)."""
    nearest = nearest_fusion(candidates)
    if nearest is None:
        return None
    label, worse = nearest
    total = len(candidates[label]["per_drive"])
    drives = ", ".join(f"{drive} {100 * c[0]:+.1f} / {100 * c[1]:+.1f} %" for drive, c in worse.items())
    return (
        f"nearest: {label}, {total - len(worse)} of {total} drives lowered; not lowered (m-ATE translation / rotation): {drives}"
    )


@dataclass
class FusionChoice:
    """How the corrections are fused, chosen on long validation drives: ``span`` (frames over which the VO's
    covariances are made consistent) and ``axes`` (the fused ones; [] when no candidate was acceptable to
    :func:`select_fusion`, and ``span`` None); ``candidates``: per candidate label its span, axes, per-drive changes
    (m-ATE translation, rotation), the worst of them and whether it was acceptable; ``vo_calibration``: the VO's
    scales at ``span`` learned on every drive (None when nothing is fused)."""

    span: int | None
    axes: list[str]
    candidates: dict[str, dict[str, Any]]
    drives: list[str]
    vo_calibration: Any = None
    remove_mean: bool = False
    correction_scale: list[float] | None = None
    vo_bias_windows: float = 0.0
    vo_rotation_scale_gain: float = 0.0
    vo_translation_scale_windows: float = 0.0


def choose_fusion(
    model: Any,
    card: Any,
    drives: Sequence[Path],
    spans: Sequence[int] = DRIVE_SPANS,
    say: Any = None,
    harm_tolerance: float = HARM_TOLERANCE,
    consistent_corrections: bool = False,
    vo_bias_windows: float | Sequence[float] = VO_BIAS_WINDOWS,
    vo_rotation_scale_gains: float | Sequence[float] = VO_ROTATION_SCALE_GAINS,
    vo_translation_scale_windows: float | Sequence[float] = VO_TRANSLATION_SCALE_WINDOWS,
) -> FusionChoice:
    """The VO span and the fused axes (:data:`AXIS_SETS` x ``spans``, each with the corrections as predicted and
    with their validation-split mean error removed, :func:`~pvo_pseudosensors.dpc_net.infer.remove_residual_mean`)
    for ``model``'s corrections, chosen on long validation ``drives`` (sequence directories with poses.txt, of the
    model's rig) by :func:`select_fusion` with ``harm_tolerance``. The VO's scales for a drive are learned on the
    other drives (leave one drive out; in sample with one drive), so no drive judges a weighing learned on itself.
    ``consistent_corrections``: for every span longer than the card's Δp each weighing is tried again with the
    corrections' covariance made consistent over the same span (:func:`correction_calibration`, learned on the other
    drives too), so the VO chain and the corrected chain are weighed by how far each drifts over that span.
    ``vo_bias_windows`` (one number of corrections or several; 0 = none): every weighing that fuses the translation
    is tried again, once per number, with the VO's translation bias learned from the corrections over that many as
    the fusion does (``inputs.correction.vo_bias_windows``, :class:`pvo_fusion.VOBiasTracker`), the VO's scales then
    learned on the VO so debiased. ``vo_rotation_scale_gains`` (0 = none): each such weighing that fuses rotation is
    tried again once per gain with the VO's turns rescaled too (``inputs.correction.vo_rotation_scale_*``, time
    constant :data:`VO_ROTATION_SCALE_WINDOWS`). ``vo_translation_scale_windows`` (0 = none): each weighing that fuses
    the translation is tried once per number with the VO's steps rescaled by the scale the corrections teach over about
    that many of them (``inputs.correction.vo_translation_scale_windows``) instead of its translation bias."""
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.infer import (
        AXES,
        corrected_covariance,
        measurement_covariance,
        predict_corrections,
        remove_residual_mean,
    )
    from pvo_pseudosensors.dpc_net.rig import check_rig

    from pvo_fusion import CalibrationSequence, calibrate_vo, debiased_motions

    from .experiments.common import fusion_figures

    if not drives:
        raise ValueError("choosing the fusion needs at least one validation drive")
    fusion_accepted([], harm_tolerance)  # a wrong tolerance fails here, before any drive is run
    windows_tried = sorted(
        {float(w) for w in ([vo_bias_windows] if np.isscalar(vo_bias_windows) else vo_bias_windows) if float(w) > 0.0}
    )
    if any(not np.isfinite(w) for w in windows_tried):
        raise ValueError(f"the VO bias's numbers of corrections must be finite, got {vo_bias_windows}")
    gains_given = [vo_rotation_scale_gains] if np.isscalar(vo_rotation_scale_gains) else list(vo_rotation_scale_gains)
    gains_tried = sorted({float(g) for g in gains_given if float(g) != 0.0})
    if any(not (0.0 < g <= 1.0) for g in gains_tried):
        raise ValueError(f"the VO turn scale's gains must be in (0, 1] (0: none), got {vo_rotation_scale_gains}")
    steps_given = (
        [vo_translation_scale_windows] if np.isscalar(vo_translation_scale_windows) else list(vo_translation_scale_windows)
    )
    steps_tried = sorted({float(w) for w in steps_given if float(w) != 0.0})
    if any(not (0.0 < w < np.inf) for w in steps_tried):
        raise ValueError(f"the VO step scale's numbers of corrections must be finite and > 0, got {vo_translation_scale_windows}")
    if not spans or min(spans) < 1:
        raise ValueError(f"VO spans must be positive frame counts, got {list(spans)}")
    variant_axes = {"pose": AXES, "rotation": AXES[3:], "yaw": ("ry",)}[DPCNetConfig.from_card(card).variant]
    residual = (card.calibration or {}).get("residual") or {}
    axis_sets: dict[str, tuple[str, ...]] = {}
    for name, axes in AXIS_SETS.items():
        chosen = tuple(a for a in variant_axes if (residual.get(f"corrected_{a}", 1.0) if axes is None else a in axes))
        if chosen and chosen not in axis_sets.values():
            axis_sets[name] = chosen
    prepared = {}
    for root in drives:
        root = Path(root)
        if root.name in prepared:
            raise ValueError(
                f"two validation drives are named {root.name!r} ({prepared[root.name][0]} and {root}): one rig's drives"
            )
        for warning in check_rig(card.input.get("rig"), root):
            (say or print)(f"  warning: {root}: {warning}")
        run, _ = vo_run(root, config=model_vo(card))
        truth = read_kitti_poses(root / "poses.txt")
        relative = run.relative()
        alone = fusion_figures(truth, truth[0] @ run.poses)
        sequence = CalibrationSequence(root.name, truth, relative["transforms"], relative["covariances"])
        # the network's corrections do not depend on how they are weighed: predicted once (as the network gives
        # them), reweighed per candidate
        as_predicted = copy.deepcopy(card)
        as_predicted.calibration["remove_mean"] = False
        prepared[root.name] = (root, run, truth, alone, sequence, predict_corrections(model, as_predicted, root, run.poses))
    names = list(prepared)
    means = (False, True) if (card.calibration or {}).get("residual") else (False,)
    delta = DPCNetConfig.from_card(card).test_delta
    labels = [(label, mean) for mean in means for label in axis_sets]
    # (span, axis set, mean removed, corrections consistent over the span, VO bias windows, VO turn scale gain, VO step
    # scale windows) -> per-drive changes
    changes: dict[tuple[int, str, bool, bool, float, float, float], Array] = {}

    def named(
        axes_label: str, remove_mean: bool, consistent: bool = False, bias: float = 0.0, gain: float = 0.0, steps: float = 0.0
    ) -> str:
        return (
            axes_label
            + (", mean removed" if remove_mean else "")
            + (", corrections over the span" if consistent else "")
            + (f", VO debiased over {bias:g}" if bias else "")
            + (f", turns rescaled x{gain:g}" if gain else "")
            + (f", steps rescaled over {steps:g}" if steps else "")
        )

    def weighing(axes_label: str, remove_mean: bool, bias: float = 0.0, gain: float = 0.0, steps: float = 0.0) -> Any:
        candidate = copy.deepcopy(card)
        candidate.calibration["fused_axes"] = list(axis_sets[axes_label])
        candidate.calibration["remove_mean"] = remove_mean
        candidate.calibration.pop("correction_scale", None)
        candidate.calibration.pop("vo_bias_windows", None)
        candidate.calibration.pop("vo_rotation_scale", None)
        candidate.calibration.pop("vo_translation_scale_windows", None)
        if steps:
            candidate.calibration["vo_translation_scale_windows"] = steps
        if bias:
            candidate.calibration["vo_bias_windows"] = bias
        if gain:
            candidate.calibration["vo_rotation_scale"] = {"windows": VO_ROTATION_SCALE_WINDOWS, "gain": gain}
        return candidate

    debiased: dict[tuple[str, bool, float, float, float], Any] = {}

    def debiased_sequence(name: str, remove_mean: bool, windows: float, gain: float = 0.0, steps: float = 0.0) -> Any:
        # the VO as the fusion takes it once the corrections (as weighed: the mean removed or not) taught its bias
        if (name, remove_mean, windows, gain, steps) not in debiased:
            _, _, truth, _, sequence, predicted = prepared[name]
            weighed = remove_residual_mean(predicted.transforms, {**card.calibration, "remove_mean": remove_mean})
            motions = debiased_motions(
                sequence.motions,
                predicted.first,
                predicted.last,
                weighed,
                windows,
                rotation_scale_windows=VO_ROTATION_SCALE_WINDOWS if gain else 0.0,
                rotation_scale_gain=gain or 1.0,
                translation_scale_windows=steps,
            )
            key = (name, remove_mean, windows, gain, steps)
            debiased[key] = CalibrationSequence(name, truth, motions, sequence.covariances)
        return debiased[(name, remove_mean, windows, gain, steps)]

    debiased_scale_sets: dict[tuple[int, bool, float, float, float], dict[str, Any]] = {}

    def debiased_scales(span: int, remove_mean: bool, windows: float, gain: float = 0.0, steps: float = 0.0) -> dict[str, Any]:
        # per drive, the debiased VO's scales learned on the other drives: the same for every axis set
        key = (span, remove_mean, windows, gain, steps)
        if key not in debiased_scale_sets:
            debiased_scale_sets[key] = {
                name: calibrate_vo(
                    [debiased_sequence(o, remove_mean, windows, gain, steps) for o in names if o != name]
                    or [debiased_sequence(name, remove_mean, windows, gain, steps)],
                    span,
                )
                for name in names
            }
        return debiased_scale_sets[key]

    def translation_fused(axes_label: str) -> bool:
        return {"x", "y", "z"} <= set(axis_sets[axes_label])

    def rotation_fused(axes_label: str) -> bool:
        return bool({"rx", "ry", "rz"} & set(axis_sets[axes_label]))

    chains: dict[tuple[str, bool], Any] = {}
    correction_scales: dict[tuple[int, bool, str], list[float]] = {}

    def corrected_chain(name: str, candidate: Any) -> Any:
        # every axis's own spread, not the unmeasured variance the fusion gives an axis it does not take: that one
        # would leak into the measured axes as the chain's covariance is carried over the span. The chain depends on
        # the mean removal only (not on the fused axes), so it is made once per drive and mean removal.
        key = (name, bool(candidate.calibration.get("remove_mean")))
        if key not in chains:
            _, _, truth, _, _, predicted = prepared[name]
            transforms = remove_residual_mean(predicted.transforms, candidate.calibration)
            chains[key] = correction_sequence(name, truth, predicted, transforms, corrected_covariance(candidate.calibration))
        return chains[key]

    def held_out_correction_scale(name: str, span: int, candidate: Any) -> list[float]:
        # learned on the other drives, as the VO's scales are; the same for every axis set of a span and mean removal
        key = (span, bool(candidate.calibration.get("remove_mean")), name)
        if key not in correction_scales:
            others = [corrected_chain(o, candidate) for o in names if o != name] or [corrected_chain(name, candidate)]
            correction_scales[key] = correction_calibration(others, span, delta)
        return correction_scales[key]

    for span in spans:
        scales = {name: calibrate_vo([prepared[o][4] for o in names if o != name] or [prepared[name][4]], span) for name in names}
        tried = [(label, mean, False, 0.0, 0.0, 0.0) for label, mean in labels]
        if consistent_corrections and span > delta:
            tried += [(label, mean, True, 0.0, 0.0, 0.0) for label, mean in labels]
        for windows in windows_tried:
            tried += [(label, mean, False, windows, 0.0, 0.0) for label, mean in labels if translation_fused(label)]
            for gain in gains_tried:
                tried += [
                    (label, mean, False, windows, gain, 0.0)
                    for label, mean in labels
                    if translation_fused(label) and rotation_fused(label)
                ]
        for steps in steps_tried:
            tried += [(label, mean, False, 0.0, 0.0, steps) for label, mean in labels if translation_fused(label)]
        for axes_label, remove_mean, consistent, bias, gain, steps in tried:
            candidate = weighing(axes_label, remove_mean, bias, gain, steps)
            drive_scales = debiased_scales(span, remove_mean, bias, gain, steps) if bias or steps else scales
            covariance = measurement_covariance(DPCNetConfig.from_card(candidate), candidate.calibration)
            rows = []
            for name in names:
                root, run, truth, alone, _, predicted = prepared[name]
                drive_covariance = covariance
                if consistent:
                    drive_card = copy.deepcopy(candidate)
                    drive_card.calibration["correction_scale"] = held_out_correction_scale(name, span, candidate)
                    drive_covariance = measurement_covariance(DPCNetConfig.from_card(drive_card), drive_card.calibration)
                weighed = replace(
                    predicted,
                    transforms=remove_residual_mean(predicted.transforms, candidate.calibration),
                    covariances=np.broadcast_to(drive_covariance, predicted.covariances.shape).copy(),
                )
                fused = correct_sequence(root, model, candidate, "fusion", drive_scales[name], run=run, corrections=weighed)
                figures = fusion_figures(truth, truth[0] @ fused.corrected_online)
                rows.append(
                    [
                        figures["m_ate_trans"] / max(alone["m_ate_trans"], 1e-12) - 1.0,
                        figures["m_ate_rot_deg"] / max(alone["m_ate_rot_deg"], 1e-12) - 1.0,
                    ]
                )
            changes[(span, axes_label, remove_mean, consistent, bias, gain, steps)] = np.asarray(rows)
            if say is not None:
                drive_changes = changes[(span, axes_label, remove_mean, consistent, bias, gain, steps)]
                mean = 100 * drive_changes.mean(axis=0)
                say(
                    f"  span {span:4d}, {named(axes_label, remove_mean, consistent, bias, gain, steps):<25} axes: "
                    f"m-ATE {mean[0]:+6.1f} % translation, "
                    f"{mean[1]:+6.1f} % rotation; {drives_lowered(drive_changes)} of {len(names)} drives lowered, "
                    f"worst {100 * worst_change(drive_changes):+.1f} %"
                )
    best = select_fusion(changes, harm_tolerance)
    candidates = {
        f"span {span}, {named(axes_label, remove_mean, consistent, bias, gain, steps)}": {
            "span": span,
            "axes": list(axis_sets[axes_label]),
            "remove_mean": remove_mean,
            **({"corrections_over_span": True} if consistent else {}),
            **({"vo_bias_windows": bias} if bias else {}),
            **({"vo_rotation_scale_gain": gain} if gain else {}),
            **({"vo_translation_scale_windows": steps} if steps else {}),
            "per_drive": {name: [round(float(v), 4) for v in row] for name, row in zip(names, c, strict=True)},
            "mean": [round(float(v), 4) for v in c.mean(axis=0)],
            "worst": round(worst_change(c), 4),
            "accepted": fusion_accepted(c, harm_tolerance),
        }
        for (span, axes_label, remove_mean, consistent, bias, gain, steps), c in changes.items()
    }
    if best is None:
        return FusionChoice(None, [], candidates, names)
    span, axes_label, remove_mean, consistent, bias, gain, steps = best
    if bias or steps:
        calibration = calibrate_vo([debiased_sequence(n, remove_mean, bias, gain, steps) for n in names], span)
    else:
        calibration = calibrate_vo([prepared[n][4] for n in names], span)
    correction_scale = None
    if consistent:
        chosen = weighing(axes_label, remove_mean)
        correction_scale = correction_calibration([corrected_chain(n, chosen) for n in names], span, delta)
    return FusionChoice(
        span, list(axis_sets[axes_label]), candidates, names, calibration, remove_mean, correction_scale, bias, gain, steps
    )


def correction_sequence(name: str, truth: Array, predicted: Any, transforms: Array, covariance: Array) -> Any:
    """The corrected chain of one drive as a :class:`pvo_fusion.CalibrationSequence`: the truth at the windows'
    boundaries (consecutive windows 0 → Δp → 2Δp ...), the corrected transforms T_last,first (N, 4, 4) as its
    motions and ``covariance`` (6, 6, ROS order) as each one's."""
    from pvo_fusion import CalibrationSequence

    boundaries = np.concatenate([predicted.first[:1], predicted.last]).astype(int)
    return CalibrationSequence(name, truth[boundaries], transforms, np.broadcast_to(covariance, (len(transforms), 6, 6)).copy())


def correction_calibration(chains: Sequence[Any], span: int, delta: int) -> list[float]:
    """Per-axis variance scales (ROS order) that make the corrected chains (:func:`correction_sequence`) consistent
    over ``span`` frames (span // Δp windows): the VO's calibration (:func:`pvo_fusion.calibrate_vo`) applied to the
    corrections. Axes the corrections do not measure come out near 0; :func:`measurement_covariance` keeps them
    unmeasured whatever their scale."""
    from pvo_fusion import calibrate_vo

    scale = np.asarray(calibrate_vo(chains, max(1, span // delta)).scale, dtype=float)
    return [float(v) for v in np.maximum(scale, 1e-6)]
