"""HydraNet's one-dimensional study (thesis §7.4.2, Figs. 7.4-7.5): five ways to get an uncertainty from a
network, trained on eq. 7.7's data and scored by the test negative log likelihood in and out of distribution.

Data (eq. 7.7): y = x + sin(4(x + w)) + sin(13(x + w)) + w; 1000 training samples with x in
[0, 0.6] U [0.8, 1.0], 100 test samples with x uniform in [-2, 2]. The thesis prints w ~ N(0, 3^2); with that
noise the targets would be noise alone, and the experiment it follows (Osband et al. 2016, after Blundell et
al. 2015) uses w ~ N(0, 0.03^2): ``noise_sigma`` defaults to 0.03.

Estimators (every network the same four fully connected layers, ``width`` units, ReLU):
- ``hydranet``: a two-layer body, ``heads`` two-layer mean heads and a variance head (softplus); each head's
  output paired with the target and the shared aleatoric variance in the Gaussian NLL (eq. 7.5); at test the
  mean of the heads, sigma^2 = the heads' sample variance (eq. 7.6) + the aleatoric variance (eq. 7.4);
- ``direct``: one network with a mean and a variance output, Gaussian NLL;
- ``dropout``: dropout after every hidden layer, mean squared error; at test ``samples`` stochastic passes, their
  mean and variance (Gal and Ghahramani 2016);
- ``bagging``: ``bags`` networks, each on a bootstrap resample, mean squared error; their mean and variance;
- ``hydranet_no_aleatoric``: the heads alone with mean squared error; sigma^2 = the heads' variance.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

Array = NDArray[np.float64]
METHODS = ("hydranet", "direct", "dropout", "bagging", "hydranet_no_aleatoric")
TRAIN_RANGES = ((0.0, 0.6), (0.8, 1.0))
TEST_RANGE = (-2.0, 2.0)


@dataclass(frozen=True)
class OneDConfig:
    """Data sizes and noise, the networks' width, the heads, bags and MC samples, the optimiser."""

    train_samples: int = 1000
    test_samples: int = 100
    noise_sigma: float = 0.03
    width: int = 50
    heads: int = 25
    bags: int = 10
    dropout: float = 0.1
    samples: int = 50
    steps: int = 1500
    learning_rate: float = 1e-2
    min_variance: float = 1e-6


def target(x: Array, w: Array) -> Array:
    """Eq. 7.7."""
    return x + np.sin(4.0 * (x + w)) + np.sin(13.0 * (x + w)) + w


def make_data(config: OneDConfig, rng: np.random.Generator) -> tuple[Array, Array, Array, Array]:
    """Training x, y (N,) from the two intervals (in proportion to their lengths) and test x, y (M,)."""
    lengths = np.array([b - a for a, b in TRAIN_RANGES])
    which = rng.choice(len(TRAIN_RANGES), config.train_samples, p=lengths / lengths.sum())
    low = np.array([TRAIN_RANGES[i][0] for i in which])
    x_train = low + rng.random(config.train_samples) * lengths[which]
    x_test = rng.uniform(*TEST_RANGE, config.test_samples)
    y_train = target(x_train, rng.normal(0.0, config.noise_sigma, config.train_samples))
    y_test = target(x_test, rng.normal(0.0, config.noise_sigma, config.test_samples))
    return x_train, y_train, x_test, y_test


def gaussian_nll(y: Array, mean: Array, variance: Array) -> Array:
    """Per-sample negative log likelihood of y under N(mean, variance)."""
    return 0.5 * (np.log(2.0 * math.pi * variance) + (y - mean) ** 2 / variance)


def _mlp(width: int, layers: int, dropout: float = 0.0) -> list[nn.Module]:
    modules: list[nn.Module] = []
    inputs = 1
    for _ in range(layers):
        modules += [nn.Linear(inputs, width), nn.ReLU()]
        if dropout > 0.0:
            modules.append(nn.Dropout(dropout))
        inputs = width
    return modules


