"""HydraNet's feature density: its distances against numpy's Mahalanobis distances, gamma against a case solved by
hand, the widened covariance through prediction, the card round trip and its bad inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_pseudosensors.hydranet.config import HydraNetConfig
from pvo_pseudosensors.hydranet.density import DENSITY_FILE, MAX_GAMMA, FeatureDensity, fit_density, fit_gamma
from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask, predict_rotations
from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card, save_model, write_card

TINY = HydraNetConfig(height=48, width=144, widths=(8, 16, 16), feature=16, heads=4, head_hidden=16, head_dropout=0.1)


def _gaussian(count: int, seed: int, features: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    mixing = rng.normal(size=(features, features)) * np.linspace(0.2, 3.0, features)
    mean = rng.normal(size=features)
    return mean + rng.normal(size=(count, features)) @ mixing.T, mean, mixing


def test_distances_are_the_mahalanobis_distances_of_the_fitted_gaussian() -> None:
    drawn, _, _ = _gaussian(7000, 0)
    fitting, validation = drawn[:5000], drawn[5000:]  # one law
    density = fit_density(torch.from_numpy(fitting), torch.from_numpy(validation), shrinkage=0.0)
    covariance = np.cov(fitting.T)
    centred = validation - fitting.mean(0)
    expected = np.einsum("ni,ij,nj->n", centred, np.linalg.inv(covariance), centred)
    np.testing.assert_allclose(density.distances(torch.from_numpy(validation)).numpy(), expected, rtol=1e-8)
    assert density.median == pytest.approx(np.median(expected))
    assert density.threshold == pytest.approx(np.quantile(expected / np.median(expected), 0.95))
    assert abs(expected.mean() / 6.0 - 1.0) < 0.1  # chi-square with 6 degrees of freedom
    # eight standard deviations along the direction the data barely moves along: d^2 = 64, far beyond the threshold;
    # gamma 0 widens nothing yet
    values, vectors = np.linalg.eigh(covariance)
    far = torch.from_numpy(fitting.mean(0) + 8.0 * np.sqrt(values[0]) * vectors[:, 0])[None]
    assert float(density.scores(far)[0]) == pytest.approx(64.0 / density.median)
    assert float(density.scores(far)[0]) > 4.0 * density.threshold
    assert float(density.inflation(far)[0]) == 1.0
    assert float(density.with_gamma(2.0).inflation(far)[0]) == pytest.approx(
        (float(density.scores(far)[0]) / density.threshold) ** 2
    )
    # along the leading directions only: the principal scores of those, whitened
    leading = fit_density(torch.from_numpy(fitting), torch.from_numpy(validation), shrinkage=0.0, components=2)
    scores = centred @ vectors[:, -2:]
    np.testing.assert_allclose(
        leading.distances(torch.from_numpy(validation)).numpy(), (scores**2 / values[-2:]).sum(1), rtol=1e-8
    )
    # shrinkage pulls the covariance toward its mean variance
    shrunk = fit_density(torch.from_numpy(fitting), torch.from_numpy(validation), shrinkage=0.5)
    target = 0.5 * covariance + 0.5 * np.trace(covariance) / 6.0 * np.eye(6)
    np.testing.assert_allclose(shrunk.precision.numpy(), np.linalg.inv(target), rtol=1e-8, atol=1e-12)


def test_bad_densities_are_one_line() -> None:
    fitting = torch.randn(50, 6, dtype=torch.float64)
    with pytest.raises(ValueError, match="needs more pairs than that, got 5"):
        fit_density(fitting[:5], fitting)
    with pytest.raises(ValueError, match=r"validation features \(10, 5\) do not match"):
        fit_density(fitting, fitting[:10, :5])
    with pytest.raises(ValueError, match=r"components must be in \[1, 6\], got 7"):
        fit_density(fitting, fitting, components=7)
    density = fit_density(fitting, fitting)
    with pytest.raises(ValueError, match=r"features \(2, 5\) do not fit a density over 6 units"):
        density.distances(fitting[:2, :5])
    with pytest.raises(ValueError, match="gamma in"):
        density.with_gamma(MAX_GAMMA + 1.0)


def test_gamma_brings_the_anees_to_one_where_the_density_can() -> None:
    threshold = 2.0
    scores = torch.full((100,), 4.0, dtype=torch.float64)  # every pair at twice the threshold
    nees = torch.full((100,), 3.0 * 2.0**1.5, dtype=torch.float64)  # ANEES 2^1.5 without the widening
    assert fit_gamma(nees, scores, threshold) == pytest.approx(1.5, abs=1e-12)
    assert fit_gamma(0.5 * torch.ones(100, dtype=torch.float64), scores, threshold) == 0.0  # already consistent
    # pairs inside the threshold cannot be widened: the cap, as close as the density gets
    assert fit_gamma(nees, torch.ones(100, dtype=torch.float64), threshold) == MAX_GAMMA
    mixed = torch.cat([scores[:50], torch.ones(50, dtype=torch.float64)])
    gamma = fit_gamma(torch.cat([nees[:50], torch.full((50,), 1.5, dtype=torch.float64)]), mixed, threshold)
    # half the pairs at NEES 1.5 stay; the other half must bring the mean NEES to 3: 3 * 2^1.5 / 2^g = 4.5
    assert gamma == pytest.approx(np.log2(3.0 * 2.0**1.5 / 4.5), abs=1e-12)


def test_prediction_widens_each_pairs_covariance_by_its_factor_as_epistemic() -> None:
    torch.manual_seed(0)
    model = HydraNet(TINY)
    flows = torch.randn(64, 2, 48, 144)
    plain = predict_rotations(model, flows)
    with torch.no_grad():
        features = model.forward_features(flows)[2].double()
    density = fit_density(features[:48], features[48:56]).with_gamma(1.0)
    model.density = density
    widened = predict_rotations(model, flows)
    factor = density.inflation(features)
    assert bool((factor > 1.0).any()) and bool((factor == 1.0).any())
    torch.testing.assert_close(widened.quaternion, plain.quaternion)
    torch.testing.assert_close(widened.aleatoric, plain.aleatoric)
    torch.testing.assert_close(widened.covariance, plain.covariance * factor[:, None, None])
    torch.testing.assert_close(widened.epistemic, plain.epistemic + (factor - 1.0)[:, None, None] * plain.covariance)


@pytest.fixture(scope="module")
def sequences(tmp_path_factory) -> dict[str, list[Path]]:
    root = tmp_path_factory.mktemp("density")
    plan = {"fitting": range(3), "validation": (10,), "shift": (20,)}
    out: dict[str, list[Path]] = {}
    for name, seeds in plan.items():
        out[name] = []
        for seed in seeds:
            # the shift turns three times as fast as the rest
            step = 2.4 if name == "shift" else 0.8
            write_rotation_sequence(root / f"{name}{seed}", frames=20, seed=seed, step_deg=step)
            out[name].append(root / f"{name}{seed}")
    return out


def test_the_density_goes_into_the_card_and_every_prediction_path_reads_it(sequences, tmp_path: Path) -> None:
    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import calibrate_density, load_hydranet, predict_sequence, sequence_features
    from pvo_pseudosensors.registry import models

    torch.manual_seed(0)
    directory = save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())
    plain_model, card = load_hydranet(directory)
    shift = sequences["shift"][0]
    plain = predict_sequence(plain_model, card, shift)
    cache = tmp_path / "cache"

    def cached(paths: list[Path]) -> list[tuple[Path, Path]]:
        return [(p, cache) for p in paths]

    result = calibrate_density(
        directory, cached(sequences["fitting"]), cached(sequences["validation"]), cached(sequences["shift"])
    )
    assert result.fitting_pairs == 3 * 19 and result.shift_before["pairs"] == 19
    assert result.shift_after["anees"] <= result.shift_before["anees"]
    entry = read_card(directory).calibration["feature_density"]
    assert entry["file"] == DENSITY_FILE and entry["gamma"] == result.density.gamma and (directory / DENSITY_FILE).is_file()

    model, card = load_hydranet(directory)
    assert isinstance(model.density, FeatureDensity)
    torch.testing.assert_close(model.density.precision, result.density.precision)
    widened = predict_sequence(model, card, shift)
    factor = result.density.inflation(sequence_features(plain_model, card, shift)).numpy()
    np.testing.assert_allclose(widened.quaternions, plain.quaternions, atol=1e-12)
    np.testing.assert_allclose(widened.covariance, plain.covariance * factor[:, None, None], rtol=1e-9)
    # the node's sensor reads the same card the same way
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(directory)))
    images = sorted((shift / "image_0").glob("*.png"))
    estimates = [sensor.estimate(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (k + 1) * 10**8) for k, p in enumerate(images[:3])]
    for k in (1, 2):
        np.testing.assert_allclose(estimates[k].covariance, widened.covariance[k - 1], rtol=1e-2)  # its own resizing
    # choosing the inference mode keeps the density
    models()["hydranet"].calibrate(directory, sequences["validation"], mode="plain")
    assert read_card(directory).calibration["feature_density"] == entry


def test_bad_density_files_are_one_line(sequences, tmp_path: Path) -> None:
    import shutil

    from pvo_pseudosensors.hydranet.infer import calibrate_density, load_hydranet, write_ensemble

    torch.manual_seed(0)
    directory = save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())
    few = [(sequences["validation"][0], None)]  # 19 pairs over 16 features: enough
    calibrate_density(directory, few, few, few)
    card = read_card(directory)
    shutil.copytree(directory, tmp_path / "kept")
    (directory / DENSITY_FILE).unlink()
    with pytest.raises(ModelFileError, match=rf"model.yaml: .*{DENSITY_FILE}: cannot read the feature density"):
        load_hydranet(directory)
    card.calibration["feature_density"] = {"file": DENSITY_FILE, "median": 1.0}
    write_card(directory, card)
    with pytest.raises(ModelFileError, match="feature_density must give file, median, threshold and gamma"):
        load_hydranet(directory)
    wider = HydraNetConfig(**{**TINY.__dict__, "feature": 24})
    other = save_model(tmp_path / "other", HydraNet(wider), HydraTask(wider).card())
    shutil.copyfile(tmp_path / "kept" / DENSITY_FILE, other / DENSITY_FILE)
    other_card = read_card(other)
    other_card.calibration = {"feature_density": read_card(tmp_path / "kept").calibration["feature_density"]}
    write_card(other, other_card)
    with pytest.raises(ModelFileError, match="the feature density is over 16 units, the network gives 24"):
        load_hydranet(other)
    second = save_model(tmp_path / "second", HydraNet(TINY), HydraTask(TINY).card())
    with pytest.raises(ValueError, match="kept: carries a feature density, .* an ensemble cannot use it"):
        write_ensemble([tmp_path / "kept", second], tmp_path / "ensemble")
    ensemble = write_ensemble([second, second], tmp_path / "ensemble")
    ensemble_card = read_card(ensemble)
    ensemble_card.calibration["feature_density"] = read_card(tmp_path / "kept").calibration["feature_density"]
    write_card(ensemble, ensemble_card)  # by hand
    with pytest.raises(ModelFileError, match="an ensemble cannot carry a feature density"):
        load_hydranet(ensemble)
    with pytest.raises(ValueError, match="needs more pairs than that, got 2"):
        two = sequences["validation"][0].parent / "two"
        write_rotation_sequence(two, frames=3, seed=5)
        calibrate_density(second, [(two, None)], few, few)
