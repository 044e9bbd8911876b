"""PROBE-GK's noise model: the kernel, the inverse-Wishart posterior against a hand computation, recovery of
heteroscedastic variances, the Student-t it implies, and bad models."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_frontend.probe.gk import (
    GKConfig,
    GKModel,
    NoiseModel,
    fit_static_student_t,
    sparse_kernel,
    student_t_log_density,
)
from pvo_frontend.vo.solver import RobustLoss
from scipy.stats import multivariate_t


def test_sparse_kernel_is_one_at_zero_zero_beyond_the_support_and_decreasing() -> None:
    r = np.linspace(0.0, 1.5, 151)
    k = sparse_kernel(r)
    assert k[0] == pytest.approx(1.0)
    assert np.all(k[r >= 1.0] == pytest.approx(0.0, abs=1e-12))
    assert np.all(np.diff(k[r <= 1.0]) <= 1e-12)
    assert np.all((k >= 0.0) & (k <= 1.0))


def test_posterior_equals_the_hand_computed_update() -> None:
    config = GKConfig(radius=0.5, max_neighbours=8, prior_samples=4.0, prior_sigma=(1.0, 2.0, 3.0))
    predictors = np.array([[0.0], [0.1], [0.3], [2.0]])
    errors = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [1.0, 1.0, 1.0], [9.0, 9.0, 9.0]])
    model = GKModel(("x",), predictors, errors, config, mean=np.zeros(1), std=np.ones(1))
    psi, nu = model.posterior(np.array([[0.0]]))
    weights = [sparse_kernel(np.array(d / 0.5)) for d in (0.0, 0.1, 0.3)]  # the sample at 2.0 is out of reach
    expected = 4.0 * np.diag([1.0, 4.0, 9.0]) + sum(w * np.outer(e, e) for w, e in zip(weights, errors[:3], strict=True))
    np.testing.assert_allclose(psi[0], expected)
    assert nu[0] == pytest.approx(4.0 + sum(weights))
    # leaving out the query's own sample (EM's D without (i, t))
    psi_out, nu_out = model.posterior(np.array([[0.0]]), exclude=np.array([0]))
    np.testing.assert_allclose(psi_out[0], expected - np.outer(errors[0], errors[0]))
    assert nu_out[0] == pytest.approx(nu[0] - 1.0)
    # far from every sample: the prior alone
    psi_far, nu_far = model.posterior(np.array([[10.0]]))
    np.testing.assert_allclose(psi_far[0], config.prior_scale)
    assert nu_far[0] == 4.0


def test_marginal_model_is_the_kernel_over_the_kept_predictors_alone() -> None:
    config = GKConfig(radius=0.5, max_neighbours=8, prior_samples=4.0, prior_sigma=(1.0, 2.0, 3.0))
    # sample 1 is near the query in x but far in y: the full model leaves it out, the marginal over x keeps it
    predictors = np.array([[0.0, 0.0], [0.2, 5.0], [3.0, 0.0]])
    errors = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [9.0, 9.0, 9.0]])
    model = GKModel(("x", "y"), predictors, errors, config, mean=np.zeros(2), std=np.ones(2))
    marginal = model.marginal(("x",))
    assert marginal.names == ("x",) and marginal.config == model.config
    psi, nu = marginal.posterior(np.array([[0.0]]))
    weights = [sparse_kernel(np.array(d / 0.5)) for d in (0.0, 0.2)]
    expected = 4.0 * np.diag([1.0, 4.0, 9.0]) + sum(w * np.outer(e, e) for w, e in zip(weights, errors[:2], strict=True))
    np.testing.assert_allclose(psi[0], expected)
    assert nu[0] == pytest.approx(4.0 + sum(weights))
    full_psi, full_nu = model.posterior(np.array([[0.0, 0.0]]))
    assert full_nu[0] == pytest.approx(5.0)
    np.testing.assert_allclose(full_psi[0], 4.0 * np.diag([1.0, 4.0, 9.0]) + np.outer(errors[0], errors[0]))
    with pytest.raises(ValueError, match="no predictor z"):
        model.marginal(("x", "z"))


def test_heteroscedastic_variances_are_recovered_within_20_percent() -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(0.0, 1.0, 40_000)
    sigma = np.stack([0.5 + 2.0 * x, 1.0 + 0.5 * x, 3.0 - 2.0 * x], axis=1)
    errors = sigma * rng.standard_normal((len(x), 3))
    model = GKModel(("x",), x[:, None], errors, GKConfig(radius=0.3, max_neighbours=512))
    queries = np.linspace(0.1, 0.9, 9)
    psi, nu = model.posterior(queries[:, None])
    posterior_mean = psi / (nu - 3.0 - 1.0)[:, None, None]  # the inverse-Wishart mean
    true = np.stack([0.5 + 2.0 * queries, 1.0 + 0.5 * queries, 3.0 - 2.0 * queries], axis=1) ** 2
    np.testing.assert_allclose(np.diagonal(posterior_mean, axis1=1, axis2=2), true, rtol=0.2)
    off_diagonal = posterior_mean[:, 0, 1] / np.sqrt(posterior_mean[:, 0, 0] * posterior_mean[:, 1, 1])
    assert np.all(np.abs(off_diagonal) < 0.1)


def test_noise_model_is_the_student_t_the_solver_loss_minimises() -> None:
    rng = np.random.default_rng(1)
    model = GKModel(("x",), rng.uniform(0, 1, (500, 1)), rng.standard_normal((500, 3)), GKConfig(radius=1.0, max_neighbours=50))
    noise = model.noise(np.array([[0.2], [0.7]]))
    psi, nu = model.posterior(np.array([[0.2], [0.7]]))
    np.testing.assert_allclose(noise.dof, nu - 2.0)  # nu* - d + 1
    np.testing.assert_allclose(noise.scale, psi / noise.dof[:, None, None])
    errors = rng.standard_normal((2, 3))
    expected = [multivariate_t(loc=np.zeros(3), shape=noise.scale[i], df=noise.dof[i]).logpdf(errors[i]) for i in range(2)]
    np.testing.assert_allclose(student_t_log_density(errors, noise), expected)
    # eq. 4.25: the solver's Student-t loss on the whitened norm is (nu* + 1)/2 log(1 + e^T Psi*^-1 e)
    loss = RobustLoss("student_t", noise.dof)
    eps = np.sqrt(np.einsum("ni,nij,nj->n", errors, noise.information, errors))
    np.testing.assert_allclose(
        loss.rho(eps), 0.5 * (nu + 1.0) * np.log1p(np.einsum("ni,nij,nj->n", errors, np.linalg.inv(psi), errors))
    )
    assert isinstance(noise, NoiseModel) and np.all(np.isfinite(noise.covariance))


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"radius": 0.0}, "radius must be positive"),
        ({"max_neighbours": 0}, "max_neighbours must be >= 1"),
        ({"prior": "nominal", "prior_samples": 2.0}, "prior_samples must be > 2"),
        ({"prior": "nominal", "prior_sigma": (1.0, 1.0)}, "prior_sigma needs 3 positive values"),
        ({"prior": "flat"}, "prior must be one of fitted, nominal"),
        ({"prior_dof": 0.0}, "prior_dof must be positive"),
        ({"prior_samples": 4.0}, "prior_samples and prior_sigma come together"),
    ],
)
def test_bad_configuration_is_one_clear_error(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        GKConfig(**values)


def test_bad_training_samples_are_refused() -> None:
    with pytest.raises(ValueError, match=r"predictors must be \(M, 2\)"):
        GKModel(("a", "b"), np.zeros((4, 1)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"errors must be \(4, 3\)"):
        GKModel(("a",), np.zeros((4, 1)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="must be finite"):
        GKModel(("a",), np.array([[0.0], [np.nan]]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="must be finite"):
        GKModel(("a",), np.zeros((2, 1)), np.array([[0.0, 0.0, np.inf], [0.0, 0.0, 0.0]]))


def test_static_student_t_fit_recovers_the_scale_of_student_t_draws() -> None:
    shape = np.array([[0.09, 0.0, 0.03], [0.0, 0.02, 0.0], [0.03, 0.0, 0.06]])
    draws = multivariate_t(loc=np.zeros(3), shape=shape, df=3.0, seed=2).rvs(size=60_000)
    np.testing.assert_allclose(fit_static_student_t(draws, 3.0), shape, atol=0.06 * shape.max())
    # the sample covariance of a dof-3 Student-t is three times its scale: the fit is not the covariance
    assert np.cov(draws.T)[0, 0] > 2.0 * fit_static_student_t(draws, 3.0)[0, 0]


def test_fitted_prior_is_the_static_student_t_where_the_model_has_no_neighbour() -> None:
    rng = np.random.default_rng(3)
    sigma = np.array([0.25, 0.13, 0.2])
    errors = multivariate_t(loc=np.zeros(3), shape=np.diag(sigma**2), df=3.0, seed=4).rvs(size=20_000)
    model = GKModel(("x",), rng.uniform(0.0, 1.0, (len(errors), 1)), errors, GKConfig(prior_dof=3.0))
    assert model.config.prior == "fitted" and model.config.prior_samples == pytest.approx(5.0)
    far = model.noise(np.array([[50.0]]))  # out of every sample's kernel support
    assert far.dof[0] == pytest.approx(3.0)
    static = fit_static_student_t(errors, 3.0)
    np.testing.assert_allclose(far.scale[0], np.diag(np.diag(static)))
    np.testing.assert_allclose(np.sqrt(np.diag(far.scale[0])), sigma, rtol=0.05)
    # the nominal prior keeps its n virtual samples of (1, 1, 2) px whatever the errors
    nominal = GKModel(("x",), rng.uniform(0.0, 1.0, (len(errors), 1)), errors, GKConfig(prior="nominal"))
    np.testing.assert_allclose(nominal.noise(np.array([[50.0]])).scale[0], 3.0 * np.diag([1.0, 1.0, 4.0]))
    with pytest.raises(ValueError, match="a fitted prior needs training errors"):
        GKModel(("x",), np.zeros((2, 1)), np.zeros((2, 3)))
