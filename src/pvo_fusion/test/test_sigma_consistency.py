"""`sigma_consistency`: a VO's e²/σ² by the size of its own σ, on synthetic drives whose VO errs as stated — as its
covariance says, and growing faster than it says — against a direct per-pair computation."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.lie import se3_exp, se3_inverse, se3_log
from pvo_fusion.calibration import CONSISTENCY_EDGES, CalibrationSequence, sigma_consistency

PAIRS = 6000


def drive(seed: int, growth: float, lost: tuple[int, ...] = ()) -> CalibrationSequence:
    """A drive of PAIRS frame pairs: each reported covariance diagonal with σ drawn per pair (log-normal about a base,
    so that a few pairs report several times the usual σ, as a VO does), each VO motion the true one perturbed on the
    left by noise of σ·(σ/σ_base)^growth."""
    rng = np.random.default_rng(seed)
    base = np.array([0.02, 0.01, 0.03, 3e-4, 6e-4, 3e-4])
    truth = [np.eye(4)]
    motions, covariances = [], []
    for k in range(PAIRS):
        true_motion = se3_exp(np.concatenate([[0.0, 0.0, 1.0], rng.normal(0.0, 0.01, 3)]))  # T_k-1,k, 1 m ahead
        truth.append(truth[-1] @ true_motion)
        sigma = base * np.exp(rng.normal(0.0, 0.6, 6))
        actual = sigma * (sigma / base) ** growth
        noise = rng.normal(0.0, actual)
        motions.append(se3_exp(noise) @ se3_inverse(true_motion))  # T_k,k-1 with a left error
        covariances.append(np.diag(sigma**2) if k not in lost else np.eye(6) * 9999.0)
    return CalibrationSequence(f"drive{seed}", np.array(truth), np.array(motions), np.array(covariances))


def direct(sequences: list[CalibrationSequence], scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ρ, mean e²/σ² and counts per axis and bin, pair by pair (loops, not the library's vectorised binning)."""
    errors, variances = [], []
    for seq in sequences:
        for k, (motion, covariance) in enumerate(zip(seq.motions, seq.covariances, strict=True)):
            if covariance.max() >= 1000.0:
                continue
            truth = se3_inverse(seq.ground_truth[k + 1]) @ seq.ground_truth[k]
            errors.append(se3_log(motion @ se3_inverse(truth)))
            variances.append(np.diag(covariance) * scale)
    e, v = np.array(errors), np.array(variances)
    rho = np.quantile(np.sqrt(v), 0.9, axis=0)
    bins = len(CONSISTENCY_EDGES) - 1
    sums, counts = np.zeros((6, bins)), np.zeros((6, bins), dtype=int)
    for pair in range(len(e)):
        for axis in range(6):
            r = np.sqrt(v[pair, axis]) / rho[axis]
            b = next(i for i in range(bins) if CONSISTENCY_EDGES[i] <= r < CONSISTENCY_EDGES[i + 1])
            sums[axis, b] += e[pair, axis] ** 2 / v[pair, axis]
            counts[axis, b] += 1
    with np.errstate(invalid="ignore"):
        return rho, sums / counts, counts


def test_a_vo_that_errs_as_it_says_reads_one_in_every_bin() -> None:
    consistency = sigma_consistency([drive(1, 0.0), drive(2, 0.0)])
    filled = consistency.counts >= 100
    assert filled[:, :5].all()  # every bin up to 2.5 ρ
    # the mean of n χ²₁ draws has a standard deviation of √(2/n): every bin within 4 of them of 1
    deviation = np.abs(consistency.mean_nees[filled] - 1.0) / np.sqrt(2.0 / consistency.counts[filled])
    assert deviation.max() < 4.0
    assert consistency.counts.sum(axis=1).tolist() == [2 * PAIRS] * 6


def test_an_error_growing_faster_than_sigma_shows_in_the_high_bins_as_the_direct_computation_gives() -> None:
    sequences = [drive(3, 1.0, lost=(5, 17))]
    scale = np.array([2.0, 1.0, 1.0, 0.5, 1.0, 1.0])
    consistency = sigma_consistency(sequences, scale)
    rho, means, counts = direct(sequences, scale)
    np.testing.assert_allclose(consistency.reference, rho, rtol=1e-12)
    np.testing.assert_array_equal(consistency.counts, counts)
    np.testing.assert_allclose(consistency.mean_nees, means, rtol=1e-9, equal_nan=True)
    assert consistency.counts[0].sum() == PAIRS - 2  # the lost frames carry no information: left out
    # error ∝ σ²: e²/σ² grows as (σ/base)², so the bins above ρ read several times the bins below it
    assert np.all(consistency.mean_nees[:, 4] > 3.0 * consistency.mean_nees[:, 1])


def test_bad_input_is_a_clear_error() -> None:
    sequences = [drive(4, 0.0)]
    with pytest.raises(ValueError, match="6 positive variance scales"):
        sigma_consistency(sequences, np.ones(5))
    with pytest.raises(ValueError, match="quantile in"):
        sigma_consistency(sequences, quantile=1.0)
    with pytest.raises(ValueError, match="from 0 to inf"):
        sigma_consistency(sequences, edges=(0.5, 1.0, np.inf))
    with pytest.raises(ValueError, match="carries no covariances"):
        sigma_consistency([CalibrationSequence("bare", sequences[0].ground_truth, sequences[0].motions, None)])
    every_lost = CalibrationSequence(
        "lost", sequences[0].ground_truth, sequences[0].motions, np.tile(np.eye(6) * 9999.0, (PAIRS, 1, 1))
    )
    with pytest.raises(ValueError, match="not lost"):
        sigma_consistency([every_lost])
