"""HydraNet's one-dimensional study: eq. 7.7's data, the Gaussian NLL, and each estimator's uncertainty
growing away from its training data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from pvo_pseudosensors.hydranet.oned import (
    METHODS,
    OneDConfig,
    fit_predict,
    gaussian_nll,
    in_training_range,
    make_data,
    one_d_study,
    target,
)
from scipy.stats import norm

TINY = OneDConfig(train_samples=150, test_samples=40, width=12, heads=4, bags=2, samples=8, steps=150)


def test_data_follow_eq_7_7_on_the_two_training_intervals() -> None:
    x_train, y_train, x_test, _ = make_data(OneDConfig(), np.random.default_rng(0))
    assert len(x_train) == 1000 and len(x_test) == 100
    assert np.all(in_training_range(x_train)) and ((x_train > 0.6) & (x_train < 0.8)).sum() == 0
    assert x_test.min() >= -2.0 and x_test.max() <= 2.0 and (~in_training_range(x_test)).sum() > 80
    residual = y_train - target(x_train, 0.0 * x_train)  # w enters inside the sines too: |dy/dw| <= 19
    assert abs(residual.mean()) < 0.05 and residual.std() < 19 * 0.03
    assert target(np.array([0.0]), np.array([0.0]))[0] == 0.0


def test_gaussian_nll_is_the_negative_log_density() -> None:
    y, mean, variance = np.array([0.3, -1.0]), np.array([0.0, 0.5]), np.array([0.04, 2.0])
    np.testing.assert_allclose(gaussian_nll(y, mean, variance), -norm.logpdf(y, mean, np.sqrt(variance)))


@pytest.mark.parametrize("method", METHODS)
def test_each_method_predicts_and_its_epistemic_uncertainty_grows_out_of_distribution(method: str) -> None:
    x_train, y_train, _, _ = make_data(TINY, np.random.default_rng(1))
    inside, outside = np.linspace(0.05, 0.55, 20), np.concatenate([np.linspace(-2, -1.5, 10), np.linspace(1.5, 2, 10)])
    mean, variance = fit_predict(method, x_train, y_train, np.concatenate([inside, outside]), TINY, seed=1)
    assert mean.shape == variance.shape == (40,) and np.all(np.isfinite(mean)) and np.all(variance > 0)
    if method != "direct":  # an epistemic spread grows away from the data; a regressed variance need not (§7.4.2)
        assert variance[20:].mean() > variance[:20].mean()


def test_a_network_trained_on_the_data_follows_the_target_inside_the_training_range() -> None:
    x_train, y_train, _, _ = make_data(TINY, np.random.default_rng(1))
    inside = np.linspace(0.05, 0.55, 20)
    mean, _ = fit_predict("direct", x_train, y_train, inside, replace(TINY, steps=600), seed=1)
    truth = target(inside, 0.0 * inside)
    assert np.sqrt(np.mean((mean - truth) ** 2)) < 0.5 * np.std(truth)


def test_study_is_deterministic_and_scores_every_method() -> None:
    config = replace(TINY, steps=20)
    a = one_d_study(config, repetitions=2, seed=3)
    b = one_d_study(config, repetitions=2, seed=3)
    assert set(a.nll) == set(METHODS) and all(len(v) == 2 for v in a.nll.values())
    assert a.nll == b.nll
    assert a.grid is not None and all(m in a.bands for m in METHODS)
    with pytest.raises(ValueError, match="unknown method"):
        fit_predict("ensemble", np.zeros(3), np.zeros(3), np.zeros(2), config, 0)
