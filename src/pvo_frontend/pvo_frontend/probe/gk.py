"""PROBE-GK (thesis §4.4): a per-feature noise model for stereo reprojection errors by generalized kernels.

Each training sample is a predictor vector phi_i (what a feature looked like) and the reprojection error
e_i = y_cur - f(T f^-1(y_ref)) it had under the true (or EM-estimated) motion T, in the solver's observation
space (u, v, d) px, so d = 3. For a query phi*, the inverse-Wishart prior IW(Psi0, nu0) is updated by the
stored errors weighted by a kernel of finite support (eqs. 4.19, 4.20):

    Psi* = Psi0 + sum_i k(phi*, phi_i) e_i e_i^T,      nu* = nu0 + sum_i k(phi*, phi_i),

and the posterior predictive of a new error is a multivariate Student-t with nu* - d + 1 degrees of freedom
and scale matrix Psi* / (nu* - d + 1) (eq. 4.23). The motion solver's Student-t loss on the whitened norm
(:class:`pvo_frontend.vo.solver.RobustLoss`, ``student_t``) with that dof and scale is exactly eq. 4.25.

Choices the thesis leaves open (thesis-code-facts §3.2), made here and measured in the experiment:
- error space: (u, v, d), d = 3 - the space the solver whitens in;
- kernel: the sparse kernel of Melkumyan and Ramos, k(r) = (2 + cos 2 pi r)/3 (1 - r) + sin(2 pi r)/(2 pi)
  for r = |phi* - phi_i| / radius < 1, else 0 (k(0) = 1, smooth, compact support), over predictors
  normalised by the training mean and standard deviation;
- neighbours: the ``max_neighbours`` nearest within the radius (a k-d tree query with a distance bound,
  vectorised over all features of a frame);
- prior (``prior: fitted``, the default): the static Student-t noise of the training errors themselves, with
  ``prior_dof`` = 3 degrees of freedom and its diagonal scale fitted by maximum likelihood
  (:func:`fit_static_student_t`), as nu0 = prior_dof + d - 1 virtual samples, so that a feature without a stored
  neighbour gets exactly that static noise. ``prior: nominal`` is the earlier prior, Psi0 = n diag(sigma^2),
  nu0 = n, "n virtual samples of the nominal noise" (1, 1, 2) px - several times the rendered rig's real noise
  (the training errors' fitted scale is 0.25 / 0.13 / 0.20 px), so it swamped the stored errors and a feature
  out of the training support was weighed by a wide Cauchy. Chosen on the rendered corpus's validation split
  (60 sequences, 5 RANSAC seeds each, a model of 60 training sequences; never its test split), the VO's
  translational ARMSE change against the default VO, all / hard tracking / the worst clean sequence, with the
  VO's Student-t inlier gate (:func:`pvo_frontend.vo.pipeline.inlier_gate`): fitted with 2 dof -48.4 / -63.7 /
  +9.4 %, **3 dof -50.1 / -67.9 / +4.9 %**, 5 dof -50.0 / -66.8 / +8.4 %; the nominal prior -9.8 / -3.9 / +51.4 %
  (its Cauchy tails leave no gate) and, with the chi-square gate it was tuned under, -31.1 / -43.4 / +7.1 %.
  On KITTI's KLT tracks cross-validation on 07 prefers the nominal prior (``pvo experiment probe`` uses it there).

The defaults (radius 0.25, 8 neighbours, n = 3) were chosen on held-out data, never a test split: on KITTI 07's
raw-derived tracks, trained on frames 1-349 and validated on 350-499, translational ARMSE 0.529 m against the
static M-estimator's 0.595 m (32 neighbours within 0.5 with n = 5: 0.597 m; 4 within 0.25: 0.541 m), and on
the synthetic world (seed 0) 0.95 m against 1.35 m. Few neighbours keep nu* small, so the posterior predictive
keeps the heavy tails that down-weight a bad track; many neighbours make it nearly Gaussian (nu* -> the
number of neighbours), the least-squares limit the thesis notes after eq. 4.25.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

Array = NDArray[np.float64]

#: Dimension of one error (u, v, d).
ERROR_DIM = 3


def sparse_kernel(r: Array) -> Array:
    """Melkumyan-Ramos sparse kernel of a normalised distance r >= 0: 1 at 0, 0 from 1 on, smooth."""
    r = np.clip(np.asarray(r, dtype=float), 0.0, 1.0)
    two_pi_r = 2.0 * np.pi * r
    k = (2.0 + np.cos(two_pi_r)) / 3.0 * (1.0 - r) + np.sin(two_pi_r) / (2.0 * np.pi)
    return np.clip(k, 0.0, 1.0)  # round-off leaves -4e-17 at r = 1


#: The prior's kinds: the static Student-t fitted to the training errors, or the nominal noise given.
PRIORS = ("fitted", "nominal")
#: The nominal prior's defaults: n virtual samples of (u, v, d) standard deviations (px).
NOMINAL_PRIOR_SAMPLES = 3.0
NOMINAL_PRIOR_SIGMA = (1.0, 1.0, 2.0)
#: The smallest standard deviation (px) a fitted prior takes on any axis.
MIN_PRIOR_SIGMA = 1e-3


@dataclass(frozen=True)
class GKConfig:
    """radius: kernel support in normalised predictor units; max_neighbours: stored errors per query;
    prior: ``fitted`` (the training errors' static Student-t with ``prior_dof`` dof; ``prior_samples`` and
    ``prior_sigma`` are filled in when the model is built from its errors) or ``nominal`` (``prior_samples``
    virtual samples of ``prior_sigma``, default 3 of (1, 1, 2) px); prior_samples: n, the prior's weight in
    virtual samples (> d - 1 = 2 so that every dof is positive); prior_sigma: the (u, v, d) standard deviations
    (px) of Psi0 = n diag(sigma^2)."""

    radius: float = 0.25
    max_neighbours: int = 8
    prior: str = "fitted"
    prior_dof: float = 3.0
    prior_samples: float | None = None
    prior_sigma: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if not self.radius > 0.0:
            raise ValueError(f"PROBE-GK radius must be positive, got {self.radius}")
        if self.max_neighbours < 1:
            raise ValueError(f"PROBE-GK max_neighbours must be >= 1, got {self.max_neighbours}")
        if self.prior not in PRIORS:
            raise ValueError(f"PROBE-GK prior must be one of {', '.join(PRIORS)}, got {self.prior!r}")
        if not self.prior_dof > 0.0:
            raise ValueError(f"PROBE-GK prior_dof must be positive, got {self.prior_dof}")
        if self.prior == "fitted" and (self.prior_samples is None) != (self.prior_sigma is None):
            raise ValueError("PROBE-GK fitted prior: prior_samples and prior_sigma come together (as fitted) or not at all")
        if self.prior == "nominal":
            if self.prior_samples is None:
                object.__setattr__(self, "prior_samples", NOMINAL_PRIOR_SAMPLES)
            if self.prior_sigma is None:
                object.__setattr__(self, "prior_sigma", NOMINAL_PRIOR_SIGMA)
        if self.prior_samples is not None and not self.prior_samples > ERROR_DIM - 1:
            raise ValueError(f"PROBE-GK prior_samples must be > {ERROR_DIM - 1}, got {self.prior_samples}")
        if self.prior_sigma is not None:
            object.__setattr__(self, "prior_sigma", tuple(float(v) for v in self.prior_sigma))
            if len(self.prior_sigma) != ERROR_DIM or not min(self.prior_sigma) > 0.0:
                raise ValueError(f"PROBE-GK prior_sigma needs {ERROR_DIM} positive values, got {self.prior_sigma}")

    @property
    def resolved(self) -> bool:
        """Whether the prior is known (a fitted prior only once the training errors were seen)."""
        return self.prior_samples is not None and self.prior_sigma is not None

    @property
    def prior_scale(self) -> Array:
        """Psi0 = n diag(sigma^2), (3, 3) px^2."""
        if self.prior_samples is None or self.prior_sigma is None:
            raise ValueError("PROBE-GK prior is not fitted yet (build the model from its training errors)")
        return self.prior_samples * np.diag(np.asarray(self.prior_sigma, dtype=float) ** 2)

    def fitted_to(self, errors: Array) -> GKConfig:
        """This config with a ``fitted`` prior resolved from training errors (M, 3) px: nu0 = prior_dof + d - 1 and
        Psi0 = nu0 diag(sigma^2) with sigma^2 = diag(S) prior_dof / nu0, S the ML scale of a Student-t with
        prior_dof dof, so that the posterior predictive without neighbours (eq. 4.23: dof nu0 - d + 1, scale
        Psi0 / dof) is that Student-t. A resolved or nominal config is returned as it is."""
        if self.prior != "fitted" or self.resolved:
            return self
        errors = np.asarray(errors, dtype=float)
        if len(errors) < ERROR_DIM + 1:
            raise ValueError(f"PROBE-GK: a fitted prior needs training errors, got {len(errors)}")
        scale = fit_static_student_t(errors, self.prior_dof)
        samples = self.prior_dof + ERROR_DIM - 1.0
        sigma = np.sqrt(np.diag(scale) * self.prior_dof / samples)
        return replace(self, prior_samples=float(samples), prior_sigma=tuple(float(v) for v in sigma))


def fit_static_student_t(errors: Array, dof: float, iterations: int = 200, tolerance: float = 1e-9) -> Array:
    """The maximum-likelihood scale matrix S (3, 3) of a zero-mean multivariate Student-t with ``dof`` degrees
    of freedom for errors (M, 3), by EM: weights w = (dof + d) / (dof + e^T S^-1 e), S = sum w e e^T / M."""
    errors = np.asarray(errors, dtype=float)
    d = errors.shape[1]
    floor = MIN_PRIOR_SIGMA**2 * np.eye(d)  # noise-free training errors would leave S singular
    scale = errors.T @ errors / len(errors) + floor
    for _ in range(iterations):
        mahalanobis = np.einsum("ni,ij,nj->n", errors, np.linalg.inv(scale), errors)
        weights = (dof + d) / (dof + mahalanobis)
        updated = (errors * weights[:, None]).T @ errors / len(errors) + floor
        converged = np.max(np.abs(updated - scale)) <= tolerance * np.max(np.abs(updated))
        scale = updated
        if converged:
            break
    return scale


@dataclass
class NoiseModel:
    """Per-feature Student-t noise: scale matrices (N, 3, 3) px^2 and degrees of freedom (N,); the solver
    whitens with ``information`` = scale^-1 and uses ``dof`` as its Student-t loss constant."""

    scale: Array
    dof: Array

    @property
    def information(self) -> Array:
        return np.linalg.inv(self.scale)

    @property
    def covariance(self) -> Array:
        """The Student-t's covariance scale * dof / (dof - 2) where it exists (dof > 2), else inf."""
        dof = self.dof[:, None, None]
        with np.errstate(divide="ignore"):
            return np.where(dof > 2.0, self.scale * dof / np.maximum(dof - 2.0, 1e-300), np.inf)


