"""HydraNet's flow-shortfall widening: the shortfall of a known image shift, the factor against hand-computed values,
the fit finding a power where the errors grow with the shortfall (and none where they do not), the card round trip,
prediction and the sensor reading it, bad entries in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_pseudosensors.hydranet.config import HydraNetConfig
from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
from pvo_pseudosensors.hydranet.shortfall import ShortfallWidening, fit_shortfall_widening, flow_shortfall
from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card, save_model, write_card

TINY = HydraNetConfig(height=48, width=144, widths=(8, 16, 16), feature=16, heads=4, head_hidden=16, head_dropout=0.1)


def textured(seed: int, shape: tuple[int, int] = (64, 208)) -> np.ndarray:
    """A smooth random texture (uint8) larger than ``shape`` by 40 px each way, to cut shifted windows from."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (shape[0] + 40, shape[1] + 40)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 3.0 - 255.0, 0, 255).astype(np.uint8)


def test_the_shortfall_is_the_shift_the_flow_missed() -> None:
    big = textured(0)
    earlier = big[20:84, 20:228]
    later = big[20:84, 13:221]  # the content moved 7 px to the right
    missed = np.zeros((2, 64, 208), np.float32)
    assert flow_shortfall(earlier, later, missed) == pytest.approx(7.0, abs=0.3)
    followed = missed.copy()
    followed[0] = 7.0
    assert flow_shortfall(earlier, later, followed) == pytest.approx(0.0, abs=0.3)
    half = missed.copy()
    half[0] = 3.0
    assert flow_shortfall(earlier, later, half) == pytest.approx(4.0, abs=0.3)
    # two unrelated images: the correlation's peak is weak, no shift is measured
    assert flow_shortfall(earlier, textured(1)[20:84, 20:228], missed) == 0.0
    import cv2

    noisy = np.clip(later + np.random.default_rng(2).normal(0, 40, later.shape), 0, 255).astype(np.uint8)
    window = cv2.createHanningWindow((208, 64), cv2.CV_32F)
    _, response = cv2.phaseCorrelate(earlier.astype(np.float32), noisy.astype(np.float32), window)
    assert flow_shortfall(earlier, noisy, missed, min_response=response * 0.99) == pytest.approx(7.0, abs=0.3)
    assert flow_shortfall(earlier, noisy, missed, min_response=response * 1.01) == 0.0
    with pytest.raises(ValueError, match="two grey images of one size"):
        flow_shortfall(earlier, later[:, :100], missed)


