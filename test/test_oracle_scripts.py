"""The oracles of `scripts/hydranet_validation_drives.py` and `scripts/dpc_correction_ceiling.py` (what a model without
error, or an honest one, would fuse): the errors an honest reading carries are drawn from its own covariance,
reproducibly; errorless ones are the truth."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest
from pvo_core.lie import so3_exp
from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations, rotation_errors
from pvo_pseudosensors.hydranet.infer import RotationPredictions
from scipy.spatial.transform import Rotation

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


@pytest.fixture(scope="module")
def oracle_readings():
    return runpy.run_path(str(SCRIPTS / "hydranet_validation_drives.py"), run_name="oracles")["oracle_readings"]


@pytest.fixture(scope="module")
def ceiling_corrections():
    return runpy.run_path(str(SCRIPTS / "dpc_correction_ceiling.py"), run_name="oracles")["ceiling_corrections"]


def _predictions(count: int, rng: np.random.Generator) -> tuple[RotationPredictions, np.ndarray]:
    true = np.stack([so3_exp(v) for v in rng.normal(0.0, 0.02, (count, 3))])
    estimates = np.stack([so3_exp(v) @ t for v, t in zip(rng.normal(0.0, 1e-3, (count, 3)), true, strict=True)])
    xyzw = Rotation.from_matrix(estimates).as_quat()
    sigmas = np.array([1e-3, 2e-3, 4e-3])  # rad, per axis: an anisotropic covariance, the same for every pair
    epistemic = np.tile(np.diag(sigmas**2) * 0.25, (count, 1, 1))
    aleatoric = np.tile(np.diag(sigmas**2) * 0.75, (count, 1, 1))
    frames = np.arange(1, count + 1)
    return RotationPredictions(frames - 1, frames, xyzw[:, [3, 0, 1, 2]], epistemic, aleatoric), true


def test_sampled_readings_carry_errors_drawn_from_their_covariance(oracle_readings) -> None:
    predictions, true = _predictions(4000, np.random.default_rng(1))
    sampled = oracle_readings(predictions, true, "sampled", rng=np.random.default_rng(7))
    estimates = Rotation.from_quat(sampled.quaternions[:, [1, 2, 3, 0]]).as_matrix()
    errors = rotation_errors(estimates, true)
    covariance = predictions.covariance[0]
    assert np.allclose(errors.mean(axis=0), 0.0, atol=4 * np.sqrt(np.diag(covariance) / len(errors)))
    assert np.allclose(np.cov(errors.T), covariance, rtol=0.1, atol=0.05 * covariance.max())
    assert evaluate_rotations(sampled.quaternions, sampled.covariance, true)["anees"] == pytest.approx(1.0, abs=0.06)
    assert np.array_equal(sampled.epistemic, predictions.epistemic)  # the covariances are the model's, kept
    again = oracle_readings(predictions, true, "sampled", rng=np.random.default_rng(7))
    assert np.array_equal(again.quaternions, sampled.quaternions)


def test_true_readings_are_the_truth_and_as_read_the_model(oracle_readings) -> None:
    predictions, true = _predictions(20, np.random.default_rng(2))
    exact = oracle_readings(predictions, true, "true")
    estimates = Rotation.from_quat(exact.quaternions[:, [1, 2, 3, 0]]).as_matrix()
    assert np.abs(rotation_errors(estimates, true)).max() < 1e-12
    assert oracle_readings(predictions, true, "as-read") is predictions


def test_ceiling_corrections_are_the_true_windows_or_honestly_perturbed(ceiling_corrections) -> None:
    from pvo_core.lie import se3_exp

    rng = np.random.default_rng(3)
    truth = [np.eye(4)]
    for v in rng.normal(0.0, [0.1, 0.1, 1.0, 0.01, 0.01, 0.01], (4000, 6)):
        truth.append(truth[-1] @ se3_exp(v))
    truth = np.array(truth)
    stamps = 10**9 + 10**8 * np.arange(len(truth), dtype=np.int64)
    exact = ceiling_corrections(truth, stamps, 4, 0.05, 100.0, False, "drive")
    assert len(exact) == 1000 and all(kind == "correction" for kind, _ in exact)
    first, last = exact[1][1].reference_stamp, exact[1][1].stamp
    assert (first, last) == (stamps[4], stamps[8])  # consecutive windows of 4 frames
    for k, (_, m) in enumerate(exact):
        np.testing.assert_allclose(m.transform, np.linalg.inv(truth[4 * k + 4]) @ truth[4 * k], atol=1e-9)
    np.testing.assert_allclose(np.diag(exact[0][1].covariance), [1e4] * 3 + [np.radians(0.05) ** 2] * 3)
    honest = ceiling_corrections(truth, stamps, 4, 0.05, 100.0, True, "drive")
    pairs = [(m.transform, e.transform) for (_, m), (_, e) in zip(honest, exact, strict=True)]
    errors = np.array([so3_log_of(m @ np.linalg.inv(e)) for m, e in pairs])  # Exp(phi) on the left
    assert np.allclose(errors.std(axis=0), np.radians(0.05), rtol=0.08)  # each axis drawn at the rotation sigma
    for (m, e), phi in zip(pairs, errors, strict=True):  # the translation only turned with it: no error of its own
        np.testing.assert_allclose(m[:3, 3], so3_exp(phi) @ e[:3, 3], atol=1e-9)
    again = ceiling_corrections(truth, stamps, 4, 0.05, 100.0, True, "drive")
    assert all(np.array_equal(a.transform, b.transform) for (_, a), (_, b) in zip(again, honest, strict=True))


def so3_log_of(transform: np.ndarray) -> np.ndarray:
    from pvo_core.lie import so3_log

    return so3_log(transform[:3, :3])
