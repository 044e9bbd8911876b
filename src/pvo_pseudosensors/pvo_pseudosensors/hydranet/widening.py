"""The aleatoric covariance widened by how far HydraNet's heads disagree beyond their usual spread.

Out of distribution the heads' spread Σ_e grows (thesis §7.5.1) but stays a fraction of a percent of the total, so
the total covariance hardly grows with it and the readings are overconfident there; a scale on Σ_e cannot mend that
(its fit on in-distribution pairs moves nothing). The spread can instead say *how much* to widen Σ_a:

    Σ = Σ_e + Σ_a · (1 + γ · max(0, r − 1)),    r = tr Σ_e / reference,

``reference`` a quantile of tr Σ_e (rad²) over in-distribution validation pairs — the median, so typical pairs are
left as they are, or a higher one (stop 67 ships the 90th percentile: the median widened the in-distribution pairs that
turn most, whose heads disagree more, to a covariance six times too wide (ANEES 0.15); at the 90th it stays 0.54).
In distribution the spread does not say which pairs Σ_a underrates (γ fitted there comes out 0), so γ is fitted by
maximum likelihood on the validation pairs of a *shift* the model was not trained on (e.g. the planetary preset for
an urban model); stop 66 measured it carrying to another shift absent from both training and fit (faster drives:
ANEES 4.17 → 1.26). The added part Σ_a · (factor − 1) is counted in Σ_e, as :mod:`.density`'s widening is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike

from .density import normalised_errors

#: the largest power a fit tries by default, and the grid's step (0: no widening)
MAX_GAMMA = 3.0
GAMMA_STEP = 0.01


def gamma_grid(max_gamma: float = MAX_GAMMA) -> np.ndarray:
    """The powers a fit tries: 0 to ``max_gamma`` (> 0) in steps of :data:`GAMMA_STEP`."""
    if not 0.0 < max_gamma <= 1000.0:  # also NaN
        raise ValueError(f"the spread widening's largest power must lie in (0, 1000], got {max_gamma}")
    return np.linspace(0.0, max_gamma, round(max_gamma / GAMMA_STEP) + 1)


@dataclass(frozen=True)
class SpreadWidening:
    """reference: a quantile of the in-distribution tr Σ_e (rad²); gamma: how much Σ_a grows per unit of r above 1."""

    reference: float
    gamma: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.reference) and self.reference > 0.0):
            raise ValueError(f"the spread widening's reference must be a positive trace of Sigma_e (rad^2), got {self.reference}")
        if not (np.isfinite(self.gamma) and self.gamma >= 0.0):
            raise ValueError(f"the spread widening's gamma must be a finite number >= 0, got {self.gamma}")

    def factor(self, epistemic: torch.Tensor) -> torch.Tensor:
        """1 + γ · max(0, tr Σ_e / reference − 1) of each pair's Σ_e (N, 3, 3): (N,)."""
        ratio = torch.diagonal(epistemic, dim1=-2, dim2=-1).sum(-1) / self.reference
        return 1.0 + self.gamma * torch.clamp(ratio - 1.0, min=0.0)

    def widen(self, epistemic: torch.Tensor, aleatoric: torch.Tensor) -> torch.Tensor:
        """Σ_e with the widening's added part Σ_a · (factor − 1) in it (N, 3, 3)."""
        return epistemic + (self.factor(epistemic) - 1.0)[:, None, None] * aleatoric

    def entry(self) -> dict[str, float]:
        return {"reference": float(self.reference), "gamma": float(self.gamma)}

    @classmethod
    def from_entry(cls, entry: Any) -> SpreadWidening:
        """The widening of a card's ``calibration.spread_widening``; ValueError naming what is wrong."""
        if not isinstance(entry, Mapping) or not {"reference", "gamma"} <= set(entry):
            raise ValueError(f"spread_widening needs a reference and a gamma, got {entry!r}")
        try:
            reference, gamma = float(entry["reference"]), float(entry["gamma"])
        except (TypeError, ValueError) as error:
            raise ValueError(f"spread_widening: {error}") from None
        return cls(reference, gamma)


def fit_widening(
    reference_epistemic: ArrayLike,
    shift_errors: ArrayLike,
    shift_epistemic: ArrayLike,
    shift_aleatoric: ArrayLike,
    gammas: ArrayLike | None = None,
    reference_quantile: float = 0.5,
) -> SpreadWidening:
    """The widening whose reference is the ``reference_quantile`` of tr Σ_e over the in-distribution pairs'
    ``reference_epistemic`` (M, 3, 3) and whose γ, among ``gammas`` (default :func:`gamma_grid`), gives the shift's
    pairs (their rotation errors (N, 3) rad, Σ_e and Σ_a (N, 3, 3) rad²) the lowest mean negative log-likelihood."""
    if not 0.0 < reference_quantile < 1.0:
        raise ValueError(f"the spread widening's reference quantile must lie in (0, 1), got {reference_quantile}")
    traces = np.trace(np.asarray(reference_epistemic, dtype=float), axis1=-2, axis2=-1)
    if traces.size == 0 or len(np.asarray(shift_errors)) == 0:
        raise ValueError("fitting a spread widening needs in-distribution and shift pairs, at least one of each")
    reference = float(np.quantile(traces, reference_quantile))
    errors = torch.as_tensor(np.asarray(shift_errors, dtype=float))
    epistemic = torch.as_tensor(np.asarray(shift_epistemic, dtype=float))
    aleatoric = torch.as_tensor(np.asarray(shift_aleatoric, dtype=float))

    def negative_log_likelihood(candidate: SpreadWidening) -> float:  # eq. 7.17 without its constant, per pair
        covariances = candidate.widen(epistemic, aleatoric) + aleatoric
        return float((0.5 * normalised_errors(errors, covariances) + 0.5 * torch.linalg.slogdet(covariances)[1]).mean())

    grid = gamma_grid() if gammas is None else np.asarray(gammas, dtype=float)
    candidates = [SpreadWidening(reference, float(g)) for g in grid]
    return min(candidates, key=negative_log_likelihood)
