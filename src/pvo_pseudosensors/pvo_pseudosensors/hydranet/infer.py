"""HydraNet on a sequence: the flow of every consecutive pair of left images through the network, the mean
rotation with Sigma = Sigma_e + Sigma_a per pair, and the prediction file."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.lie import quaternion_to_rotation as quat_to_matrix
from pvo_core.readers import ROTATION_PREDICTIONS_HEADER
from pvo_core.trajectory import read_kitti_poses

from ..learning.checkpoint import CARD, ModelCard, ModelFileError, load_model
from ..learning.data import Source
from .config import ARCHITECTURE, HydraNetConfig
from .density import QUANTILE, SHRINKAGE, FeatureDensity, fit_density, fit_gamma, normalised_errors
from .flow import FlowPairs, network_input
from .model import HydraEnsemble, HydraNet, RotationNetwork, inference_mode, predict_rotations
from .shortfall import REFERENCE_QUANTILE, ShortfallWidening, fit_shortfall_widening, sequence_shortfalls
from .widening import MAX_GAMMA, SpreadWidening, fit_widening, gamma_grid

Array = NDArray[np.float64]


def load_hydranet(directory: Path) -> tuple[RotationNetwork, ModelCard]:
    """The trained network of ``directory`` in eval mode (one clear line for every bad model file). A card whose
    ``calibration.members`` lists further model directories (relative to ``directory``; :func:`write_ensemble`)
    gives a :class:`~.model.HydraEnsemble` of this directory's network and those."""
    directory = Path(directory)
    model, card = _load_one(directory)
    members = (card.calibration or {}).get("members") or []
    density_entry = (card.calibration or {}).get("feature_density")
    if density_entry is not None:
        if members:
            raise ModelFileError(f"{directory / CARD}: an ensemble cannot carry a feature density (its members' features differ)")
        try:
            model.density = FeatureDensity.load(directory, density_entry)
        except ValueError as error:
            raise ModelFileError(f"{directory / CARD}: {error}") from None
        if model.density.features != model.config.feature:
            raise ModelFileError(
                f"{directory / CARD}: the feature density is over {model.density.features} units, the network gives "
                f"{model.config.feature}"
            )
    widening = _card_widening(directory, card, "spread_widening", SpreadWidening.from_entry)
    shortfall = _card_widening(directory, card, "flow_shortfall_widening", ShortfallWidening.from_entry)
    if not members:
        if widening is not None:
            model.widening = widening
        model.shortfall_widening = shortfall
        return model, card
    if not isinstance(members, list) or not all(isinstance(m, str) for m in members):
        raise ModelFileError(f"{directory / CARD}: calibration.members must be a list of directories, got {members!r}")
    first = HydraNetConfig.from_card(card)
    networks = [model]
    for name in members:
        member, member_card = _load_one(directory / name)
        if (member_card.calibration or {}).get("members"):
            raise ModelFileError(f"{directory / name / CARD}: a member of an ensemble cannot be an ensemble itself")
        config = HydraNetConfig.from_card(member_card)
        if _network_input(config) != _network_input(first):
            raise ModelFileError(
                f"{directory / name / CARD}: reads {_describe_input(config)}, the ensemble's first network "
                f"{_describe_input(first)}: members must read the same input"
            )
        networks.append(member)
    ensemble = HydraEnsemble(networks)
    ensemble.eval()
    if widening is not None:
        ensemble.widening = widening
    ensemble.shortfall_widening = shortfall
    return ensemble, card


def _card_widening(directory: Path, card: ModelCard, key: str, parse: Callable[[Any], Any]) -> Any:
    """The card's ``calibration.<key>`` parsed (None without one); a bad entry is one line naming the card."""
    entry = (card.calibration or {}).get(key)
    if entry is None:
        return None
    try:
        return parse(entry)
    except ValueError as error:
        raise ModelFileError(f"{directory / CARD}: {error}") from None