class BatchedHeads(nn.Module):
    """``heads`` independent two-layer heads (width -> hidden -> 1, ReLU) evaluated as one batched product; each
    head initialised on its own as ``nn.Linear`` would be."""

    def __init__(self, width: int, hidden: int, heads: int) -> None:
        super().__init__()
        bound1, bound2 = 1.0 / math.sqrt(width), 1.0 / math.sqrt(hidden)
        self.w1 = nn.Parameter(torch.empty(heads, width, hidden).uniform_(-bound1, bound1))
        self.b1 = nn.Parameter(torch.empty(heads, 1, hidden).uniform_(-bound1, bound1))
        self.w2 = nn.Parameter(torch.empty(heads, hidden, 1).uniform_(-bound2, bound2))
        self.b2 = nn.Parameter(torch.empty(heads, 1, 1).uniform_(-bound2, bound2))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden = torch.relu(torch.matmul(features.unsqueeze(0), self.w1) + self.b1)  # (H, N, hidden)
        return (torch.matmul(hidden, self.w2) + self.b2).squeeze(-1).T  # (N, H)


class HydraOneD(nn.Module):
    """A two-layer body, ``heads`` two-layer mean heads (four layers from input to output, as the other
    networks) and optionally a two-layer variance head."""

    def __init__(self, width: int, heads: int, aleatoric: bool, head_width: int = 32) -> None:
        super().__init__()
        self.body = nn.Sequential(*_mlp(width, 2))
        self.heads = BatchedHeads(width, head_width, heads)
        self.variance = nn.Sequential(nn.Linear(width, width), nn.ReLU(), nn.Linear(width, 1)) if aleatoric else None

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        features = self.body(x)
        variance = None if self.variance is None else nn.functional.softplus(self.variance(features)).squeeze(-1)
        return self.heads(features), variance


