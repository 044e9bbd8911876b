"""How far a frame pair lies from the data HydraNet was made for, and the covariance that follows from it.

One body's heads barely disagree anywhere (their spread is well under 1 % of the total covariance, in distribution
and out of it), so eq. 7.16's Sigma_e cannot carry a shift of the input. A Gaussian density over the body's
features (the 256 units the heads read) can: fitted on in-distribution pairs, the Mahalanobis distance d² of a
pair's features says how unlike them it is. With r = d² / (the median d² over in-distribution validation pairs)
and q the 95th percentile of r there, the covariance of a pair becomes

    Sigma = (Sigma_e + Sigma_a) g,   g = max(1, r / q) ** gamma,

the added part (g - 1)(Sigma_e + Sigma_a) counted as epistemic: pairs like the validation ones keep their
covariance, pairs beyond them widen it as a power of how far beyond. gamma is fitted so that the ANEES is 1 on
pairs of a shift the model never saw (:func:`fit_gamma`). Arrays are float64 torch tensors: features (N, F),
covariances (N, 3, 3) in rad².
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

#: The file beside the weights that holds the density's mean and precision.
DENSITY_FILE = "feature_density.safetensors"
#: Share of the feature covariance shrunk toward tr/F I, so that a feature direction the fitting pairs barely
#: spread along does not make every new pair look far away.
SHRINKAGE = 0.1
#: The quantile of the in-distribution validation pairs' r below which a covariance is left as it is.
QUANTILE = 0.95
#: gamma is looked for in [0, this].
MAX_GAMMA = 4.0


@dataclass(frozen=True)
class FeatureDensity:
    """A Gaussian over HydraNet's body features: ``mean`` (F,), ``precision`` (F, F) (the shrunk covariance's
    inverse), ``median`` the in-distribution validation pairs' median d², ``threshold`` q (the 95th percentile
    of their r = d² / median), ``gamma`` the power of the widening (0: none)."""

    mean: torch.Tensor
    precision: torch.Tensor
    median: float
    threshold: float
    gamma: float = 0.0

    def __post_init__(self) -> None:
        features = self.mean.shape[0]
        if self.mean.ndim != 1 or self.precision.shape != (features, features):
            raise ValueError(
                f"a feature density needs a mean (F,) and a precision (F, F), got {tuple(self.mean.shape)} and "
                f"{tuple(self.precision.shape)}"
            )
        if not (self.median > 0.0 and self.threshold > 0.0 and 0.0 <= self.gamma <= MAX_GAMMA):
            raise ValueError(
                f"a feature density needs median > 0, threshold > 0 and gamma in [0, {MAX_GAMMA}], got "
                f"{self.median}, {self.threshold}, {self.gamma}"
            )

    @property
    def features(self) -> int:
        return int(self.mean.shape[0])

    def distances(self, features: torch.Tensor) -> torch.Tensor:
        """Squared Mahalanobis distances (N,) of features (N, F)."""
        if features.ndim != 2 or features.shape[1] != self.features:
            raise ValueError(f"features {tuple(features.shape)} do not fit a density over {self.features} units")
        centred = features.double() - self.mean
        return torch.einsum("ni,ij,nj->n", centred, self.precision, centred)

    def scores(self, features: torch.Tensor) -> torch.Tensor:
        """r (N,): d² over the in-distribution validation pairs' median (about 1 there)."""
        return self.distances(features) / self.median

    def inflation(self, features: torch.Tensor) -> torch.Tensor:
        """g (N,) >= 1, the factor on each pair's covariance."""
        return widening(self.scores(features), self.threshold, self.gamma)

    def with_gamma(self, gamma: float) -> FeatureDensity:
        return FeatureDensity(self.mean, self.precision, self.median, self.threshold, float(gamma))

    def save(self, directory: Path) -> dict[str, float | str]:
        """Mean and precision into ``directory/`` :data:`DENSITY_FILE`; the scalars returned for the card's
        ``calibration.feature_density``."""
        from safetensors.torch import save_file

        save_file(
            {"mean": self.mean.contiguous(), "precision": self.precision.contiguous()},
            str(Path(directory) / DENSITY_FILE),
        )
        return {"file": DENSITY_FILE, "median": self.median, "threshold": self.threshold, "gamma": self.gamma}

    @classmethod
    def load(cls, directory: Path, entry: dict) -> FeatureDensity:
        """The density a card's ``calibration.feature_density`` ``entry`` names in ``directory`` (ValueError in
        one line naming what is wrong)."""
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        if not isinstance(entry, dict) or not {"file", "median", "threshold", "gamma"} <= set(entry):
            raise ValueError("calibration.feature_density must give file, median, threshold and gamma")
        path = Path(directory) / str(entry["file"])
        try:
            tensors = load_file(str(path))
        except (OSError, SafetensorError, ValueError, RuntimeError) as error:
            raise ValueError(f"{path}: cannot read the feature density ({error})") from None
        if set(tensors) != {"mean", "precision"}:
            raise ValueError(f"{path}: a feature density holds mean and precision, found {sorted(tensors)}")
        return cls(
            tensors["mean"].double(),
            tensors["precision"].double(),
            float(entry["median"]),
            float(entry["threshold"]),
            float(entry["gamma"]),
        )


