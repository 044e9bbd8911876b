"""Sun-BCNN on a sequence: MC-dropout samples per image, Method I mean and Method II covariance (calibrated), and
the prediction file. Its evaluation against the true sun vectors is :mod:`.evaluation`."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.readers import SUN_PREDICTIONS_HEADER
from pvo_core.sun import (
    UNCALIBRATED,
    CovarianceCalibration,
    aleatoric_covariance,
    sample_mean_and_covariance,
    unit_zenith_azimuth,
)

from ..learning.checkpoint import CARD, ModelCard, ModelFileError, load_model
from ..learning.data import FrameDataset, Source
from ..learning.spec import DataSpec
from .model import ARCHITECTURE, SunBCNN, SunBCNNConfig

Array = NDArray[np.float64]


def equalize_input(model: SunBCNN) -> SunBCNN:
    """``model``, now reading every image histogram-equalised (as a model trained with ``equalize`` does), whatever
    it was trained on; returned for chaining. For the synthetic model on a real camera: equalised KITTI 07 frames
    read 31.4 deg instead of 37.6 (stop 74, rule 3) — the renders' grey levels spread more evenly than a real
    exposure's."""
    model.config = replace(model.config, equalize=True)
    return model


def load_sun_bcnn(directory: Path) -> tuple[SunBCNN, ModelCard]:
    """The trained network of ``directory`` (one clear line for every bad model file, its covariance
    calibration included)."""
    model, card = load_model(directory, ARCHITECTURE, lambda card: SunBCNN(SunBCNNConfig.from_card(card)))
    try:
        card_calibration(card)
    except ValueError as exc:
        raise ModelFileError(f"{Path(directory) / CARD}: {exc}") from None
    return model, card


@dataclass
class SunPredictions:
    """Per image: frame number, unit sun vector (N, 3) in the camera optical frame, zenith and azimuth (N,)
    in rad, and the (zenith, azimuth) covariance (N, 2, 2) in rad²."""

    frames: NDArray[np.int64]
    vectors: Array
    zenith: Array
    azimuth: Array
    covariance: Array

    def rows(self) -> Array:
        """(N, 10): frame, s (3), zenith, azimuth, covariance (4, row-major) — the prediction file's columns."""
        return np.column_stack([self.frames, self.vectors, self.zenith, self.azimuth, self.covariance.reshape(-1, 4)])

    def write_csv(self, path: Path) -> Path:
        rows = [SUN_PREDICTIONS_HEADER]
        for f, s, z, a, c in zip(self.frames, self.vectors, self.zenith, self.azimuth, self.covariance, strict=True):
            values = [*s, z, a, *c.reshape(-1)]
            rows.append(f"{int(f)}," + ",".join(f"{v:.9g}" for v in values))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(rows) + "\n")
        return path


#: MC sampling: "full" (dropout everywhere, every pass through the whole network; the thesis), "head" (the
#: backbone once, the passes through the head), and either "-mirrored": half the passes over the image mirrored
#: left-right, their sun's x negated (the network was trained on mirrored images; pooling both halves averages
#: out what the network does differently to the two).
MODES = ("full", "head", "full-mirrored", "head-mirrored")
MIRRORED = "-mirrored"
#: The default, chosen on the corpus's validation split (60 sequences, 2,400 images, the shipped model, N = 25 as
#: the node draws them): median vector error 22.23 deg full, 21.81 head, 21.59 full-mirrored, 20.91 head-mirrored
#: - the most accurate and, at 4.8 ms per image against 44.9 (one core, batches of 40), within the 30 ms budget.
DEFAULT_MODE = "head-mirrored"


def model_mode(card: ModelCard, mode: str | None = None) -> str:
    """The MC mode to run a model in: ``mode`` when given, else the one its card's τ was calibrated in (the
    covariance is only calibrated for that one), else :data:`DEFAULT_MODE`."""
    chosen = mode or str(card.calibration.get("mode") or DEFAULT_MODE)
    if chosen not in MODES:
        source = "" if mode else "the model card's calibration.mode: "
        raise ValueError(f"{source}unknown MC mode {chosen!r}: choose one of {', '.join(MODES)}")
    return chosen


def predict_sequence(
    model: SunBCNN,
    card: ModelCard,
    sequence: Path,
    samples: int = 25,
    batch: int = 32,
    seed: int = 0,
    cache_dir: Path | None = None,
    mode: str | None = None,
    calibration: CovarianceCalibration | None = None,
) -> SunPredictions:
    """Every left image of ``sequence`` through ``samples`` dropout passes (seeded) in ``mode`` (:data:`MODES`;
    default: the one the card's calibration was fitted in, :func:`model_mode`). calibration: how the model's
    covariance becomes the stated one (default: the card's, :func:`card_calibration`)."""
    frames, draws = sample_sequence(model, card, sequence, samples, batch, seed, cache_dir, mode)
    return predictions_from_draws(frames, draws, card_calibration(card) if calibration is None else calibration)


