"""Sun-BCNN as a sensor: one image in, the sun direction with its covariance out (no ROS; the node wraps it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.sun import unit_zenith_azimuth

from ..learning.checkpoint import resolve_model as resolve_shipped
from .config import SHIPPED
from .infer import MODES, card_calibration, combine, draw_samples, equalize_input, load_sun_bcnn, model_mode

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SunBCNNSensorConfig:
    """model: the model directory ("" = the model shipped in the package, trained on the synthetic corpus;
    "sun_bcnn_kitti" = the shipped one fine-tuned on KITTI); every_n: one estimate every N
    images (the thesis used every 10th); samples: MC-dropout passes; mode: full | head | full-mirrored |
    head-mirrored (see `infer.MODES`), "" = the one the model's τ was calibrated in (its card; the shipped
    ``sun_bcnn``: `infer.DEFAULT_MODE`); seed: of the dropout samples; threads: torch threads; equalize: every
    image histogram-equalised before the network reads it, whatever the model was trained on (`infer.equalize_input`:
    the synthetic model on a real camera)."""

    model: str = ""
    every_n: int = 10
    samples: int = 25
    mode: str = ""
    seed: int = 0
    threads: int = 1
    equalize: bool = False

    def __post_init__(self) -> None:
        if self.every_n < 1 or self.samples < 2 or self.threads < 1:
            raise ValueError("every_n and threads must be >= 1 and samples >= 2")
        if self.mode and self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r}: choose one of {', '.join(MODES)} (or '' for the model's own)")


def resolve_model(model: str) -> Path:
    """The ``model`` parameter as a directory: "" is the shipped synthetic model, a shipped model's name
    (``sun_bcnn``, ``sun_bcnn_kitti``) that is not a local path is that model, anything else a path."""
    return resolve_shipped(model, SHIPPED)


@dataclass
class SunEstimate:
    """Unit vector towards the sun (3,) in the camera optical frame, zenith and azimuth (rad), covariance
    (2, 2) over (zenith, azimuth) in rad²."""

    direction: Array
    zenith: float
    azimuth: float
    covariance: Array


class SunBCNNSensor:
    """Loads the model once (``ModelFileError``, one line, when it cannot) and estimates from 8-bit images of
    any size (resized to the model's input; colour or grey converted to what the model takes)."""

    def __init__(self, config: SunBCNNSensorConfig) -> None:
        self.config = config
        torch.set_num_threads(config.threads)
        self.model, self.card = load_sun_bcnn(resolve_model(config.model))
        if config.equalize:
            equalize_input(self.model)
        self.height, self.width = (int(v) for v in self.card.input["size"])
        self.colour = bool(self.card.input.get("colour", False))
        self.calibration = card_calibration(self.card)
        self.mode = model_mode(self.card, self.config.mode)
        self.count = 0

    def estimate(self, image: NDArray[np.uint8]) -> SunEstimate:
        """The estimate for one image (H, W) or (H, W, 3), uint8; ``ValueError`` naming what is wrong."""
        import cv2

        if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
            raise ValueError(f"Sun-BCNN takes 8-bit grey or RGB images, got {image.dtype} of shape {image.shape}")
        if self.colour and image.ndim == 2:
            raise ValueError("this Sun-BCNN model was trained on colour images; the input is grey")
        if not self.colour and image.ndim == 3:
            image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        resized = cv2.resize(image, (self.width, self.height), interpolation=cv2.INTER_AREA)
        tensor = torch.from_numpy(resized.astype(np.float32) / 255.0)
        tensor = tensor.permute(2, 0, 1)[None] if tensor.ndim == 3 else tensor[None, None]
        seed = self.config.seed + self.count
        self.count += 1
        draws = draw_samples(self.model, tensor, self.config.samples, seed, self.mode)
        mean, covariance = combine(draws, self.calibration)
        zenith, azimuth = unit_zenith_azimuth(mean)
        return SunEstimate(mean[0], float(zenith[0]), float(azimuth[0]), covariance[0])
