"""Sun-BCNN's evaluation against the truth: Table 5.1's figures, the calibration curve and Method I/II, each
checked on predictions whose errors are known by construction."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.sun import CovarianceCalibration, zenith_azimuth_to_vector
from pvo_pseudosensors.sun_bcnn.evaluation import calibration_curve, evaluate_predictions, method_comparison, predicted_sigma
from pvo_pseudosensors.sun_bcnn.infer import Draws


def rows_for(vectors: np.ndarray, zenith: np.ndarray, azimuth: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    return np.column_stack([np.arange(len(vectors)), vectors, zenith, azimuth, covariance.reshape(-1, 4)])


def tangent_perturbed(truth: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each unit vector moved by an isotropic Gaussian tangent error of std ``sigma`` per axis (rad)."""
    helper = np.where(np.abs(truth[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(truth, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(truth, e1)
    step = sigma[:, None] * (rng.standard_normal((len(truth), 1)) * e1 + rng.standard_normal((len(truth), 1)) * e2)
    moved = truth + step
    return moved / np.linalg.norm(moved, axis=1, keepdims=True)


def test_table_figures_for_a_known_zenith_offset() -> None:
    zenith = np.radians(np.linspace(30.0, 70.0, 5))
    azimuth = np.radians(np.linspace(-150.0, 170.0, 5))
    truth = zenith_azimuth_to_vector(zenith, azimuth)
    offset = np.radians(np.array([1.0, 2.0, 3.0, 4.0, 50.0]))
    predicted = zenith_azimuth_to_vector(zenith + offset, azimuth)
    covariance = np.tile(np.diag([np.radians(2.0) ** 2, 1.0]), (5, 1, 1))
    figures = evaluate_predictions(rows_for(predicted, zenith + offset, azimuth, covariance), truth)
    assert figures["images"] == 5
    assert figures["vector_median_deg"] == pytest.approx(3.0, abs=1e-9)  # a zenith step is a vector angle
    assert figures["zenith_mean_deg"] == pytest.approx(12.0, abs=1e-9)
    assert figures["azimuth_mean_deg"] == pytest.approx(0.0, abs=1e-9)
    nees = (np.degrees(offset) / 2.0) ** 2
    assert figures["anees"] == pytest.approx(nees.mean() / 2.0)
    assert figures["filtered_images"] == 4  # 50 deg is beyond cosine distance 0.3
    assert figures["anees_filtered"] == pytest.approx(nees[:4].mean() / 2.0)


def test_predicted_sigma_of_an_isotropic_tangent_covariance() -> None:
    zenith = np.radians(np.array([20.0, 45.0, 80.0]))
    sigma = np.radians(np.array([1.0, 5.0, 10.0]))
    covariance = np.stack([np.diag([s**2, s**2 / np.sin(z) ** 2]) for s, z in zip(sigma, zenith, strict=True)])
    rows = rows_for(zenith_azimuth_to_vector(zenith, 0 * zenith), zenith, 0 * zenith, covariance)
    np.testing.assert_allclose(predicted_sigma(rows), sigma)


def test_calibration_curve_follows_the_diagonal_for_calibrated_errors_and_reads_overconfidence() -> None:
    rng = np.random.default_rng(3)
    n = 8000
    zenith, azimuth = rng.uniform(0.4, 1.3, n), rng.uniform(-np.pi, np.pi, n)
    truth = zenith_azimuth_to_vector(zenith, azimuth)
    sigma = np.radians(rng.uniform(0.5, 8.0, n))
    predicted = tangent_perturbed(truth, sigma, rng)
    covariance = np.stack([np.diag([s**2, s**2 / np.sin(z) ** 2]) for s, z in zip(sigma, zenith, strict=True)])
    rows = rows_for(predicted, zenith, azimuth, covariance)
    said, actual = calibration_curve(rows, truth, bins=8)
    assert len(said) == 8 and np.all(np.diff(said) > 0)
    np.testing.assert_allclose(actual, said, rtol=0.1)
    # the same errors with half the stated sigma: the curve lies at twice the diagonal
    overconfident = rows.copy()
    overconfident[:, 6:10] /= 4.0
    said_half, actual_half = calibration_curve(overconfident, truth, bins=8)
    np.testing.assert_allclose(actual_half / said_half, 2.0, rtol=0.1)
    # one bin by hand: the RMS angle over sqrt 2 of the images with the smallest stated sigma
    first = np.argsort(sigma, kind="stable")[: n // 8]
    angle = np.arccos(np.clip(np.sum(predicted[first] * truth[first], axis=1), -1.0, 1.0))
    assert actual[0] == pytest.approx(np.degrees(np.sqrt(np.mean(angle**2) / 2.0)), rel=1e-6)


def test_method_comparison_on_draws_from_the_truths_distribution() -> None:
    """Draws and the truth from one distribution: the mean of S draws misses the truth by the spread times
    sqrt(1 + 1/S), and the inverse of a sample covariance of S draws over p = 2 angles is (S - 1)/(S - p - 2)
    times the true inverse on average (inverse Wishart), so ANEES = (1 + 1/S)(S - 1)/(S - 4)."""
    rng = np.random.default_rng(5)
    n, samples = 3000, 25
    zenith, azimuth = rng.uniform(0.5, 1.2, n), rng.uniform(-2.5, 2.5, n)  # away from the azimuth cut
    centre = zenith_azimuth_to_vector(zenith, azimuth)
    sigma = np.full(n, np.radians(3.0))
    draws = np.stack([tangent_perturbed(centre, sigma, rng) for _ in range(samples)])
    truth = tangent_perturbed(centre, sigma, rng)
    table = method_comparison(Draws(draws, None), truth)
    assert set(table) == {"Method I", "Method II"}
    expected_anees = (1 + 1 / samples) * (samples - 1) / (samples - 4)
    # the vector error of an isotropic tangent error: Rayleigh with scale sigma * sqrt(1 + 1/S)
    expected_median = np.degrees(sigma[0]) * np.sqrt(1 + 1 / samples) * np.sqrt(2 * np.log(2))
    for row in table.values():
        assert row["anees_cov_Method I"] == pytest.approx(expected_anees, rel=0.08)
        assert row["anees_cov_Method II"] == pytest.approx(expected_anees, rel=0.08)
        assert row["vector_median_deg"] == pytest.approx(expected_median, rel=0.08)
    assert table["Method I"]["vector_mean_deg"] == pytest.approx(table["Method II"]["vector_mean_deg"], rel=0.02)
    # tau^-1 I added: per image the spread is diag(s², s²/sin² zenith) and the stated covariance that plus
    # tau^-1 I, so the NEES is about tr((C + tau^-1 I)^-1 (1 + 1/S) C) / 2
    tau_inverse = sigma[0] ** 2
    spread = np.stack([np.full(n, sigma[0] ** 2), sigma[0] ** 2 / np.sin(zenith) ** 2], axis=1)
    expected_widened = np.mean(np.sum((1 + 1 / samples) * spread / (spread + tau_inverse), axis=1)) / 2.0
    widened = method_comparison(Draws(draws, None), truth, CovarianceCalibration(tau=1.0 / tau_inverse))
    for row in widened.values():
        assert row["anees_cov_Method II"] == pytest.approx(expected_widened, rel=0.08)


def test_method_two_mean_fails_across_the_azimuth_cut_as_the_text_has_it() -> None:
    """Samples on both sides of azimuth +-pi: Method I's vector mean is right, Method II's averaged
    azimuth points the other way (the thesis's Method II, kept as written)."""
    zenith = np.full(2, 1.0)
    draws = zenith_azimuth_to_vector(zenith, np.array([np.pi - 0.01, -np.pi + 0.01]))[:, None, :]
    truth = zenith_azimuth_to_vector(np.array([1.0]), np.array([np.pi]))
    table = method_comparison(Draws(draws, None), truth)
    assert table["Method I"]["vector_mean_deg"] < 0.1
    assert table["Method II"]["vector_mean_deg"] > 90.0


def test_a_cards_fusion_settings_are_read_and_a_foreign_entry_is_named() -> None:
    from pvo_pseudosensors.learning.checkpoint import ModelCard
    from pvo_pseudosensors.sun_bcnn.infer import card_fusion, fusion_arguments

    from pvo_fusion.config import from_flat

    card = ModelCard("sun-bcnn", {}, {}, calibration={"tau": 4.0})
    assert card_fusion(card) == {}  # a card without the block: readings fused as independent
    offset = {"inputs.sun.bias_sigma": [0.25, 0.25], "inputs.sun.bias_walk_sigma": [0.01, 0.01]}
    card.calibration["fusion"] = offset
    assert card_fusion(card) == offset
    assert from_flat(card_fusion(card)).inputs.sun.has_bias  # what the demo and the experiment hand to the fusion
    assert fusion_arguments(offset) == "-p inputs.sun.bias_sigma:=[0.25,0.25] -p inputs.sun.bias_walk_sigma:=[0.01,0.01]"
    assert fusion_arguments({"inputs.sun.huber_k": 1.5, "inputs.sun.enabled": True}) == (
        "-p inputs.sun.huber_k:=1.5 -p inputs.sun.enabled:=True"  # scalars too: a card may set any sun parameter
    )
    card.calibration["fusion"] = {"inputs.vo.covariance_scale": [2.0] * 6}
    with pytest.raises(ValueError, match="'inputs.vo.covariance_scale' is not a fusion parameter of the sun"):
        card_fusion(card)
    card.calibration["fusion"] = [0.25, 0.01]
    with pytest.raises(ValueError, match="calibration.fusion must be a mapping"):
        card_fusion(card)