def _network_input(config: HydraNetConfig) -> tuple[tuple[int, ...], bool, bool, str, bool, int]:
    """What a network reads: the flow's size (height, width), whether a texture and a pitch channel come with it,
    where its Farnebäck starts, whether a depth channel comes with it, and how many frames apart its images are."""
    return tuple(config.size), config.texture, config.pitch, config.flow_prior, config.depth, config.gap


def _describe_input(config: HydraNetConfig) -> str:
    extra = [name for name, present in (("texture", config.texture), ("pitch", config.pitch), ("depth", config.depth)) if present]
    prior = "" if config.flow_prior == "none" else " (Farnebäck started from the images' global shift)"
    gap = "" if config.gap == 1 else f" over {config.gap} frames"
    return f"{config.size[0]}x{config.size[1]} flow{gap}{prior}" + (f" with {' and '.join(extra)}" if extra else "")


def _load_one(directory: Path) -> tuple[HydraNet, ModelCard]:
    model, card = load_model(directory, ARCHITECTURE, lambda card: HydraNet(HydraNetConfig.from_card(card)))
    model.eval()
    return model, card  # type: ignore[return-value]


def write_ensemble(models: list[Path], out: Path, command: str = "") -> Path:
    """One model directory ``out`` that runs ``models`` (at least two, each a trained HydraNet reading the same
    input) as a :class:`~.model.HydraEnsemble`: the first's weights and card at its top, each other in
    ``members/member-<i>`` (copied: the directory stands alone), listed in the card's ``calibration.members``;
    the card keeps the first's training record, its inference mode, and adds the ``ensemble`` command. Each
    input is loaded first, so a bad one is one line and nothing is written; ``out`` must not hold a model yet."""
    import shutil

    from ..learning.checkpoint import WEIGHTS, write_card

    models = [Path(m) for m in models]
    if len(models) < 2:
        raise ValueError(f"an ensemble needs at least two models, got {len(models)}")
    out = Path(out)
    if (out / CARD).exists():
        raise ValueError(f"{out}: already holds a model; choose a new directory")
    cards = []
    for path in models:
        _, card = load_hydranet(path)
        if (card.calibration or {}).get("members"):
            raise ValueError(f"{path}: already an ensemble; give its members instead")
        if (card.calibration or {}).get("feature_density"):
            raise ValueError(f"{path}: carries a feature density, which is of its own features; an ensemble cannot use it")
        cards.append(card)
    inputs = [HydraNetConfig.from_card(c) for c in cards]
    if len({_network_input(c) for c in inputs}) > 1:
        read = ", ".join(f"{m}: {_describe_input(c)}" for m, c in zip(models, inputs, strict=True))
        raise ValueError(f"the models read different inputs ({read}); an ensemble's members must read the same")
    names = [f"members/member-{i}" for i in range(1, len(models))]
    for source, target in zip(models, [out, *(out / n for n in names)], strict=True):
        target.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source / WEIGHTS, target / WEIGHTS)
        shutil.copyfile(source / CARD, target / CARD)
    card = cards[0]
    card.calibration = {"mode": (card.calibration or {}).get("mode", "plain"), "members": names}
    card.commands = {**card.commands, "ensemble": command} if command else card.commands
    sources = ", ".join(f"{n} = {m}" for n, m in zip(names, models[1:], strict=True))
    card.notes = (
        f"An ensemble of {len(models)} HydraNets: this directory's weights ({models[0]}; its training record below) "
        f"and {sources}; the heads of all pooled (eq. 7.14, 7.16), Sigma_a their mean.\n" + card.notes
    )
    write_card(out, card)
    return out


@dataclass
class RotationPredictions:
    """Per frame pair: the earlier and later frame numbers (N,), the quaternion (N, 4) (w, x, y, z) of
    C_later,earlier and the covariances Sigma_e, Sigma_a (N, 3, 3) (rad², left tangent space)."""

    earlier: NDArray[np.int64]
    frames: NDArray[np.int64]
    quaternions: Array
    epistemic: Array
    aleatoric: Array

    @property
    def covariance(self) -> Array:
        return self.epistemic + self.aleatoric

    def write_csv(self, path: Path) -> Path:
        rows = [ROTATION_PREDICTIONS_HEADER]
        for a, b, q, c in zip(self.earlier, self.frames, self.quaternions, self.covariance, strict=True):
            rows.append(f"{int(a)},{int(b)}," + ",".join(f"{v:.9g}" for v in [*q, *c.reshape(-1)]))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(rows) + "\n")
        return path