@dataclass
class PredictorSpace:
    """Where stored samples live: predictor names, the normalisation by the training mean and std (stored with
    the model) and a k-d tree over the normalised training predictors (M, p)."""

    names: tuple[str, ...]
    mean: Array
    std: Array
    tree: cKDTree | None

    @classmethod
    def fit(
        cls, names: tuple[str, ...], predictors: Array, mean: Array | None = None, std: Array | None = None
    ) -> PredictorSpace:
        """Check the predictors ((M, len(names)), finite) and index them; mean/std from them unless given."""
        if predictors.ndim != 2 or predictors.shape[1] != len(names):
            raise ValueError(f"predictors must be (M, {len(names)}) for {names}, got {predictors.shape}")
        if not np.all(np.isfinite(predictors)):
            raise ValueError("PROBE training samples must be finite")
        if mean is None or std is None:
            mean = predictors.mean(axis=0) if len(predictors) else np.zeros(len(names))
            spread = predictors.std(axis=0) if len(predictors) else np.ones(len(names))
            std = np.where(spread > 1e-12, spread, 1.0)
        space = cls(names, np.asarray(mean, dtype=float), np.asarray(std, dtype=float), None)
        space.tree = cKDTree(space.normalise(predictors)) if len(predictors) else None
        return space

    def normalise(self, predictors: Array) -> Array:
        return (np.asarray(predictors, dtype=float) - self.mean) / self.std