def card_calibration(card: ModelCard) -> CovarianceCalibration:
    """The covariance calibration of a model card (``calibration.tau`` and ``calibration.scale``; none until
    `pvo sun-bcnn calibrate` fitted them)."""
    if card.calibration is not None and not isinstance(card.calibration, dict):
        raise ValueError(f"calibration must be a mapping, got {card.calibration!r}")
    return CovarianceCalibration.from_mapping(card.calibration or {})


def card_fusion(card: ModelCard) -> dict[str, Any]:
    """How the fusion should weigh this model's readings (``calibration.fusion``: dotted ``inputs.sun.*`` fusion
    parameters, e.g. the offset state ``inputs.sun.bias_sigma`` chosen on validation drives); {} when the card has none.
    ``ValueError`` naming the entry that is not a fusion setting of the sun."""
    block = (card.calibration or {}).get("fusion") or {}
    if not isinstance(block, dict):
        raise ValueError(f"calibration.fusion must be a mapping of fusion parameters, got {block!r}")
    for name in block:
        if not str(name).startswith("inputs.sun."):
            raise ValueError(f"calibration.fusion: {name!r} is not a fusion parameter of the sun (inputs.sun.*)")
    return dict(block)


def fusion_arguments(settings: dict[str, Any]) -> str:
    """``settings`` (dotted fusion parameters) as ``--ros-args`` words for the fusion node: ``-p name:=value``, a list
    as ``[a,b]``."""

    def value_text(value: Any) -> str:
        if isinstance(value, list | tuple):
            return "[" + ",".join(value_text(v) for v in value) + "]"
        return f"{value:g}" if isinstance(value, float) else str(value)

    return " ".join(f"-p {name}:={value_text(value)}" for name, value in settings.items())


def predictions_from_draws(
    frames: NDArray[np.int64], draws: Draws, calibration: CovarianceCalibration = UNCALIBRATED
) -> SunPredictions:
    """Method I mean, the covariance of :func:`combine` and their angles, per frame."""
    mean, covariance = combine(draws, calibration)
    zenith, azimuth = unit_zenith_azimuth(mean)
    return SunPredictions(frames, mean, zenith, azimuth, covariance)


def sample_sequence(
    model: SunBCNN,
    card: ModelCard,
    sequence: Path,
    samples: int = 25,
    batch: int = 32,
    seed: int = 0,
    cache_dir: Path | None = None,
    mode: str | None = None,
) -> tuple[NDArray[np.int64], Draws]:
    """The frame numbers (N,) of ``sequence``'s left images and their MC-dropout draws (samples, N, ...), in
    ``mode`` (default: the card's calibrated one, :func:`model_mode`)."""
    mode = model_mode(card, mode)
    spec = SunBCNNConfig.from_card(card).spec
    data = FrameDataset([Source(Path(sequence), Path(sequence).name)], DataSpec(spec.size, colour=spec.colour), cache_dir)
    vectors, inverse, frames = [], [], []
    generator = torch.Generator().manual_seed(seed)
    for start in range(0, len(data), batch):
        items = [data[i] for i in range(start, min(start + batch, len(data)))]
        images = torch.stack([item["left"] for item in items])
        draws = draw_samples(model, images, samples, int(torch.randint(0, 2**31 - 1, (1,), generator=generator)), mode)
        vectors.append(draws.vectors)
        inverse.append(draws.inverse_concentration)
        frames += [int(item["frame"]) for item in items]
    kappas = None if inverse[0] is None else np.concatenate(inverse, axis=1)
    return np.asarray(frames), Draws(np.concatenate(vectors, axis=1), kappas)


@dataclass
class Draws:
    """MC-dropout passes over a batch: unit vectors (S, B, 3) and 1/kappa (S, B) of the aleatoric output
    (None without it)."""

    vectors: Array
    inverse_concentration: Array | None


#: the most image copies one batch of full-mode MC passes holds (bounds memory: ~0.25 MB of stem features each)
PASS_BATCH = 128


