"""PROBE training data from image sequences: the stereo VO runs over a KITTI-layout sequence and every frame's
tracked features (reference and current observations, with their predictors) are kept with the VO's motion and,
when the sequence has poses, the true one; then a model is trained on them (with ground truth or by EM)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.lie import se3_inverse
from pvo_core.readers import KittiSequence

from ..vo import StereoVO, VOConfig
from ..vo.config import default_feature_covariance
from ..vo.features import StereoFeatures
from ..vo.pipeline import FeatureNoiseEstimate
from .gk import GKConfig, GKModel
from .knn import KNNConfig, KNNModel, train_knn
from .model import ProbeModel, imu_magnitudes
from .predictors import PredictorConfig, compute_predictors
from .training import FramePair, train_expectation_maximisation, train_with_ground_truth

Array = NDArray[np.float64]


class FeatureRecorder:
    """A VO noise hook that keeps what PROBE trains on - each frame's tracked features with their predictors -
    and gives the VO its default noise, so the run is the plain VO's."""

    def __init__(self, predictors: PredictorConfig, default_covariance: Array) -> None:
        self.predictors = predictors
        self.default_covariance = default_covariance
        self.pairs: list[FramePair] = []

    def __call__(
        self, before: StereoFeatures, after: StereoFeatures, image: NDArray[np.uint8], imu: Array | None = None
    ) -> FeatureNoiseEstimate:
        reference = before.observations()
        magnitudes = imu_magnitudes(imu)
        phi = compute_predictors(self.predictors, before.left, after.left, image, magnitudes, reference[:, 2])
        self.pairs.append(FramePair(reference, after.observations(), phi))
        return FeatureNoiseEstimate(np.broadcast_to(self.default_covariance, (len(after), 3, 3)))


@dataclass
class SequenceData:
    """Frame pairs of one sequence with the VO's motions T_cur,ref and the true ones (None without poses)."""

    name: str
    pairs: list[FramePair] = field(default_factory=list)
    vo_motions: list[Array] = field(default_factory=list)
    true_motions: list[Array] | None = None


def collect(
    sequence: KittiSequence, vo_config: VOConfig, predictors: PredictorConfig, name: str = "", imu: Array | None = None
) -> SequenceData:
    """Run the VO (without PROBE) over ``sequence``, keeping every frame pair it tracked and solved; ``imu``:
    the IMU reading per frame (N, 6) [wx, wy, wz, fx, fy, fz], needed when the predictors use the IMU."""
    if predictors.imu and imu is None:
        raise ValueError(f"{name or sequence.root}: the IMU predictors need an IMU reading per frame (imu.csv)")
    config = replace(vo_config, probe=replace(vo_config.probe, model=""))
    recorder = FeatureRecorder(predictors, default_feature_covariance(config.solver))
    vo = StereoVO(sequence.camera(), config, feature_noise=recorder)
    poses = sequence.poses
    data = SequenceData(name or str(sequence.root), true_motions=[] if poses is not None else None)
    previous_frame = None
    for i in range(len(sequence)):
        left, right = sequence.load_pair(i)
        before = len(recorder.pairs)
        result = vo.process(left, right, float(sequence.stamps[i]), None if imu is None else imu[i])
        if len(recorder.pairs) > before:
            pair = recorder.pairs.pop()
            if result.transform is not None and previous_frame is not None:
                data.pairs.append(pair)
                data.vo_motions.append(result.transform)
                if data.true_motions is not None and poses is not None:
                    data.true_motions.append(se3_inverse(poses[i]) @ poses[previous_frame])
        previous_frame = i
    return data


def train_on_sequences(
    data: Sequence[SequenceData],
    camera_of: Callable[[SequenceData], StereoCamera],
    predictors: PredictorConfig,
    kind: str = "gk",
    em: bool = False,
    em_iterations: int = 5,
    gk: GKConfig | None = None,
    knn: KNNConfig | None = None,
    nominal_sigma: tuple[float, float, float] = (1.0, 1.0, 2.0),
    say: Callable[[str], None] | None = None,
    training: dict[str, Any] | None = None,
) -> ProbeModel:
    """A PROBE model from the frame pairs of ``data``: with the true motions (Algorithm 1 / 6) or, with ``em``,
    from the VO's motions by EM (Algorithm 3, GK only; each sequence with its own camera, the converged
    samples pooled). ``camera_of`` gives each sequence's StereoCamera."""
    if kind not in ("gk", "knn"):
        raise ValueError(f"PROBE model kind must be gk or knn, got {kind!r}")
    if em and kind == "knn":
        raise ValueError("PROBE k-NN trains with ground truth only (--em is for PROBE-GK)")
    used = [d for d in data if d.pairs]
    if not used:
        raise ValueError("no frame pair to train PROBE on (every sequence lost tracking?)")
    names = predictors.names
    record = dict(training or {})
    record.update(pairs=sum(len(d.pairs) for d in used), features=sum(len(p) for d in used for p in d.pairs))
    estimator: GKModel | KNNModel
    if kind == "knn":
        parts = [train_knn(camera_of(d), d.pairs, _truth(d), names, nominal_sigma, knn) for d in used]
        errors_knn = np.concatenate([m.errors for m in parts])
        estimator = KNNModel(names, np.vstack([m.predictors for m in parts]), errors_knn, knn or KNNConfig())
    else:
        stored = []
        for d in used:
            if em:
                result = train_expectation_maximisation(camera_of(d), d.pairs, d.vo_motions, names, gk, em_iterations, say=say)
                record.setdefault("em_log_likelihood", {})[d.name] = [round(v, 3) for v in result.log_likelihood]
                stored.append(result.model)
            else:
                stored.append(train_with_ground_truth(camera_of(d), d.pairs, _truth(d), names, gk))
        estimator = GKModel(
            names, np.vstack([m.predictors for m in stored]), np.vstack([m.errors for m in stored]), gk or GKConfig()
        )
    if say:
        say(f"PROBE {kind}{' (EM)' if em else ''}: {len(estimator.errors)} stored samples from {record['pairs']} frame pairs")
    return ProbeModel(kind, predictors, estimator, record, nominal_sigma)


def _truth(d: SequenceData) -> list[Array]:
    if d.true_motions is None:
        raise ValueError(f"{d.name}: no poses to train with ground truth (give --em to train without)")
    return d.true_motions
