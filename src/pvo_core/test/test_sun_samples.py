"""Sun-BCNN's MC estimates (Method I mean, Method II covariance) and angular errors against direct computations."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.sun import angular_errors, sample_mean_and_covariance, zenith_azimuth_to_vector


def test_method_two_covariance_is_the_sample_covariance_of_the_angles() -> None:
    rng = np.random.default_rng(0)
    zenith = 1.0 + rng.normal(0, 0.05, 200)
    azimuth = 0.3 + rng.normal(0, 0.1, 200)
    samples = zenith_azimuth_to_vector(zenith, azimuth)[:, None, :]  # (S, 1, 3)
    mean, covariance = sample_mean_and_covariance(samples)
    expected = np.cov(np.vstack([zenith, azimuth]))  # about the sample means, which the mean direction matches closely
    np.testing.assert_allclose(covariance[0], expected, rtol=0.05, atol=1e-5)
    np.testing.assert_allclose(mean[0], zenith_azimuth_to_vector(1.0, 0.3), atol=0.02)
    _, with_tau = sample_mean_and_covariance(samples, tau=100.0)
    np.testing.assert_allclose(with_tau[0] - covariance[0], np.eye(2) / 100.0, atol=1e-12)


def test_azimuth_is_wrapped_about_the_mean() -> None:
    azimuth = np.array([np.pi - 0.01, -np.pi + 0.01, np.pi - 0.02, -np.pi + 0.02])
    samples = zenith_azimuth_to_vector(np.full(4, 1.2), azimuth)[:, None, :]
    _, covariance = sample_mean_and_covariance(samples)
    assert covariance[0, 1, 1] < 1e-3  # not ~pi^2: the samples lie 0.04 rad apart across the cut


def test_angular_errors() -> None:
    truth = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    predicted = np.array([[np.sin(0.1), 0.0, np.cos(0.1)], [0.0, -np.cos(0.2), np.sin(0.2)]])
    errors = angular_errors(predicted, truth)
    np.testing.assert_allclose(errors["vector"], [0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(errors["azimuth"][0], 0.1, atol=1e-12)  # x towards z: azimuth atan2(sx, sz)
    np.testing.assert_allclose(errors["zenith"][1], 0.2, atol=1e-12)  # zenith acos(-sy)


def test_bad_sample_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="samples must be"):
        sample_mean_and_covariance(np.zeros((1, 4, 3)))


def test_calibrated_tau_gives_the_target_anees() -> None:
    from pvo_core.sun import calibrate_tau

    rng = np.random.default_rng(1)
    covariance = np.tile(np.diag([1e-4, 4e-4]), (500, 1, 1))  # overconfident: the errors are larger
    residuals = rng.normal(0, 0.05, (500, 2))
    tau = calibrate_tau(residuals, covariance)
    widened = covariance + np.eye(2) / tau
    anees = np.mean(np.einsum("ni,nij,nj->n", residuals, np.linalg.inv(widened), residuals)) / 2.0
    assert anees == pytest.approx(1.0, rel=1e-6)
    assert 1.0 / tau == pytest.approx(0.05**2, rel=0.25)  # it recovers most of the missing variance
    assert calibrate_tau(residuals, covariance * 1e4) == np.inf  # already wide enough: nothing to add


def test_covariance_scale_narrows_a_too_wide_covariance() -> None:
    from pvo_core.sun import CovarianceCalibration, anees, calibrate_scale

    rng = np.random.default_rng(2)
    true_sigma = np.array([0.02, 0.05])
    residuals = rng.normal(0, 1, (4000, 2)) * true_sigma
    stated = np.tile(np.diag((2.0 * true_sigma) ** 2), (4000, 1, 1))  # four times the variance the errors have
    everything = np.ones(4000, dtype=bool)
    scale = calibrate_scale(residuals, stated, everything)
    assert scale == pytest.approx(0.25, rel=0.05)
    assert anees(residuals, CovarianceCalibration(scale=scale).apply(stated)) == pytest.approx(1.0, rel=1e-9)

    # a filter that drops the largest errors: the two ANEES end symmetric about 1 (their geometric mean is 1)
    keep = np.linalg.norm(residuals / true_sigma, axis=1) < 2.0
    scale = calibrate_scale(residuals, stated, keep)
    narrowed = CovarianceCalibration(scale=scale).apply(stated)
    assert anees(residuals[keep], narrowed[keep]) < 1.0 < anees(residuals, narrowed)
    assert np.sqrt(anees(residuals[keep], narrowed[keep]) * anees(residuals, narrowed)) == pytest.approx(1.0, rel=1e-9)

    assert calibrate_scale(residuals, stated / 16.0, everything) == 1.0  # overconfident: tau's job, not the scale's
    with pytest.raises(ValueError, match="no residual to calibrate the covariance scale on"):
        calibrate_scale(residuals, stated, ~everything)


def test_covariance_calibration_applies_scale_then_tau() -> None:
    from pvo_core.sun import UNCALIBRATED, CovarianceCalibration

    covariance = np.array([[[4.0, 1.0], [1.0, 9.0]]])
    np.testing.assert_allclose(CovarianceCalibration(tau=2.0, scale=0.5).apply(covariance), [[[2.5, 0.5], [0.5, 5.0]]])
    np.testing.assert_array_equal(UNCALIBRATED.apply(covariance), covariance)
    assert CovarianceCalibration.from_mapping({"tau": 4.0}) == CovarianceCalibration(tau=4.0, scale=1.0)
    assert CovarianceCalibration.from_mapping({}) == UNCALIBRATED
    for bad, message in (({"scale": 0.0}, "scale must be positive"), ({"tau": float("nan")}, "tau must be positive")):
        with pytest.raises(ValueError, match=message):
            CovarianceCalibration.from_mapping(bad)


@pytest.mark.parametrize(("zenith", "kappa"), [(1.2, 400.0), (0.5, 2000.0), (2.4, 900.0)])
def test_aleatoric_covariance_matches_von_mises_fisher_draws(zenith: float, kappa: float) -> None:
    from pvo_core.sun import aleatoric_covariance, unit_zenith_azimuth, wrap_angle
    from scipy.stats import vonmises_fisher

    mean = zenith_azimuth_to_vector(zenith, 0.7)
    draws = vonmises_fisher(mean, kappa).rvs(20000, random_state=np.random.default_rng(3))
    z, a = unit_zenith_azimuth(draws)
    empirical = np.cov(np.vstack([z - zenith, wrap_angle(a - 0.7)]))
    predicted = aleatoric_covariance(mean[None], np.array([1.0 / kappa]))[0]
    np.testing.assert_allclose(np.diag(predicted), np.diag(empirical), rtol=0.05)
    assert abs(empirical[0, 1]) < 0.05 * np.sqrt(empirical[0, 0] * empirical[1, 1])  # no correlation
    assert predicted[0, 1] == predicted[1, 0] == 0.0


def test_method_one_covariance_is_the_propagated_vector_covariance() -> None:
    from pvo_core.sun import unit_zenith_azimuth, vector_covariance_in_angles, zenith_azimuth_jacobian

    rng = np.random.default_rng(4)
    mean = zenith_azimuth_to_vector(1.1, -0.6)
    # the Jacobian against central differences of eq. 5.7
    step = 1e-6
    numeric = np.zeros((2, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = step
        plus, minus = unit_zenith_azimuth(mean + d), unit_zenith_azimuth(mean - d)
        numeric[:, i] = (np.array(plus) - np.array(minus)) / (2 * step)
    np.testing.assert_allclose(zenith_azimuth_jacobian(mean[None])[0], numeric, atol=1e-6)
    # small spreads: Method I and Method II covariances agree
    samples = zenith_azimuth_to_vector(1.1 + rng.normal(0, 0.01, 500), -0.6 + rng.normal(0, 0.02, 500))[:, None, :]
    method_one = vector_covariance_in_angles(samples, mean[None])[0]
    _, method_two = sample_mean_and_covariance(samples)
    np.testing.assert_allclose(method_one, method_two[0], rtol=0.03, atol=1e-7)


def test_method_two_mean_averages_the_angles_as_numbers() -> None:
    from pvo_core.sun import angle_mean

    samples = zenith_azimuth_to_vector(np.array([1.0, 1.2]), np.array([0.2, 0.4]))[:, None, :]
    np.testing.assert_allclose(angle_mean(samples)[0], zenith_azimuth_to_vector(1.1, 0.3), atol=1e-12)
    across = zenith_azimuth_to_vector(np.array([1.0, 1.0]), np.array([np.pi - 0.1, -np.pi + 0.1]))[:, None, :]
    np.testing.assert_allclose(angle_mean(across)[0], zenith_azimuth_to_vector(1.0, 0.0), atol=1e-12)  # the wrong side
