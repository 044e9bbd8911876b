"""HydraNet's covariance widened where the flow did not follow the image (beyond the thesis).

At the model's 64-px-high input Farnebäck has two pyramid levels and, from a zero start, follows a turn of up to
about 3° per frame (:mod:`.flow`); beyond it the flow reads a fraction of the turn, the network reads that flow as a
smaller rotation, and its heads agree: on urban drives 1.8–2.5x faster than any it was trained on the pairs that turn
more than 4° err by 6° at an ANEES of 70 (stop 80, faster validation drives). Nothing the network outputs says so,
but the images do: phase correlation finds how far the whole image moved, and the flow's median should have moved
as far. Their difference, the *shortfall* d (pixels at the model's input size), is under 1.4 px for 99 % of the urban
validation pairs and several pixels where the flow failed. The aleatoric part is widened with it, in the spread
widening's form (:mod:`.widening`):

    Σ = Σ_e + Σ_a · (1 + γ · max(0, d / reference − 1)),

``reference`` a high quantile of d over in-distribution validation pairs, γ fitted by maximum likelihood on the
validation pairs of a faster-driven shift; the added part counted in Σ_e. Where the phase-correlation peak is weak
(response below ``min_response``: the planetary validation sequences whose pitched cameras give no single shift, peaks
≤ 0.2 against ≥ 0.48 on urban pairs) it measures no shift and d is 0.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: a phase-correlation peak below this measures no shift (cv2.phaseCorrelate's response, 0 … 1)
MIN_RESPONSE = 0.2
#: the quantile of the in-distribution shortfalls a widening starts from
REFERENCE_QUANTILE = 0.99
#: the powers a fit tries: none, then 1e-3 … 1e3 in 200 logarithmic steps
GAMMAS = np.concatenate([[0.0], np.geomspace(1e-3, 1e3, 200)])


def flow_shortfall(
    earlier: NDArray[np.uint8], later: NDArray[np.uint8], flow: ArrayLike, min_response: float = MIN_RESPONSE
) -> float:
    """d (px): how far the images' global shift (phase correlation, Hann window) lies from the median of ``flow``
    (2, H, W) from ``earlier`` to ``later`` (grey, the flow's size); 0 where the correlation's peak is below
    ``min_response``."""
    import cv2

    if earlier.shape != later.shape or earlier.ndim != 2:
        raise ValueError(f"a shortfall needs two grey images of one size, got {earlier.shape} and {later.shape}")
    window = cv2.createHanningWindow((earlier.shape[1], earlier.shape[0]), cv2.CV_32F)
    shift, response = cv2.phaseCorrelate(earlier.astype(np.float32), later.astype(np.float32), window)
    if not response >= min_response:
        return 0.0
    median = np.median(np.asarray(flow, dtype=np.float32).reshape(2, -1), axis=1)
    return float(np.hypot(shift[0] - median[0], shift[1] - median[1]))


def sequence_shortfalls(images: NDArray[np.uint8], flows: ArrayLike, gap: int = 1, min_response: float = MIN_RESPONSE) -> NDArray:
    """d (N-gap,) of each pair of ``images`` (N, 1, H, W) ``gap`` frames apart and its forward flow (N-gap, 2, H, W)."""
    flows = np.asarray(flows)
    return np.array(
        [flow_shortfall(images[k, 0], images[k + gap, 0], flows[k], min_response) for k in range(len(flows))], dtype=float
    )


@dataclass(frozen=True)
class ShortfallWidening:
    """reference: a quantile of the in-distribution shortfalls (px); gamma: how much Σ_a grows per unit of
    d / reference above 1; min_response: the weakest phase-correlation peak taken as a shift."""

    reference: float
    gamma: float
    min_response: float = MIN_RESPONSE

    def __post_init__(self) -> None:
        if not (np.isfinite(self.reference) and self.reference > 0.0):
            raise ValueError(f"the shortfall widening's reference must be a positive number of pixels, got {self.reference}")
        if not (np.isfinite(self.gamma) and self.gamma >= 0.0):
            raise ValueError(f"the shortfall widening's gamma must be a finite number >= 0, got {self.gamma}")
        if not 0.0 <= self.min_response < 1.0:
            raise ValueError(f"the shortfall widening's min_response must lie in [0, 1), got {self.min_response}")

    def factor(self, shortfalls: ArrayLike) -> NDArray:
        """1 + γ · max(0, d / reference − 1) of each pair's shortfall d (N,) px."""
        return 1.0 + self.gamma * np.maximum(0.0, np.asarray(shortfalls, dtype=float) / self.reference - 1.0)

    def widen(self, epistemic: ArrayLike, aleatoric: ArrayLike, shortfalls: ArrayLike) -> NDArray:
        """Σ_e (N, 3, 3) with the added part Σ_a · (factor − 1) in it."""
        added = (self.factor(shortfalls) - 1.0)[:, None, None] * np.asarray(aleatoric, dtype=float)
        return np.asarray(epistemic, dtype=float) + added

    def entry(self) -> dict[str, float]:
        return {"reference": float(self.reference), "gamma": float(self.gamma), "min_response": float(self.min_response)}

    @classmethod
    def from_entry(cls, entry: Any) -> ShortfallWidening:
        """The widening of a card's ``calibration.flow_shortfall_widening``; ValueError naming what is wrong."""
        if not isinstance(entry, Mapping) or not {"reference", "gamma"} <= set(entry):
            raise ValueError(f"flow_shortfall_widening needs a reference and a gamma, got {entry!r}")
        try:
            return cls(float(entry["reference"]), float(entry["gamma"]), float(entry.get("min_response", MIN_RESPONSE)))
        except (TypeError, ValueError) as error:
            raise ValueError(f"flow_shortfall_widening: {error}") from None


def mean_nll(errors: ArrayLike, covariances: ArrayLike) -> float:
    """Mean negative log-likelihood (without its constant) of left-tangent errors (N, 3) under covariances (N, 3, 3)."""
    errors, covariances = np.asarray(errors, dtype=float), np.asarray(covariances, dtype=float)
    nees = np.einsum("ni,ni->n", errors, np.linalg.solve(covariances, errors[..., None])[..., 0])
    return float(np.mean(0.5 * nees + 0.5 * np.linalg.slogdet(covariances)[1]))


def fit_shortfall_widening(
    reference_shortfalls: ArrayLike,
    shift_errors: ArrayLike,
    shift_epistemic: ArrayLike,
    shift_aleatoric: ArrayLike,
    shift_shortfalls: ArrayLike,
    reference_quantile: float = REFERENCE_QUANTILE,
    min_response: float = MIN_RESPONSE,
    gammas: ArrayLike = GAMMAS,
) -> ShortfallWidening:
    """The widening whose reference is the ``reference_quantile`` of the in-distribution pairs' shortfalls (px) and
    whose γ, among ``gammas``, gives the shift's pairs (errors (N, 3) rad, Σ_e with any other widening in it and Σ_a
    (N, 3, 3) rad², shortfalls (N,) px) the lowest mean negative log-likelihood."""
    if not 0.0 < reference_quantile < 1.0:
        raise ValueError(f"the reference quantile must lie in (0, 1), got {reference_quantile}")
    reference = float(np.quantile(np.asarray(reference_shortfalls, dtype=float), reference_quantile))
    if not reference > 0.0:
        raise ValueError("the in-distribution pairs' shortfalls are all 0: no reference to widen from")
    epistemic, aleatoric = np.asarray(shift_epistemic, dtype=float), np.asarray(shift_aleatoric, dtype=float)
    scores = [
        mean_nll(
            shift_errors,
            ShortfallWidening(reference, float(g), min_response).widen(epistemic, aleatoric, shift_shortfalls) + aleatoric,
        )
        for g in np.asarray(gammas, dtype=float)
    ]
    return ShortfallWidening(reference, float(np.asarray(gammas, dtype=float)[int(np.argmin(scores))]), min_response)