def draw_samples(model: SunBCNN, images: torch.Tensor, samples: int, seed: int, mode: str = DEFAULT_MODE) -> Draws:
    """``samples`` MC-dropout passes over images (B, C, H, W) in ``mode`` (:data:`MODES`); the global RNG is left
    as it was. A mirrored mode draws ceil(samples / 2) passes over the images (seed) and the rest over the images
    mirrored left-right (seed + 1), the latter's sun vectors mirrored back (x negated)."""
    if mode not in MODES:
        raise ValueError(f"unknown MC mode {mode!r}: choose one of {', '.join(MODES)}")
    if mode.endswith(MIRRORED):
        if samples < 2:
            raise ValueError(f"MC mode {mode}: needs at least 2 samples (one per side), got {samples}")
        base = mode.removesuffix(MIRRORED)
        direct = draw_samples(model, images, (samples + 1) // 2, seed, base)
        mirror = draw_samples(model, torch.flip(images, dims=[-1]), samples // 2, seed + 1, base)
        vectors = mirror.vectors * np.array([-1.0, 1.0, 1.0])
        inverse = None
        if direct.inverse_concentration is not None and mirror.inverse_concentration is not None:
            inverse = np.concatenate([direct.inverse_concentration, mirror.inverse_concentration])
        return Draws(np.concatenate([direct.vectors, vectors]), inverse)
    state = torch.get_rng_state()
    # the CPU generator alone: torch.manual_seed also queues seeds for CUDA, MTIA and XPU, formatting a stack
    # trace for each (~2 ms a call); the passes run on the CPU
    torch.default_generator.manual_seed(seed)
    count = len(images)
    try:
        with torch.no_grad():
            model.eval()
            # the passes as one batch of copies (each row its own dropout masks), in chunks of at most
            # PASS_BATCH rows: the head mode copies the pooled features (the backbone once, deterministic), the
            # full mode the stem's (everything before the first dropout, the same in every pass)
            if mode == "head":
                shared = model.pooled(images)
                model.head.train()
            else:
                shared = model.stem(images)
                model.mc_dropout()  # dropout on everywhere after the stem
            per_chunk = max(1, PASS_BATCH // max(count, 1))
            passes = []
            for start in range(0, samples, per_chunk):
                k = min(per_chunk, samples - start)
                copies = torch.cat([shared] * k)  # pass-major rows: pass i holds rows i * count ... (i + 1) * count - 1
                pooled = copies if mode == "head" else model.pooled_from_stem(copies)
                vectors, kappa = model.outputs(pooled)
                passes += [
                    (vectors[i * count : (i + 1) * count], None if kappa is None else kappa[i * count : (i + 1) * count])
                    for i in range(k)
                ]
            vectors = torch.stack([v for v, _ in passes]).double().numpy()
            kappas = [k for _, k in passes]
            inverse = None if kappas[0] is None else (1.0 / torch.stack(kappas)).double().numpy()  # type: ignore[arg-type]
            return Draws(vectors, inverse)
    finally:
        model.eval()
        torch.set_rng_state(state)


def combine(draws: Draws, calibration: CovarianceCalibration = UNCALIBRATED) -> tuple[Array, Array]:
    """Method I mean (B, 3) and the covariance (B, 2, 2) over (zenith, azimuth), rad²: Method II's sample
    covariance (epistemic) plus the mean over passes of the aleatoric vMF covariance, through ``calibration``
    (scaled, then tau^-1 I added; uncalibrated by default)."""
    mean, covariance = sample_mean_and_covariance(draws.vectors)
    if draws.inverse_concentration is not None:
        covariance = covariance + aleatoric_covariance(mean, draws.inverse_concentration.mean(axis=0))
    return mean, calibration.apply(covariance)


def calibrate(
    model: SunBCNN,
    card: ModelCard,
    sequences: list[Path],
    samples: int = 25,
    mode: str = DEFAULT_MODE,
    max_cosine_distance: float = 0.3,
    cache_dir: Path | None = None,
) -> dict[str, float]:
    """The covariance calibration on ``sequences`` (the validation split): tau so that ANEES = 1 over the
    predictions within ``max_cosine_distance`` of the truth (the thesis's code) when the model is overconfident,
    else the scale of :func:`pvo_core.sun.calibrate_scale` (tau cannot narrow a covariance); the figures,
    ANEES over the kept predictions and over all, before and after."""
    from pvo_core.readers import read_kitti_sun_csv
    from pvo_core.sun import anees, calibrate_scale, calibrate_tau, zenith_azimuth_residuals

    residuals, covariances, distances = [], [], []
    for sequence in sequences:
        predictions = predict_sequence(model, card, sequence, samples, mode=mode, calibration=UNCALIBRATED, cache_dir=cache_dir)
        truth = read_kitti_sun_csv(Path(sequence) / "sun.csv")[predictions.frames]
        residuals.append(zenith_azimuth_residuals(predictions.vectors, truth))
        covariances.append(predictions.covariance)
        distances.append(1.0 - np.sum(predictions.vectors * truth, axis=1))
    r, c, d = np.vstack(residuals), np.concatenate(covariances), np.concatenate(distances)
    keep = d < max_cosine_distance
    if not keep.any():
        raise ValueError(
            f"none of the {len(r)} validation predictions is within cosine distance {max_cosine_distance} of the true sun: "
            "the model is too far off to calibrate its covariance"
        )
    tau = calibrate_tau(r, c, keep)
    calibration = CovarianceCalibration(tau=tau, scale=calibrate_scale(r, c, keep) if np.isinf(tau) else 1.0)
    stated = calibration.apply(c)
    return {
        "tau": tau,
        "scale": calibration.scale,
        "images": float(len(r)),
        "kept": float(keep.sum()),
        "anees_uncalibrated": anees(r[keep], c[keep]),
        "anees": anees(r[keep], stated[keep]),
        "anees_all_uncalibrated": anees(r, c),
        "anees_all": anees(r, stated),
        "samples": float(samples),
        "max_cosine_distance": max_cosine_distance,
    }