@dataclass
class GKModel:
    """Stored training samples: predictors (M, p) in their own units with their names, errors (M, 3) px.

    The predictors are normalised by ``mean`` and ``std`` (the training statistics, stored with the model)."""

    names: tuple[str, ...]
    predictors: Array
    errors: Array
    config: GKConfig = field(default_factory=GKConfig)
    mean: Array | None = None
    std: Array | None = None

    def __post_init__(self) -> None:
        self.predictors = np.asarray(self.predictors, dtype=float)
        self.errors = np.asarray(self.errors, dtype=float)
        space = PredictorSpace.fit(self.names, self.predictors, self.mean, self.std)
        if self.errors.shape != (len(self.predictors), ERROR_DIM):
            raise ValueError(f"errors must be ({len(self.predictors)}, {ERROR_DIM}), got {self.errors.shape}")
        if not np.all(np.isfinite(self.errors)):
            raise ValueError("PROBE training samples must be finite")
        self.config = self.config.fitted_to(self.errors)
        self.mean, self.std, self._space = space.mean, space.std, space
        self._tree = space.tree
        self._padded = np.vstack([self.errors, np.zeros((1, ERROR_DIM))])  # index M = "no neighbour"

    def normalise(self, predictors: Array) -> Array:
        return self._space.normalise(predictors)

    def marginal(self, names: tuple[str, ...]) -> GKModel:
        """The same stored errors indexed by the predictors ``names`` only (a subset of this model's), for a
        query that lacks the others (an IMU model at a frame without an IMU reading): the kernel over the kept
        predictors, normalised by their training statistics, and the same (already resolved) prior."""
        columns = predictor_columns(self.names, names)
        assert self.mean is not None and self.std is not None
        return GKModel(names, self.predictors[:, columns], self.errors, self.config, self.mean[columns], self.std[columns])

    def replace_errors(self, errors: Array) -> None:
        """New errors for the same samples (an EM step): the index over the predictors is kept."""
        errors = np.asarray(errors, dtype=float)
        if errors.shape != self.errors.shape:
            raise ValueError(f"errors must be {self.errors.shape}, got {errors.shape}")
        self.errors = errors
        self._padded = np.vstack([errors, np.zeros((1, ERROR_DIM))])

    def neighbours(self, predictors: Array) -> tuple[NDArray[np.int64], Array]:
        """Indices (N, K) of the stored samples within the kernel's support of each query (M where fewer than
        K are) and their kernel weights (N, K)."""
        queries = self.normalise(np.atleast_2d(predictors))
        n, k = len(queries), min(self.config.max_neighbours, max(len(self.predictors), 1))
        if self._tree is None:
            return np.zeros((n, 0), dtype=np.int64), np.zeros((n, 0))
        distance, index = self._tree.query(queries, k=k, distance_upper_bound=self.config.radius)
        distance, index = distance.reshape(n, k), index.reshape(n, k)
        found = np.isfinite(distance)
        weights = np.where(found, sparse_kernel(np.where(found, distance, 0.0) / self.config.radius), 0.0)
        return index.astype(np.int64), weights

    def posterior(self, predictors: Array, exclude: NDArray[np.int64] | None = None) -> tuple[Array, Array]:
        """Psi* (N, 3, 3) and nu* (N,) at the query predictors (N, p), eqs. 4.19-4.20. ``exclude``: for each
        query the index of a stored sample to leave out (its own, in EM: D without (i, t)), or -1."""
        index, weights = self.neighbours(predictors)
        if exclude is not None:
            weights = np.where(index == np.asarray(exclude)[:, None], 0.0, weights)
        stored = self._padded[index]  # (N, K, 3)
        psi = self.config.prior_scale + np.matmul(np.swapaxes(stored * weights[:, :, None], 1, 2), stored)
        nu = self.config.prior_samples + weights.sum(axis=1)
        return psi, nu

    def noise(self, predictors: Array, exclude: NDArray[np.int64] | None = None) -> NoiseModel:
        """The posterior predictive Student-t per query (eq. 4.23): dof nu* - d + 1, scale Psi* / dof."""
        psi, nu = self.posterior(predictors, exclude)
        dof = nu - ERROR_DIM + 1.0
        return NoiseModel(psi / dof[:, None, None], dof)


def predictor_columns(names: tuple[str, ...], kept: tuple[str, ...]) -> list[int]:
    """The column of each of ``kept`` among ``names``; a name the model lacks is a ValueError."""
    missing = [n for n in kept if n not in names]
    if missing:
        raise ValueError(f"PROBE: the model has no predictor {', '.join(missing)} (it has {', '.join(names)})")
    return [names.index(n) for n in kept]


def student_t_log_density(errors: Array, noise: NoiseModel) -> Array:
    """log t_dof(e; 0, scale) of errors (N, 3) under per-feature Student-t noise, (N,)."""
    from scipy.special import gammaln

    e = np.asarray(errors, dtype=float)
    dof, scale = noise.dof, noise.scale
    d = e.shape[1]
    _, logdet = np.linalg.slogdet(scale)
    mahalanobis = np.einsum("ni,nij,nj->n", e, np.linalg.inv(scale), e)
    return (
        gammaln((dof + d) / 2.0)
        - gammaln(dof / 2.0)
        - 0.5 * d * np.log(dof * np.pi)
        - 0.5 * logdet
        - 0.5 * (dof + d) * np.log1p(mahalanobis / dof)
    )
