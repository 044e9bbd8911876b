"""DPC-Net's corrections applied to this project's stereo VO on one sequence (no I/O beyond reading it).

Two ways to apply them: ``fusion`` — the VO's frame-to-frame transforms and the corrected Δp-frame transforms
as factors of the fixed-lag smoother (:class:`pvo_fusion.FusionGraph`), the pose-graph relaxation of thesis
§6.4.5; ``overwrite`` — the authors' shipped code: every Δp-th pose overwritten by the corrected transform, the
VO chained in between (:func:`pvo_pseudosensors.dpc_net.infer.overwrite_trajectory`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
FIRST_STAMP_NS = 1_000_000_000  # the fusion's stamps start at 1 s (a zero stamp reads as unset in ROS)
METHODS = ("fusion", "overwrite")


@dataclass
class CorrectedSequence:
    """vo: the VO's camera-to-odom poses (N, 4, 4); corrected: after the corrections, online (the newest state
    as the fusion node publishes it; the overwrite is causal, so both are the same there) and smoothed (after
    the fixed lag); corrections: what the model predicted; accepted: corrections the fusion took; warnings: the
    model card's rig check (what could not be verified)."""

    vo: Array
    corrected: Array
    corrected_online: Array
    corrections: Any
    accepted: int
    warnings: list[str] = field(default_factory=list)


def rig_sequences(manifest: Any, card: Any, split: str = "validation") -> list[Any]:
    """The sequences of ``split`` of a corpus manifest that are the model's rig: its presets (the card's), none of
    another camera (the conditions DPC-Net's training leaves out, ``ModelEntry.off_rig``)."""
    from pvo_pseudosensors.registry import models

    off_rig = set(models()["dpc-net"].off_rig)
    presets = set((card.corpus or {}).get("presets") or [])
    return [s for s in manifest.split(split) if not set(s.conditions) & off_rig and (not presets or s.preset in presets)]


def vo_run(root: Path, rate_hz: float = 10.0) -> Any:
    """This project's stereo VO (default settings) over the KITTI-layout sequence at ``root``."""
    from pvo_core.readers import KittiSequence
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig

    sequence = KittiSequence(root, rate_hz=None if (Path(root) / "times.txt").is_file() else rate_hz)
    return run_sequence(sequence, VOConfig()), sequence


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
) -> CorrectedSequence:
    """The VO of the sequence at ``root`` (``run``: a `run_sequence` result already made, else it is run) with
    ``model``'s corrections applied by ``method``. ``vo_calibration``: per-axis scales of the VO's covariances
    (:func:`pvo_fusion.calibrate_vo`), None for the VO's own. The model's rig is checked first
    (:func:`pvo_pseudosensors.dpc_net.rig.check_rig`: ``ValueError`` on another rig unless ``allow_any_rig``)."""
    from pvo_pseudosensors.dpc_net.infer import overwrite_trajectory, predict_corrections
    from pvo_pseudosensors.dpc_net.rig import check_rig

    from pvo_fusion import FusionGraph, RelativeMeasurement, ordered_events, run_offline, vo_measurements
    from pvo_fusion.config import from_flat

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    warnings = check_rig(card.input.get("rig"), root, allow_any_rig)
    sequence = None
    if run is None:
        run, sequence = vo_run(root, rate_hz)
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
    graph = FusionGraph(from_flat({"prior.source": "given"}))
    graph.set_initial_pose(np.eye(4))
    fused = run_offline(graph, stamps, ordered_events(vo, others))
    accepted = int(fused.counts.get("correction.accepted", 0))
    return CorrectedSequence(run.poses, fused.poses, fused.online_poses, corrections, accepted, warnings)


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
        run, _ = vo_run(sequence.root)
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