def widening(scores: torch.Tensor, threshold: float, gamma: float) -> torch.Tensor:
    """g = max(1, r / q) ** gamma for scores r (N,)."""
    return torch.clamp(scores / threshold, min=1.0) ** gamma


def fit_density(
    fitting: torch.Tensor,
    validation: torch.Tensor,
    shrinkage: float = SHRINKAGE,
    quantile: float = QUANTILE,
    components: int | None = None,
) -> FeatureDensity:
    """The Gaussian of the ``fitting`` features (N, F) (covariance shrunk by ``shrinkage`` toward tr/F I), its
    d² median and r ``quantile`` over the ``validation`` features (M, F); gamma 0 (fit it with :func:`fit_gamma`).
    ``components``: the distance only along the covariance's that many leading principal directions (the
    precision of rank ``components``), where the fitting pairs pin the density down best; None: all F."""
    fitting, validation = fitting.double(), validation.double()
    if fitting.ndim != 2 or len(fitting) <= fitting.shape[1]:
        raise ValueError(f"a density over {fitting.shape[-1]} features needs more pairs than that, got {len(fitting)}")
    if validation.ndim != 2 or validation.shape[1] != fitting.shape[1] or len(validation) < 2:
        raise ValueError(f"validation features {tuple(validation.shape)} do not match fitting ones {tuple(fitting.shape)}")
    mean = fitting.mean(0)
    covariance = torch.cov(fitting.T)
    size = covariance.shape[0]
    covariance = (1.0 - shrinkage) * covariance + shrinkage * torch.trace(covariance) / size * torch.eye(
        size, dtype=torch.float64
    )
    if components is not None and not 1 <= components <= size:
        raise ValueError(f"components must be in [1, {size}], got {components}")
    values, vectors = torch.linalg.eigh(covariance)  # ascending
    kept = slice(size - (components or size), size)
    precision = (vectors[:, kept] / values[kept]) @ vectors[:, kept].T
    precision = 0.5 * (precision + precision.T)
    unscaled = FeatureDensity(mean, precision, 1.0, 1.0)
    distances = unscaled.distances(validation)
    median = float(torch.quantile(distances, 0.5))
    threshold = float(torch.quantile(distances / median, quantile))
    return FeatureDensity(mean, precision, median, threshold)


def normalised_errors(errors: torch.Tensor, covariances: torch.Tensor) -> torch.Tensor:
    """NEES (N,) of left-tangent errors (N, 3) under covariances (N, 3, 3): phi^T Sigma^-1 phi."""
    errors, covariances = errors.double(), covariances.double()
    return torch.einsum("ni,ni->n", errors, torch.linalg.solve(covariances, errors.unsqueeze(-1)).squeeze(-1))


def fit_gamma(nees: torch.Tensor, scores: torch.Tensor, threshold: float, target: float = 1.0) -> float:
    """The gamma in [0, :data:`MAX_GAMMA`] at which pairs with NEES (N,) (under the covariances without the
    widening) and scores r (N,) reach an ANEES (mean NEES / 3, each NEES divided by its g) of ``target``:
    0 when they are already at or below it, :data:`MAX_GAMMA` when not even that widening gets there."""

    def anees(gamma: float) -> float:
        return float((nees / widening(scores, threshold, gamma)).mean() / 3.0)

    if anees(0.0) <= target:
        return 0.0
    if anees(MAX_GAMMA) > target:
        return MAX_GAMMA
    low, high = 0.0, MAX_GAMMA
    for _ in range(60):  # ANEES falls monotonically with gamma: bisection to ~4e-18
        middle = 0.5 * (low + high)
        low, high = (middle, high) if anees(middle) > target else (low, middle)
    return 0.5 * (low + high)
