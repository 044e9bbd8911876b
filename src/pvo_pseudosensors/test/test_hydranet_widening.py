"""HydraNet's spread widening: its factor against hand-computed values, the fit recovering a known power, the widened
covariance through prediction, the card round trip and its bad entries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_pseudosensors.hydranet.config import HydraNetConfig
from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask, predict_rotations
from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence
from pvo_pseudosensors.hydranet.widening import SpreadWidening, fit_widening, gamma_grid
from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card, save_model, write_card

TINY = HydraNetConfig(height=48, width=144, widths=(8, 16, 16), feature=16, heads=4, head_hidden=16, head_dropout=0.1)


def test_the_factor_grows_with_the_spread_above_its_reference_only() -> None:
    widening = SpreadWidening(reference=2.0, gamma=0.5)
    epistemic = torch.stack([torch.eye(3) * t / 3.0 for t in (1.0, 2.0, 6.0)]).double()
    torch.testing.assert_close(widening.factor(epistemic), torch.tensor([1.0, 1.0, 2.0], dtype=torch.float64))
    aleatoric = torch.eye(3, dtype=torch.float64).expand(3, 3, 3) * 0.1
    widened = widening.widen(epistemic, aleatoric)
    torch.testing.assert_close(widened[:2], epistemic[:2])
    torch.testing.assert_close(widened[2], epistemic[2] + aleatoric[2])  # r = 3: 1 + 0.5 * 2
    assert SpreadWidening.from_entry(widening.entry()) == widening


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"gamma": 1.0}, "needs a reference and a gamma"),
        ("0.5", "needs a reference and a gamma"),
        ({"reference": 0.0, "gamma": 1.0}, "reference must be a positive trace"),
        ({"reference": 1e-8, "gamma": -0.1}, "gamma must be a finite number >= 0"),
        ({"reference": "many", "gamma": 1.0}, "spread_widening: could not convert"),
    ],
)
def test_bad_widening_entries_are_one_line(entry: object, message: str) -> None:
    with pytest.raises(ValueError, match=message) as raised:
        SpreadWidening.from_entry(entry)
    assert "\n" not in str(raised.value)


def test_the_fit_recovers_the_power_the_errors_were_drawn_with() -> None:
    rng = np.random.default_rng(3)
    count = 6000
    traces = np.exp(rng.uniform(np.log(0.2), np.log(20.0), count)) * 1e-8  # the reference below is 1e-8
    epistemic = traces[:, None, None] * np.eye(3) / 3.0
    aleatoric = np.broadcast_to(np.eye(3) * 4e-7, (count, 3, 3)).copy()
    truth = SpreadWidening(reference=1e-8, gamma=0.8)
    total = truth.widen(torch.from_numpy(epistemic), torch.from_numpy(aleatoric)).numpy() + aleatoric
    errors = np.einsum("nij,nj->ni", np.linalg.cholesky(total), rng.normal(size=(count, 3)))
    in_distribution = np.eye(3) * np.array([0.5e-8, 1e-8, 1.5e-8])[:, None, None] / 3.0
    fitted = fit_widening(in_distribution, errors, epistemic, aleatoric)
    assert fitted.reference == pytest.approx(1e-8)
    assert fitted.gamma == pytest.approx(0.8, abs=0.08)
    # errors no larger than Sigma_a says: nothing to widen
    plain = np.einsum("nij,nj->ni", np.linalg.cholesky(aleatoric), rng.normal(size=(count, 3)))
    assert fit_widening(in_distribution, plain, epistemic, aleatoric).gamma == pytest.approx(0.0, abs=0.02)
    with pytest.raises(ValueError, match="needs in-distribution and shift pairs"):
        fit_widening(np.zeros((0, 3, 3)), errors, epistemic, aleatoric)
    # a grid that stops below the truth stops the fit at its edge; one reaching past it finds the truth again
    assert fit_widening(in_distribution, errors, epistemic, aleatoric, gamma_grid(0.5)).gamma == pytest.approx(0.5)
    assert fit_widening(in_distribution, errors, epistemic, aleatoric, gamma_grid(20.0)).gamma == pytest.approx(0.8, abs=0.08)
    assert len(gamma_grid(3.0)) == 301 and gamma_grid(3.0)[-1] == 3.0
    for bad in (0.0, -1.0, float("nan"), 2000.0):
        with pytest.raises(ValueError, match="largest power must lie in"):
            gamma_grid(bad)


def test_a_higher_reference_quantile_leaves_more_pairs_unwidened() -> None:
    """The reference is the quantile asked for: at the 90th percentile nine in ten in-distribution pairs keep their
    covariance, where the median widens half of them."""
    traces = np.arange(1, 11, dtype=float) * 1e-8  # tr Sigma_e of ten in-distribution pairs: 1e-8 ... 1e-7
    in_distribution = traces[:, None, None] * np.eye(3) / 3.0
    aleatoric = np.broadcast_to(np.eye(3) * 4e-7, (10, 3, 3)).copy()
    errors = np.full((10, 3), 1e-3)  # far beyond Sigma_a: the fit widens as far as the grid lets it
    median = fit_widening(in_distribution, errors, in_distribution, aleatoric)
    upper = fit_widening(in_distribution, errors, in_distribution, aleatoric, reference_quantile=0.9)
    assert median.reference == pytest.approx(np.quantile(traces, 0.5))
    assert upper.reference == pytest.approx(np.quantile(traces, 0.9))
    widened = {w: int((w.factor(torch.from_numpy(in_distribution)) > 1.0).sum()) for w in (median, upper)}
    assert widened[median] == 5 and widened[upper] == 1
    for bad in (0.0, 1.0, -0.5):
        with pytest.raises(ValueError, match=f"reference quantile must lie in \\(0, 1\\), got {bad}"):
            fit_widening(in_distribution, errors, in_distribution, aleatoric, reference_quantile=bad)


def test_prediction_widens_sigma_a_by_the_factor_and_counts_it_as_epistemic() -> None:
    torch.manual_seed(0)
    model = HydraNet(TINY)
    flows = torch.randn(32, 2, 48, 144)
    plain = predict_rotations(model, flows)
    traces = torch.diagonal(plain.epistemic, dim1=-2, dim2=-1).sum(-1)
    model.widening = SpreadWidening(reference=float(traces.median()), gamma=1.5)
    widened = predict_rotations(model, flows)
    factor = model.widening.factor(plain.epistemic)
    assert bool((factor > 1.0).any()) and bool((factor == 1.0).any())
    torch.testing.assert_close(widened.quaternion, plain.quaternion)
    torch.testing.assert_close(widened.aleatoric, plain.aleatoric)
    torch.testing.assert_close(widened.epistemic, plain.epistemic + (factor - 1.0)[:, None, None] * plain.aleatoric)


def test_the_widening_goes_into_the_card_and_prediction_reads_it(tmp_path: Path) -> None:
    from pvo_pseudosensors.hydranet.infer import calibrate_widening, load_hydranet, predict_sequence

    for name, seed, step in (("validation", 10, 0.8), ("shift", 20, 2.4)):  # the shift turns three times as fast
        write_rotation_sequence(tmp_path / name, frames=20, seed=seed, step_deg=step)
    torch.manual_seed(0)
    directory = save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())
    plain_model, card = load_hydranet(directory)
    plain = predict_sequence(plain_model, card, tmp_path / "shift")
    result = calibrate_widening(directory, [(tmp_path / "validation", None)], [(tmp_path / "shift", None)])
    assert result.shift_before["pairs"] == 19 and result.validation_before["pairs"] == 19
    assert result.shift_after["nll"] <= result.shift_before["nll"] + 1e-12
    entry = read_card(directory).calibration["spread_widening"]
    assert SpreadWidening.from_entry(entry) == result.widening and entry["shift_anees"] == result.shift_after["anees"]
    model, card = load_hydranet(directory)
    assert model.widening == result.widening
    widened = predict_sequence(model, card, tmp_path / "shift")
    factor = result.widening.factor(torch.from_numpy(plain.epistemic)).numpy()
    np.testing.assert_allclose(widened.quaternions, plain.quaternions, atol=1e-12)
    np.testing.assert_allclose(widened.covariance, plain.epistemic + plain.aleatoric * factor[:, None, None], rtol=1e-9)
    # choosing the inference mode keeps the widening
    from pvo_pseudosensors.registry import models

    hydranet = models()["hydranet"]
    assert entry["mode"] == "plain"
    assert "spread_widening_dropped" not in hydranet.calibrate(directory, [tmp_path / "validation"], mode="plain")
    assert read_card(directory).calibration["spread_widening"] == entry
    # ... in its own mode only: another mode's spread is not the one its reference was taken from
    figures = hydranet.calibrate(directory, [tmp_path / "validation"], mode="mirrored")
    assert "spread_widening" not in read_card(directory).calibration and read_card(directory).calibration["mode"] == "mirrored"
    assert hydranet.summary(figures)[0].endswith("dropped: fitted in another inference mode (run pvo hydranet widen again)")
    assert getattr(load_hydranet(directory)[0], "widening", None) is None
    # a broken entry is one line naming the card
    card.calibration["spread_widening"] = {"reference": -1.0, "gamma": 0.5}
    write_card(directory, card)
    with pytest.raises(ModelFileError, match="model.yaml: the spread widening's reference must be a positive"):
        load_hydranet(directory)
    with pytest.raises(ValueError, match="needs validation and shift sequences"):
        calibrate_widening(directory, [], [(tmp_path / "shift", None)])


def test_the_node_says_at_start_up_that_its_covariance_is_widened() -> None:
    from pvo_pseudosensors.hydranet_node import widening_words

    words = widening_words({"spread_widening": {"reference": 9.2e-8, "gamma": 0.93, "reference_quantile": 0.9}})
    assert words == ", Sigma_a widened by 1 + 0.93 max(0, r - 1), r the heads' spread over its reference (card: spread_widening)"
    assert widening_words({}) == "" and widening_words({"spread_widening": "broken"}) == ""
