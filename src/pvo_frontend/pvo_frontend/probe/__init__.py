"""PROBE (thesis ch. 4, app. A): learned per-feature noise for the stereo VO.

:mod:`.gk` (PROBE-GK: the inverse-Wishart / generalized-kernel noise model), :mod:`.training` (with ground
truth, Algorithm 1; without it by EM, Algorithm 3; the per-frame solve, Algorithm 2), :mod:`.synthetic` (the
thesis's point world)."""

from .gk import GKConfig, GKModel, NoiseModel
from .training import FramePair, reprojection_errors, train_expectation_maximisation, train_with_ground_truth

__all__ = [
    "FramePair",
    "GKConfig",
    "GKModel",
    "NoiseModel",
    "reprojection_errors",
    "train_expectation_maximisation",
    "train_with_ground_truth",
]