def test_the_factor_grows_with_the_shortfall_above_its_reference_only() -> None:
    widening = ShortfallWidening(reference=2.0, gamma=0.5)
    np.testing.assert_allclose(widening.factor([0.0, 2.0, 6.0]), [1.0, 1.0, 2.0])
    epistemic = np.stack([np.eye(3) * 1e-8] * 3)
    aleatoric = np.stack([np.eye(3) * 1e-6] * 3)
    widened = widening.widen(epistemic, aleatoric, [0.0, 2.0, 6.0])
    np.testing.assert_allclose(widened[:2], epistemic[:2])
    np.testing.assert_allclose(widened[2], epistemic[2] + aleatoric[2])  # d / reference = 3: 1 + 0.5 * 2
    assert ShortfallWidening.from_entry(widening.entry()) == widening


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"gamma": 1.0}, "needs a reference and a gamma"),
        ({"reference": 0.0, "gamma": 1.0}, "reference must be a positive number of pixels"),
        ({"reference": 1.0, "gamma": -1.0}, "gamma must be a finite number >= 0"),
        ({"reference": 1.0, "gamma": 1.0, "min_response": 1.5}, "min_response must lie in"),
        ({"reference": "far", "gamma": 1.0}, "flow_shortfall_widening: could not convert"),
    ],
)
def test_bad_entries_are_one_line(entry: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ShortfallWidening.from_entry(entry)


def test_the_fit_widens_where_the_errors_grow_with_the_shortfall_and_nowhere_else() -> None:
    rng = np.random.default_rng(3)
    reference = rng.uniform(0.0, 1.0, 2000)  # in-distribution shortfalls: q99 ~ 0.99 px
    shortfalls = np.concatenate([rng.uniform(0.0, 1.0, 1500), rng.uniform(2.0, 10.0, 500)])
    sigma = 1e-3
    epistemic = np.zeros((2000, 3, 3))
    aleatoric = np.broadcast_to(np.eye(3) * sigma**2, (2000, 3, 3)).copy()
    # the errors' true variance: sigma^2 (1 + 4 (d / 0.99 - 1)) beyond the reference, sigma^2 below it
    true_factor = 1.0 + 4.0 * np.maximum(0.0, shortfalls / 0.99 - 1.0)
    errors = rng.normal(size=(2000, 3)) * sigma * np.sqrt(true_factor)[:, None]
    fitted = fit_shortfall_widening(reference, errors, epistemic, aleatoric, shortfalls)
    assert fitted.reference == pytest.approx(np.quantile(reference, 0.99))
    assert fitted.gamma == pytest.approx(4.0, rel=0.2)
    consistent = rng.normal(size=(2000, 3)) * sigma  # errors that do not grow with d: no widening
    assert fit_shortfall_widening(reference, consistent, epistemic, aleatoric, shortfalls).gamma == 0.0


def test_the_widening_goes_into_the_card_and_prediction_and_the_sensor_read_it(tmp_path: Path) -> None:
    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.flow import dense_flow, global_shift
    from pvo_pseudosensors.hydranet.infer import calibrate_shortfall, load_hydranet, predict_sequence
    from pvo_pseudosensors.hydranet_node import widening_words
    from pvo_pseudosensors.learning.data import cached_images

    for name, seed, step in (("validation", 10, 0.8), ("shift", 20, 6.0)):  # the shift turns far beyond the flow's reach
        write_rotation_sequence(tmp_path / name, frames=20, seed=seed, step_deg=step)
    torch.manual_seed(0)
    directory = save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())
    plain_model, card = load_hydranet(directory)
    assert plain_model.shortfall_widening is None
    plain = predict_sequence(plain_model, card, tmp_path / "shift")
    result = calibrate_shortfall(directory, [(tmp_path / "validation", None)], [(tmp_path / "shift", None)])
    assert result.shift_before["pairs"] == 19 and result.shift_after["nll"] <= result.shift_before["nll"] + 1e-12
    entry = read_card(directory).calibration["flow_shortfall_widening"]
    assert ShortfallWidening.from_entry(entry) == result.widening and entry["shift_anees"] == result.shift_after["anees"]
    model, card = load_hydranet(directory)
    assert model.shortfall_widening == result.widening
    widened = predict_sequence(model, card, tmp_path / "shift")
    np.testing.assert_allclose(widened.quaternions, plain.quaternions, atol=1e-12)
    np.testing.assert_allclose(widened.aleatoric, plain.aleatoric, rtol=1e-12)
    # the shortfalls, computed here independently: the images' shift (phase correlation) against the flow's median
    paths = sorted((tmp_path / "shift" / "image_0").glob("*.png"))
    images = cached_images(paths, (TINY.height, TINY.width), False, None)
    shortfalls = []
    window = cv2.createHanningWindow((TINY.width, TINY.height), cv2.CV_32F)
    for k in range(len(images) - 1):
        a, b = images[k, 0], images[k + 1, 0]
        median = np.median(dense_flow(a, b).reshape(2, -1), axis=1)
        _, response = cv2.phaseCorrelate(a.astype(np.float32), b.astype(np.float32), window)
        measured = response >= result.widening.min_response
        shortfalls.append(float(np.hypot(*(np.array(global_shift(a, b)) - median))) if measured else 0.0)
    factor = 1.0 + result.widening.gamma * np.maximum(0.0, np.array(shortfalls) / result.widening.reference - 1.0)
    assert result.widening.gamma > 0.0 and (factor > 1.0).any()  # the shift's errors grow with its shortfall
    np.testing.assert_allclose(
        widened.epistemic, plain.epistemic + (factor - 1.0)[:, None, None] * plain.aleatoric, rtol=2e-3, atol=1e-9
    )  # flows kept as float16
    # the sensor (the node's) widens each pair as prediction does
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(directory)))
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths[:3]]
    estimates = [sensor.estimate(image, (k + 1) * 100_000_000) for k, image in enumerate(frames)]
    for k, estimate in enumerate(estimates[1:]):
        np.testing.assert_allclose(estimate.epistemic + estimate.aleatoric, widened.covariance[k], rtol=2e-3, atol=1e-9)
    assert "flow_shortfall_widening" in widening_words(read_card(directory).calibration)
    # `pvo hydranet calibrate` (the inference mode chosen again) keeps it
    from pvo_pseudosensors.registry import models

    models()["hydranet"].calibrate(directory, [tmp_path / "validation"], mode="mirrored")
    assert read_card(directory).calibration["flow_shortfall_widening"] == entry
    # a broken entry is one line naming the card
    card.calibration["flow_shortfall_widening"] = {"reference": -1.0, "gamma": 0.5}
    write_card(directory, card)
    with pytest.raises(ModelFileError, match="model.yaml: flow_shortfall_widening: the shortfall widening's reference must be"):
        load_hydranet(directory)
    with pytest.raises(ValueError, match="needs validation and shift sequences"):
        calibrate_shortfall(directory, [], [(tmp_path / "shift", None)])
