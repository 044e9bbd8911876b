"""The simulated sun sensor: its mean angular error, covariance consistency, cadence and determinism."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.sun import vector_to_zenith_azimuth
from pvo_pseudosensors.simulated_sun import SimulatedSunConfig, SimulatedSunSensor, perturb_direction

TRUTH = np.array([0.2, -0.7, 0.6]) / np.linalg.norm([0.2, -0.7, 0.6])


@pytest.mark.parametrize("mean_deg", [5.0, 10.0, 20.0, 30.0])
def test_mean_angular_error_is_the_requested_one(mean_deg: float) -> None:
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=mean_deg, every_n=1, seed=3))
    angles = []
    for _ in range(20000):
        direction, _ = sensor.measure(TRUTH)
        assert abs(np.linalg.norm(direction) - 1.0) < 1e-12
        angles.append(np.degrees(np.arccos(np.clip(direction @ TRUTH, -1.0, 1.0))))
    assert np.mean(angles) == pytest.approx(mean_deg, rel=0.03)


def test_zero_noise_returns_the_truth_with_the_floor_covariance() -> None:
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=0.0, every_n=1, covariance_floor_deg=1.0))
    direction, covariance = sensor.measure(TRUTH)
    np.testing.assert_allclose(direction, TRUTH, atol=1e-15)
    assert np.sqrt(covariance[0, 0]) == pytest.approx(np.radians(1.0) / np.sqrt(np.pi / 2))


def test_reported_covariance_is_consistent_with_the_errors() -> None:
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=5.0, every_n=1, seed=11))
    true_za = np.array(vector_to_zenith_azimuth(TRUTH))
    nees = []
    for _ in range(5000):
        direction, covariance = sensor.measure(TRUTH)
        error = np.array(vector_to_zenith_azimuth(direction)) - true_za
        error[1] = (error[1] + np.pi) % (2 * np.pi) - np.pi
        nees.append(error @ np.linalg.solve(covariance, error))
    assert np.mean(nees) / 2.0 == pytest.approx(1.0, abs=0.08)


def test_every_nth_input_from_the_first_and_seeded() -> None:
    config = SimulatedSunConfig(mean_error_deg=10.0, every_n=10, seed=5)
    a, b = SimulatedSunSensor(config), SimulatedSunSensor(config)
    out_a = [a.measure(TRUTH) for _ in range(35)]
    out_b = [b.measure(TRUTH) for _ in range(35)]
    assert [i for i, r in enumerate(out_a) if r is not None] == [0, 10, 20, 30]
    for ra, rb in zip(out_a, out_b, strict=True):
        if ra is not None:
            np.testing.assert_array_equal(ra[0], rb[0])
    other = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=10.0, every_n=10, seed=6)).measure(TRUTH)
    assert not np.allclose(other[0], out_a[0][0])


def test_near_the_zenith_the_azimuth_variance_is_capped() -> None:
    up = np.array([0.0, -1.0, 0.0])
    sensor = SimulatedSunSensor(SimulatedSunConfig(mean_error_deg=0.0, every_n=1))
    _, covariance = sensor.measure(up)
    assert covariance[1, 1] == pytest.approx(np.pi**2)
    tilted = perturb_direction(up, 0.0, np.random.default_rng(0))
    np.testing.assert_allclose(tilted, up)


def test_bad_input_and_configuration() -> None:
    sensor = SimulatedSunSensor()
    with pytest.raises(ValueError, match="not a finite non-zero"):
        sensor.measure([np.nan, 0.0, 1.0])
    with pytest.raises(ValueError, match="mean_error_deg"):
        SimulatedSunConfig(mean_error_deg=-1.0)
    with pytest.raises(ValueError, match="every_n"):
        SimulatedSunConfig(every_n=0)


def test_yaml_defaults_equal_the_typed_config() -> None:
    from pathlib import Path

    import yaml
    from pvo_core.config import flatten, from_flat

    path = Path(__file__).resolve().parents[1] / "config" / "simulated_sun.yaml"
    params = yaml.safe_load(path.read_text())["simulated_sun"]["ros__parameters"]
    assert set(params) == set(flatten(SimulatedSunConfig()))
    assert from_flat(params, SimulatedSunConfig()) == SimulatedSunConfig()