def predict_flows(
    model: RotationNetwork,
    flows: torch.Tensor,
    batch: int = 64,
    mirrored: bool = False,
    reversed_flows: torch.Tensor | None = None,
) -> tuple[Array, Array, Array]:
    """Quaternions (N, 4), Sigma_e and Sigma_a (N, 3, 3) for network inputs (N, C, H, W), in batches
    (``mirrored``, ``reversed_flows``: :func:`~.model.predict_rotations`' mirrored and reversed inference)."""
    parts = [
        predict_rotations(
            model,
            flows[start : start + batch],
            mirrored,
            None if reversed_flows is None else reversed_flows[start : start + batch],
        )
        for start in range(0, len(flows), batch)
    ]
    return tuple(torch.cat([getattr(p, name) for p in parts]).numpy() for name in ("quaternion", "epistemic", "aleatoric"))  # type: ignore[return-value]


def sequence_inputs(
    config: HydraNetConfig, sequence: Path, reverse: bool = False, cache_dir: Path | None = None, pitch_deg: float | None = None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The network inputs (N, C, H, W) of every pair of ``sequence``'s left images the card's ``gap`` apart
    (consecutive: 1), forward, and (``reverse``) from the later image to the earlier (else None). A model with the
    pitch input reads ``pitch_deg`` (deg below the horizon), else the pitch the sequence's sim.yaml records."""
    return pair_inputs(config, sequence_pairs(config, sequence, reverse, cache_dir, pitch_deg), reverse)


def sequence_pairs(
    config: HydraNetConfig, sequence: Path, reverse: bool = False, cache_dir: Path | None = None, pitch_deg: float | None = None
) -> Any:
    """The resized images and flows of ``sequence`` as the card reads them (see :func:`sequence_inputs`)."""
    sequence = Path(sequence)
    data = FlowPairs(
        [Source(sequence, sequence.name)],
        config.size,
        reverse=reverse,
        cache_dir=cache_dir,
        targets=False,
        pitch=config.pitch,
        pitch_deg=pitch_deg,
        flow_prior=config.flow_prior,
        depth=config.depth,
        gap=config.gap,
    )
    return data.pairs[0]


def pair_inputs(config: HydraNetConfig, pairs: Any, reverse: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The network inputs of :func:`sequence_pairs`' pairs, forward and (``reverse``) backward."""
    depths = pairs.inverse_depths

    def inputs(flows: NDArray[np.floating], first: range) -> torch.Tensor:
        flows = np.asarray(flows, dtype=np.float32)
        if config.texture or config.pitch or config.depth:  # what each flow's first image shows, the camera's pitch
            flows = np.stack(
                [
                    network_input(pairs.images[k, 0], f, config.texture, pairs.pitch_deg, None if depths is None else depths[k])
                    for k, f in zip(first, flows, strict=True)
                ]
            )
        return torch.from_numpy(flows)

    count = len(pairs.images)
    forward = inputs(pairs.forward, range(count - config.gap))
    backward = inputs(pairs.backward, range(config.gap, count)) if reverse and pairs.backward is not None else None
    return forward, backward


def body_features(model: HydraNet, inputs: torch.Tensor, batch: int = 64) -> torch.Tensor:
    """The body's features (N, feature) of network inputs (N, C, H, W), in batches, eval mode (float64)."""
    model.eval()
    with torch.no_grad():
        return torch.cat([model.forward_features(inputs[i : i + batch])[2] for i in range(0, len(inputs), batch)]).double()


def sequence_features(
    model: HydraNet, card: ModelCard, sequence: Path, batch: int = 64, cache_dir: Path | None = None
) -> torch.Tensor:
    """The body's features (N, feature) of every consecutive pair of ``sequence``'s left images, read forward."""
    forward, _ = sequence_inputs(HydraNetConfig.from_card(card), sequence, cache_dir=cache_dir)
    return body_features(model, forward, batch)


def predict_sequence(
    model: RotationNetwork,
    card: ModelCard,
    sequence: Path,
    batch: int = 64,
    cache_dir: Path | None = None,
    pitch_deg: float | None = None,
) -> RotationPredictions:
    """Every pair of ``sequence``'s left images the card's ``gap`` apart (consecutive: 1; KITTI layout; poses.txt
    not needed), run as the card's ``calibration.mode`` says (plain, mirrored or reversed); ``pitch_deg``: see
    :func:`sequence_inputs`. With a gap g > 1 the pairs overlap (k-g -> k for every k >= g): :func:`chained`
    keeps the ones a fusion may take as independent."""
    config = HydraNetConfig.from_card(card)
    mode = inference_mode(card)
    pairs = sequence_pairs(config, sequence, mode == "reversed", cache_dir, pitch_deg)
    forward, backward = pair_inputs(config, pairs, mode == "reversed")
    quaternions, epistemic, aleatoric = predict_flows(model, forward, batch, mode == "mirrored", backward)
    shortfall = getattr(model, "shortfall_widening", None)
    if shortfall is not None:  # where the flow did not follow the image: Sigma_a widened, counted in Sigma_e
        shortfalls = sequence_shortfalls(pairs.images, pairs.forward, config.gap, shortfall.min_response)
        epistemic = shortfall.widen(epistemic, aleatoric, shortfalls)
    frames = np.arange(config.gap, len(forward) + config.gap)
    return RotationPredictions(frames - config.gap, frames, quaternions, epistemic, aleatoric)


def chained(predictions: RotationPredictions) -> RotationPredictions:
    """The pairs that chain without sharing an image's interval (0 -> g, g -> 2g, ...), as a fusion takes
    them: two overlapping pairs share most of their flow and so their error. Consecutive pairs stay as they are."""
    gap = predictions.frames - predictions.earlier
    keep = predictions.earlier % np.maximum(gap, 1) == 0
    return RotationPredictions(
        predictions.earlier[keep],
        predictions.frames[keep],
        predictions.quaternions[keep],
        predictions.epistemic[keep],
        predictions.aleatoric[keep],
    )


#: A sequence directory and the flow cache its pairs are kept in (None: none).
CachedSequence = tuple[Path, "Path | None"]


@dataclass
class ShiftFigures:
    """The figures (:func:`~.evaluation.evaluate_rotations`' keys) of the in-distribution validation pairs and of a
    shift's pairs, without and with a covariance widening."""

    validation_before: dict[str, float]
    validation_after: dict[str, float]
    shift_before: dict[str, float]
    shift_after: dict[str, float]


@dataclass
class DensityCalibration(ShiftFigures):
    """What :func:`calibrate_density` fitted and measured: the density (gamma fitted), the pairs it was fitted on,
    and the figures (plus ``widened``: the share of pairs whose covariance grows)."""

    density: FeatureDensity
    fitting_pairs: int


def calibrate_density(
    directory: Path,
    fitting: list[CachedSequence],
    validation: list[CachedSequence],
    shift: list[CachedSequence],
    quantile: float = QUANTILE,
    components: int | None = None,
    shrinkage: float = SHRINKAGE,
    say: Callable[[str], None] = lambda _: None,
) -> DensityCalibration:
    """Fit a :class:`~.density.FeatureDensity` for the model in ``directory`` (:mod:`.density`): the Gaussian of its
    features over the ``fitting`` sequences' pairs (``shrinkage``; along its ``components`` leading directions,
    None: all), the median and ``quantile`` over the in-distribution ``validation`` ones, gamma so that the ANEES
    over the ``shift`` sequences' pairs (a shift of the input the model was not trained on) is 1; written into the
    card (``calibration.feature_density`` and the density file beside the weights; the card's other calibration
    kept). Every sequence needs its poses.txt but the fitting ones; ``say`` hears each stage as it starts."""
    from ..learning.checkpoint import write_card
    from .evaluation import evaluate_rotations, rotation_errors, true_relative_rotations

    directory = Path(directory)
    model, card = load_hydranet(directory)
    if isinstance(model, HydraEnsemble):
        raise ValueError(f"{directory}: an ensemble cannot carry a feature density (its members' features differ)")
    if not (fitting and validation and shift):
        raise ValueError("a feature density needs fitting, validation and shift sequences, each at least one")
    model.density = None  # figures "before" are the model's own covariances

    config = HydraNetConfig.from_card(card)
    mode = inference_mode(card)

    def fitting_features(sequences: list[CachedSequence]) -> torch.Tensor:
        return torch.cat([sequence_features(model, card, s, cache_dir=c) for s, c in sequences])

    def measured(sequences: list[CachedSequence]) -> tuple[torch.Tensor, Array, Array, Array]:
        """Features, quaternions, covariances (the model's own) and true rotations of every pair, each
        sequence's flows read once."""
        features, quaternions, covariances, truth = [], [], [], []
        for sequence, cache in sequences:
            forward, backward = sequence_inputs(config, sequence, mode == "reversed", cache)
            q, epistemic, aleatoric = predict_flows(model, forward, mirrored=mode == "mirrored", reversed_flows=backward)
            frames = np.arange(config.gap, len(forward) + config.gap)
            features.append(body_features(model, forward))
            quaternions.append(q)
            covariances.append(epistemic + aleatoric)
            truth.append(true_relative_rotations(read_kitti_poses(Path(sequence) / "poses.txt"), frames - config.gap, frames))
        return torch.cat(features), np.vstack(quaternions), np.concatenate(covariances), np.concatenate(truth)

    say(f"features of {len(fitting)} fitting sequences")
    fitted_on = fitting_features(fitting)
    say(f"features and predictions of {len(validation)} validation sequences")
    validation_features, validation_q, validation_covariances, validation_truth = measured(validation)
    density = fit_density(fitted_on, validation_features, shrinkage, quantile, components)
    say(f"features and predictions of {len(shift)} shift sequences")
    shift_features, shift_q, shift_covariances, shift_truth = measured(shift)
    estimates = np.stack([quat_to_matrix(q) for q in shift_q])
    errors = torch.from_numpy(rotation_errors(estimates, shift_truth))
    nees = normalised_errors(errors, torch.from_numpy(shift_covariances))
    density = density.with_gamma(fit_gamma(nees, density.scores(shift_features), density.threshold))

    def figures(quaternions: Array, covariances: Array, truth: Array, inflation: torch.Tensor | None) -> dict[str, float]:
        if inflation is None:
            return evaluate_rotations(quaternions, covariances, truth)
        widened = covariances * inflation.numpy()[:, None, None]
        return {**evaluate_rotations(quaternions, widened, truth), "widened": float((inflation > 1.0).double().mean())}

    calibration = DensityCalibration(
        validation_before=figures(validation_q, validation_covariances, validation_truth, None),
        validation_after=figures(validation_q, validation_covariances, validation_truth, density.inflation(validation_features)),
        shift_before=figures(shift_q, shift_covariances, shift_truth, None),
        shift_after=figures(shift_q, shift_covariances, shift_truth, density.inflation(shift_features)),
        density=density,
        fitting_pairs=len(fitted_on),
    )
    entry = density.save(directory)
    card.calibration = {
        **(card.calibration or {}),
        "feature_density": {
            **entry,
            "fitting_pairs": calibration.fitting_pairs,
            "quantile": quantile,
            "shrinkage": shrinkage,
            "components": components or density.features,
            "validation_anees": calibration.validation_after["anees"],
            "shift_anees_before": calibration.shift_before["anees"],
            "shift_anees": calibration.shift_after["anees"],
        },
    }
    write_card(directory, card)
    return calibration


@dataclass
class WideningCalibration(ShiftFigures):
    """What :func:`calibrate_widening` fitted and measured: the widening, and the figures."""

    widening: SpreadWidening


def calibrate_widening(
    directory: Path,
    validation: list[CachedSequence],
    shift: list[CachedSequence],
    say: Callable[[str], None] = lambda _: None,
    reference_quantile: float = 0.5,
    max_gamma: float = MAX_GAMMA,
) -> WideningCalibration:
    """Fit a :class:`~.widening.SpreadWidening` for the model in ``directory``: its reference the
    ``reference_quantile`` of tr Σ_e over the in-distribution ``validation`` sequences' pairs, its γ by maximum
    likelihood among 0 … ``max_gamma`` on the ``shift`` sequences' pairs (validation pairs of a shift the model was not
    trained on); written into the card (``calibration.spread_widening``, the card's other calibration kept). Every
    sequence needs its poses.txt; ``say`` hears each stage as it starts."""
    from ..learning.checkpoint import write_card
    from .evaluation import evaluate_rotations, rotation_errors, true_relative_rotations

    if not (validation and shift):
        raise ValueError("a spread widening needs validation and shift sequences, each at least one")
    gammas = gamma_grid(max_gamma)  # before the predictions: a bad bound is named at once
    directory = Path(directory)
    model, card = load_hydranet(directory)
    model.widening = None  # figures "before" are the model's own covariances
    mode = inference_mode(card)
    config = HydraNetConfig.from_card(card)

    def measured(sequences: list[CachedSequence]) -> tuple[Array, Array, Array, Array]:
        quaternions, epistemic, aleatoric, truth = [], [], [], []
        for sequence, cache in sequences:
            forward, backward = sequence_inputs(config, sequence, mode == "reversed", cache)
            q, e, a = predict_flows(model, forward, mirrored=mode == "mirrored", reversed_flows=backward)
            frames = np.arange(config.gap, len(forward) + config.gap)
            quaternions.append(q)
            epistemic.append(e)
            aleatoric.append(a)
            truth.append(true_relative_rotations(read_kitti_poses(Path(sequence) / "poses.txt"), frames - config.gap, frames))
        return np.vstack(quaternions), np.concatenate(epistemic), np.concatenate(aleatoric), np.concatenate(truth)

    say(f"predictions of {len(validation)} validation sequences")
    validation_q, validation_e, validation_a, validation_truth = measured(validation)
    say(f"predictions of {len(shift)} shift sequences")
    shift_q, shift_e, shift_a, shift_truth = measured(shift)
    errors = rotation_errors(np.stack([quat_to_matrix(q) for q in shift_q]), shift_truth)
    widening = fit_widening(validation_e, errors, shift_e, shift_a, gammas, reference_quantile=reference_quantile)

    def figures(quaternions: Array, epistemic: Array, aleatoric: Array, truth: Array, widened: bool) -> dict[str, float]:
        e = widening.widen(torch.from_numpy(epistemic), torch.from_numpy(aleatoric)).numpy() if widened else epistemic
        return evaluate_rotations(quaternions, e + aleatoric, truth)

    calibration = WideningCalibration(
        validation_before=figures(validation_q, validation_e, validation_a, validation_truth, False),
        validation_after=figures(validation_q, validation_e, validation_a, validation_truth, True),
        shift_before=figures(shift_q, shift_e, shift_a, shift_truth, False),
        shift_after=figures(shift_q, shift_e, shift_a, shift_truth, True),
        widening=widening,
    )
    card.calibration = {
        **(card.calibration or {}),
        "spread_widening": {
            **widening.entry(),
            "reference_quantile": float(reference_quantile),
            "max_gamma": float(max_gamma),
            "mode": mode,  # the spread is the mode's own: mirrored and reversed inference pool more readings
            "validation_anees": calibration.validation_after["anees"],
            "shift_anees_before": calibration.shift_before["anees"],
            "shift_anees": calibration.shift_after["anees"],
        },
    }
    write_card(directory, card)
    return calibration


@dataclass
class ShortfallCalibration(ShiftFigures):
    """What :func:`calibrate_shortfall` fitted and measured: the widening, and the figures."""

    widening: ShortfallWidening


def calibrate_shortfall(
    directory: Path,
    validation: list[CachedSequence],
    shift: list[CachedSequence],
    say: Callable[[str], None] = lambda _: None,
    reference_quantile: float = REFERENCE_QUANTILE,
) -> ShortfallCalibration:
    """Fit a :class:`~.shortfall.ShortfallWidening` for the model in ``directory`` (its card's other widenings
    applied, as the model ships): its reference the ``reference_quantile`` of the flow shortfall over the
    in-distribution ``validation`` sequences' pairs, its γ by maximum likelihood on the ``shift`` sequences' pairs
    (validation pairs of a faster-driven shift); written into the card (``calibration.flow_shortfall_widening``).
    Every sequence needs its poses.txt; ``say`` hears each stage as it starts."""
    from ..learning.checkpoint import write_card
    from .evaluation import evaluate_rotations, rotation_errors, true_relative_rotations

    if not (validation and shift):
        raise ValueError("a shortfall widening needs validation and shift sequences, each at least one")
    directory = Path(directory)
    model, card = load_hydranet(directory)
    model.shortfall_widening = None  # figures "before" are the card's without it
    config = HydraNetConfig.from_card(card)
    mode = inference_mode(card)

    def measured(sequences: list[CachedSequence]) -> tuple[Array, Array, Array, Array, Array]:
        quaternions, epistemic, aleatoric, truth, shortfalls = [], [], [], [], []
        for sequence, cache in sequences:
            # predict_sequence's steps without the widening being fitted, the pairs read once for both
            pairs = sequence_pairs(config, sequence, mode == "reversed", cache)
            forward, backward = pair_inputs(config, pairs, mode == "reversed")
            q, e, a = predict_flows(model, forward, mirrored=mode == "mirrored", reversed_flows=backward)
            frames = np.arange(config.gap, len(forward) + config.gap)
            quaternions.append(q)
            epistemic.append(e)
            aleatoric.append(a)
            poses = read_kitti_poses(Path(sequence) / "poses.txt")
            truth.append(true_relative_rotations(poses, frames - config.gap, frames))
            shortfalls.append(sequence_shortfalls(pairs.images, pairs.forward, config.gap))
        joined = (np.vstack(quaternions), *(np.concatenate(v) for v in (epistemic, aleatoric, truth, shortfalls)))
        return joined  # type: ignore[return-value]

    say(f"predictions of {len(validation)} validation sequences")
    validation_q, validation_e, validation_a, validation_truth, validation_d = measured(validation)
    say(f"predictions of {len(shift)} shift sequences")
    shift_q, shift_e, shift_a, shift_truth, shift_d = measured(shift)
    errors = rotation_errors(np.stack([quat_to_matrix(q) for q in shift_q]), shift_truth)
    widening = fit_shortfall_widening(validation_d, errors, shift_e, shift_a, shift_d, reference_quantile)

    def figures(q: Array, e: Array, a: Array, truth: Array, d: Array, widened: bool) -> dict[str, float]:
        return evaluate_rotations(q, (widening.widen(e, a, d) if widened else e) + a, truth)

    calibration = ShortfallCalibration(
        validation_before=figures(validation_q, validation_e, validation_a, validation_truth, validation_d, False),
        validation_after=figures(validation_q, validation_e, validation_a, validation_truth, validation_d, True),
        shift_before=figures(shift_q, shift_e, shift_a, shift_truth, shift_d, False),
        shift_after=figures(shift_q, shift_e, shift_a, shift_truth, shift_d, True),
        widening=widening,
    )
    card.calibration = {
        **(card.calibration or {}),
        "flow_shortfall_widening": {
            **widening.entry(),
            "reference_quantile": float(reference_quantile),
            "validation_anees": calibration.validation_after["anees"],
            "shift_anees_before": calibration.shift_before["anees"],
            "shift_anees": calibration.shift_after["anees"],
        },
    }
    write_card(directory, card)
    return calibration
