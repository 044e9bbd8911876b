"""VO covariance calibration against ground truth (the sun experiment's leave-one-out scheme).

Raw VO covariances are overconfident (viso2-s: ANEES 5-20 per dof). A calibration learns, on training
sequences, per-dof variance scales (ROS order x y z rotX rotY rotZ) that make the VO consistent over
``span``-frame motions — the span between two sun measurements: over one frame KITTI's ground-truth
noise rivals the VO error, over the span the VO's drift dominates, and that drift is what the fusion
must weigh. ``scale_i = mean_k(e_k,i^2 / Sigma_k,ii)``, ``Sigma_k`` the per-frame covariances carried
through the span (each left perturbation by the adjoint). For VO without covariances it learns a static
per-frame covariance ``diag(mean_k e_k,i^2) / span``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import se3_adjoint, se3_inverse, se3_log

from .measurements import RelativeMeasurement

Array = NDArray[np.float64]


@dataclass(frozen=True)
class VOCalibration:
    """Per-dof variance scales (ROS order) for VO with covariances, a static covariance for VO without."""

    scale: Array
    static_covariance: Array
    trained_on: tuple[str, ...]


@dataclass(frozen=True)
class CalibrationSequence:
    """What a calibration learns from: ground truth T_map,k (N, 4, 4), VO motions T_k,k-1 (N-1, 4, 4) and
    their covariances (N-1, 6, 6) or None."""

    name: str
    ground_truth: Array
    motions: Array
    covariances: Array | None


def span_errors(seq: CalibrationSequence, span: int) -> tuple[Array, Array | None]:
    """Left errors (ROS order) of the VO's composite motions T_k,k-span against ground truth, and their
    first-order covariances from the per-frame ones (None without covariances)."""
    motions, covs = seq.motions, seq.covariances
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


def calibrate_vo(train: Iterable[CalibrationSequence], span: int) -> VOCalibration:
    """Variance scales that make the VO consistent over ``span``-frame motions on the training sequences."""
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


#: The six axes of a VO motion, ROS order (translation m, rotation rad), as tables name them.
AXES = ("x", "y", "z", "rx", "ry", "rz")
#: Bins of σ/ρ for `sigma_consistency` (ρ: the quantile of each axis's σ), from 0 to infinity.
CONSISTENCY_EDGES = (0.0, 0.5, 0.8, 1.0, 1.5, 2.5, 5.0, np.inf)


@dataclass(frozen=True)
class SigmaConsistency:
    """How consistent a VO's frame-to-frame covariance is against its own size, per ROS-order axis (x y z rotX rotY
    rotZ): ``reference`` (6,) ρ, the ``quantile`` of each axis's σ (m, rad); ``edges`` (B+1,) of σ/ρ; ``mean_nees`` (6, B)
    the mean e²/σ² of the pairs whose σ/ρ falls in each bin (NaN where none do); ``counts`` (6, B) those pairs.

    A calibrated VO reads 1 in every bin. A scale per axis (`calibrate_vo`) makes their average 1 and leaves the
    shape: where a VO's error grows faster than the σ it reports (it fails where it is unsure), the high bins read
    far above 1."""

    reference: Array
    quantile: float
    edges: Array
    mean_nees: Array
    counts: NDArray[np.int64]


def sigma_consistency(
    sequences: Iterable[CalibrationSequence],
    scale: Array | None = None,
    quantile: float = 0.9,
    edges: tuple[float, ...] = CONSISTENCY_EDGES,
    lost_variance: float = 1000.0,
) -> SigmaConsistency:
    """`SigmaConsistency` of the VO's frame-to-frame motions on ``sequences``, its covariances times ``scale`` (6,)
    (the fusion's ``inputs.vo.covariance_scale``; None: as read). Motions with a variance of ``lost_variance`` or
    more (a lost frame: no information) are left out."""
    factor = np.ones(6) if scale is None else np.asarray(scale, dtype=float)
    if factor.shape != (6,) or not np.all(factor > 0.0):
        raise ValueError(f"scale must be 6 positive variance scales, got {scale!r}")
    if not 0.0 < quantile < 1.0 or len(edges) < 2 or np.any(np.diff(edges) <= 0.0) or edges[0] != 0.0 or edges[-1] != np.inf:
        raise ValueError("sigma_consistency needs a quantile in (0, 1) and bin edges increasing from 0 to inf")
    errors, variances = [], []
    for seq in sequences:
        if seq.covariances is None:
            raise ValueError(f"{seq.name}: the VO carries no covariances to check")
        e, propagated = span_errors(seq, 1)
        diagonal = np.diagonal(propagated, axis1=1, axis2=2)
        kept = diagonal.max(axis=1) < lost_variance
        errors.append(e[kept])
        variances.append(diagonal[kept] * factor)
    if not errors or not sum(len(e) for e in errors):
        raise ValueError("sigma_consistency needs at least one motion that was not lost")
    e, variance = np.concatenate(errors), np.concatenate(variances)
    sigma = np.sqrt(variance)
    reference = np.quantile(sigma, quantile, axis=0)
    bins = np.digitize(sigma / reference, np.asarray(edges, dtype=float)[1:-1])
    nees = e**2 / variance
    counts = np.zeros((6, len(edges) - 1), dtype=np.int64)
    means = np.full((6, len(edges) - 1), np.nan)
    for axis in range(6):
        counts[axis] = np.bincount(bins[:, axis], minlength=len(edges) - 1)
        sums = np.bincount(bins[:, axis], weights=nees[:, axis], minlength=len(edges) - 1)
        filled = counts[axis] > 0
        means[axis, filled] = sums[filled] / counts[axis, filled]
    return SigmaConsistency(reference, quantile, np.asarray(edges, dtype=float), means, counts)


def calibrated_covariances(covariances: Array | None, frames: int, calibration: VOCalibration | None) -> Array:
    """Per-frame VO covariances (frames, 6, 6): scaled per dof, or the static one when the VO has none."""
    if covariances is not None:
        if calibration is None:
            return np.asarray(covariances, dtype=float)
        s = np.sqrt(calibration.scale)
        return covariances * np.outer(s, s)
    if calibration is None:
        raise ValueError("VO without covariances needs a calibration (its static covariance)")
    return np.broadcast_to(calibration.static_covariance, (frames, 6, 6))


def vo_measurements(
    stamps: NDArray[np.int64], motions: Array, covariances: Array | None, calibration: VOCalibration | None
) -> list[RelativeMeasurement]:
    """One RelativeMeasurement T_k,k-1 per frame k >= 1 (covariances calibrated when a calibration is given)."""
    covs = calibrated_covariances(covariances, len(motions), calibration)
    return [RelativeMeasurement(int(stamps[k + 1]), int(stamps[k]), motions[k], np.array(covs[k])) for k in range(len(motions))]