class MeanVariance(nn.Module):
    """Four layers with a mean and (``variance``) a softplus variance output; dropout after each hidden layer."""

    def __init__(self, width: int, variance: bool, dropout: float = 0.0) -> None:
        super().__init__()
        self.body = nn.Sequential(*_mlp(width, 3, dropout))
        self.out = nn.Linear(width, 2 if variance else 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        out = self.out(self.body(x))
        return out[:, 0], (nn.functional.softplus(out[:, 1]) if out.shape[1] == 2 else None)


def _fit(model: nn.Module, loss: Callable[[], torch.Tensor], config: OneDConfig) -> None:
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    model.train()
    for _ in range(config.steps):
        optimiser.zero_grad()
        value = loss()
        value.backward()
        optimiser.step()
    model.eval()


def _nll_torch(y: torch.Tensor, mean: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
    return 0.5 * (torch.log(variance) + (y - mean) ** 2 / variance).mean()


def fit_predict(method: str, x: Array, y: Array, x_query: Array, config: OneDConfig, seed: int) -> tuple[Array, Array]:
    """Train ``method`` on (x, y) and return its mean and variance (M,) at ``x_query``."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    torch.manual_seed(seed)
    xt = torch.tensor(x, dtype=torch.float32).unsqueeze(-1)
    yt = torch.tensor(y, dtype=torch.float32)
    xq = torch.tensor(x_query, dtype=torch.float32).unsqueeze(-1)
    floor = config.min_variance
    if method in ("hydranet", "hydranet_no_aleatoric"):
        hydra = HydraOneD(config.width, config.heads, aleatoric=method == "hydranet")

        def hydra_loss() -> torch.Tensor:
            heads, variance = hydra(xt)
            targets = yt.unsqueeze(-1).expand_as(heads)
            if variance is None:
                return ((heads - targets) ** 2).mean()
            return _nll_torch(targets, heads, variance.unsqueeze(-1) + floor)

        _fit(hydra, hydra_loss, config)
        with torch.no_grad():
            heads, variance = hydra(xq)
        outputs = heads.double().numpy()
        epistemic = outputs.var(axis=1, ddof=1)
        aleatoric = 0.0 if variance is None else variance.double().numpy()
        return outputs.mean(axis=1), epistemic + aleatoric + floor
    if method == "direct":
        net = MeanVariance(config.width, variance=True)

        def direct_loss() -> torch.Tensor:
            mean, variance = net(xt)
            assert variance is not None
            return _nll_torch(yt, mean, variance + floor)

        _fit(net, direct_loss, config)
        with torch.no_grad():
            mean, variance = net(xq)
        assert variance is not None
        return mean.double().numpy(), variance.double().numpy() + floor
    if method == "dropout":
        net = MeanVariance(config.width, variance=False, dropout=config.dropout)
        _fit(net, lambda: ((net(xt)[0] - yt) ** 2).mean(), config)
        net.train()  # dropout on at test time
        with torch.no_grad():
            draws = torch.stack([net(xq)[0] for _ in range(config.samples)]).double().numpy()
        return draws.mean(axis=0), draws.var(axis=0, ddof=1) + floor
    # bagging
    generator = np.random.default_rng(seed)
    predictions = []
    for bag in range(config.bags):
        pick = generator.integers(0, len(x), len(x))
        xb, yb = xt[pick], yt[pick]
        torch.manual_seed(seed * 1000 + bag)
        net = MeanVariance(config.width, variance=False)
        _fit(net, lambda net=net, xb=xb, yb=yb: ((net(xb)[0] - yb) ** 2).mean(), config)
        with torch.no_grad():
            predictions.append(net(xq)[0].double().numpy())
    stacked = np.stack(predictions)
    return stacked.mean(axis=0), stacked.var(axis=0, ddof=1) + floor


@dataclass
class OneDResult:
    """Per method: the test NLL of each repetition (R,), split in and out of the training ranges; one
    repetition's predictions on a dense grid for the band figure."""

    nll: dict[str, list[float]] = field(default_factory=dict)
    nll_in: dict[str, list[float]] = field(default_factory=dict)
    nll_out: dict[str, list[float]] = field(default_factory=dict)
    grid: Array | None = None
    bands: dict[str, tuple[Array, Array]] = field(default_factory=dict)
    data: tuple[Array, Array, Array, Array] | None = None


def in_training_range(x: Array) -> NDArray[np.bool_]:
    return np.any([(x >= a) & (x <= b) for a, b in TRAIN_RANGES], axis=0)


def one_d_study(
    config: OneDConfig | None = None,
    repetitions: int = 20,
    seed: int = 0,
    methods: tuple[str, ...] = METHODS,
    say: Callable[[str], None] | None = None,
) -> OneDResult:
    """Every method trained ``repetitions`` times (a fresh data draw and initialisation each), scored by the mean
    test NLL; the first repetition's predictions on a grid over [-2, 2] kept for the figure."""
    config = config or OneDConfig()
    result = OneDResult()
    grid = np.linspace(*TEST_RANGE, 401)
    for r in range(repetitions):
        rng = np.random.default_rng(seed * 10_000 + r)
        data = make_data(config, rng)
        x_train, y_train, x_test, y_test = data
        inside = in_training_range(x_test)
        for method in methods:
            query = np.concatenate([x_test, grid]) if r == 0 else x_test
            mean, variance = fit_predict(method, x_train, y_train, query, config, seed=seed * 10_000 + r)
            nll = gaussian_nll(y_test, mean[: len(x_test)], variance[: len(x_test)])
            result.nll.setdefault(method, []).append(float(nll.mean()))
            result.nll_in.setdefault(method, []).append(float(nll[inside].mean()) if inside.any() else float("nan"))
            result.nll_out.setdefault(method, []).append(float(nll[~inside].mean()))
            if r == 0:
                result.bands[method] = (mean[len(x_test) :], variance[len(x_test) :])
        if r == 0:
            result.grid, result.data = grid, data
        if say:
            say(f"repetition {r + 1}/{repetitions}: " + ", ".join(f"{m} {result.nll[m][-1]:.2f}" for m in methods))
    return result
