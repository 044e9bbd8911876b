"""Isotropic PROBE by k nearest neighbours (thesis app. A, the IROS'15 method).

Training (Algorithm 6) traverses the path ``subsets`` times; each time every frame's features are shuffled
into disjoint subsets, the motion is solved from each subset alone, and the translational error of that
motion against the truth is stored at every predictor of the subset. At test time each feature's nominal
covariance is scaled by

    beta(phi) = ( mean of the K stored errors nearest phi / mean of all stored errors )^gamma      (eq. A.6)

and features with beta above ``max_weight`` are dropped (the code's ``maxProbeWeight``). The thesis's code
used K = 100, gamma = 8 at test, max weight 100 (thesis-code-facts §3.1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera

from ..vo.solver import RobustLoss
from .gk import PredictorSpace, predictor_columns
from .training import FramePair, solve_pair

Array = NDArray[np.float64]


@dataclass(frozen=True)
class KNNConfig:
    """neighbours: K; gamma: the exponent of eq. A.6; max_weight: features with a larger beta are dropped;
    subsets: disjoint feature subsets per frame in training (the code's repeatIter); min_subset: fewest
    features a subset is solved with."""

    neighbours: int = 100
    gamma: float = 8.0
    max_weight: float = 100.0
    subsets: int = 10
    min_subset: int = 6

    def __post_init__(self) -> None:
        if self.neighbours < 1:
            raise ValueError(f"PROBE k-NN neighbours must be >= 1, got {self.neighbours}")
        if not self.gamma > 0.0:
            raise ValueError(f"PROBE k-NN gamma must be positive, got {self.gamma}")
        if not self.max_weight > 1.0:
            raise ValueError(f"PROBE k-NN max_weight must be > 1, got {self.max_weight}")
        if self.subsets < 1 or self.min_subset < 3:
            raise ValueError(f"PROBE k-NN needs subsets >= 1 and min_subset >= 3, got {self.subsets}, {self.min_subset}")


@dataclass
class KNNModel:
    """Stored egomotion errors (M,) m at predictors (M, p), normalised by the training mean and std."""

    names: tuple[str, ...]
    predictors: Array
    errors: Array
    config: KNNConfig = field(default_factory=KNNConfig)
    mean: Array | None = None
    std: Array | None = None

    def __post_init__(self) -> None:
        self.predictors = np.asarray(self.predictors, dtype=float)
        self.errors = np.asarray(self.errors, dtype=float).reshape(-1)
        space = PredictorSpace.fit(self.names, self.predictors, self.mean, self.std)
        if len(self.errors) != len(self.predictors) or len(self.errors) == 0:
            raise ValueError(f"need one error per stored predictor (at least one): {len(self.errors)} for {len(self.predictors)}")
        if not (np.all(np.isfinite(self.errors)) and np.all(self.errors >= 0.0)):
            raise ValueError("PROBE k-NN training errors must be finite and non-negative")
        self.mean, self.std, self._space = space.mean, space.std, space
        assert space.tree is not None
        self._tree = space.tree
        self.average_error = float(self.errors.mean())

    def marginal(self, names: tuple[str, ...]) -> KNNModel:
        """The same stored errors indexed by the predictors ``names`` only (see :meth:`GKModel.marginal`)."""
        columns = predictor_columns(self.names, names)
        assert self.mean is not None and self.std is not None
        return KNNModel(names, self.predictors[:, columns], self.errors, self.config, self.mean[columns], self.std[columns])

    def weights(self, predictors: Array) -> Array:
        """beta (N,) of eq. A.6 at the query predictors (N, p)."""
        k = min(self.config.neighbours, len(self.errors))
        _, index = self._tree.query(self._space.normalise(np.atleast_2d(predictors)), k=k)
        index = np.asarray(index).reshape(len(np.atleast_2d(predictors)), k)
        ratio = self.errors[index].mean(axis=1) / max(self.average_error, 1e-300)
        return ratio**self.config.gamma

    def covariances(self, predictors: Array, nominal: Array) -> tuple[Array, NDArray[np.bool_]]:
        """beta-scaled nominal covariances (N, 3, 3) and which features are kept (beta <= max_weight)."""
        beta = self.weights(predictors)
        return beta[:, None, None] * np.asarray(nominal, dtype=float), beta <= self.config.max_weight


def train_knn(
    camera: StereoCamera,
    pairs: Sequence[FramePair],
    transforms: Sequence[Array],
    names: tuple[str, ...],
    nominal_sigma: Sequence[float] = (2.0, 2.0, 2.0),
    config: KNNConfig | None = None,
    seed: int = 0,
) -> KNNModel:
    """Algorithm 6 with ground truth: per frame and pass, disjoint random subsets of the features, each solved
    by least squares with the nominal covariance; |t_est - t_true| stored at every predictor of the subset."""
    config = config or KNNConfig()
    rng = np.random.default_rng(seed)
    information = np.linalg.inv(np.diag(np.asarray(nominal_sigma, dtype=float) ** 2))
    stored_predictors, stored_errors = [], []
    for pair, truth in zip(pairs, transforms, strict=True):
        n = len(pair)
        parts = min(config.subsets, n // config.min_subset)
        if parts < 1:
            continue
        for subset in np.array_split(rng.permutation(n), parts):
            sub = FramePair(pair.reference[subset], pair.current[subset], pair.predictors[subset])
            motion = solve_pair(camera, sub, np.broadcast_to(information, (len(subset), 3, 3)), RobustLoss("l2"), np.eye(4))
            error = float(np.linalg.norm(motion[:3, 3] - truth[:3, 3]))
            if np.isfinite(error):
                stored_predictors.append(sub.predictors)
                stored_errors.append(np.full(len(subset), error))
    if not stored_errors:
        raise ValueError(f"PROBE k-NN training: no frame pair has {config.min_subset} features or more")
    return KNNModel(names, np.vstack(stored_predictors), np.concatenate(stored_errors), config)
