"""The Sun-BCNN network, its loss and its MC-dropout prediction.

A small CNN for a CPU (input and widths in :class:`SunBCNNConfig`), dropout after the convolutional blocks
and the fully connected layer, a unit-norm 3-vector output in the camera's optical frame (x right, y down,
z forward), trained with the loss 1 - s·ŝ (thesis eq. 5.3). At test time N stochastic passes with dropout
on; the mean direction is the normalised mean of the samples (Method I of §5.3).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from ..learning.checkpoint import ModelCard
from ..learning.data import DataSpec

ARCHITECTURE = "sun-bcnn"


@dataclass(frozen=True)
class SunBCNNConfig:
    """height, width: the input (px); colour: RGB or grey; widths: channels of the convolutional blocks (each
    a stride-2 3x3 convolution and a 3x3 one); hidden: the fully connected layer; dropout: probability after
    every block and the hidden layer (kept on for MC sampling)."""

    height: int = 94
    width: int = 310
    colour: bool = False
    widths: tuple[int, ...] = (16, 32, 64, 96)
    hidden: int = 128
    dropout: float = 0.2

    def __post_init__(self) -> None:
        if min(self.height, self.width) < 16 or not self.widths or not 0.0 <= self.dropout < 1.0:
            raise ValueError("Sun-BCNN needs an input of at least 16 px, at least one block and dropout in [0, 1)")

    @property
    def spec(self) -> DataSpec:
        return DataSpec((self.height, self.width), colour=self.colour, sun=True)

    @classmethod
    def from_card(cls, card: ModelCard) -> SunBCNNConfig:
        values = dict(card.hyperparameters)
        values["widths"] = tuple(values["widths"])
        return cls(**values)


class SunBCNN(nn.Module):
    def __init__(self, config: SunBCNNConfig) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        channels = 3 if config.colour else 1
        for width in config.widths:
            layers += [
                nn.Conv2d(channels, width, 3, stride=2, padding=1),
                nn.ReLU(inplace=True),
                nn.Conv2d(width, width, 3, padding=1),
                nn.ReLU(inplace=True),
                nn.Dropout2d(config.dropout),
            ]
            channels = width
        self.features = nn.Sequential(*layers)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(channels * 2, config.hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(config.dropout),
            nn.Linear(config.hidden, 3),
        )

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) in [0, 1] -> (B, 3) unit vectors towards the sun."""
        x = self.features(image - 0.5)
        pooled = torch.cat([x.mean(dim=(2, 3)), x.amax(dim=(2, 3))], dim=1)  # average and max pooling
        return nn.functional.normalize(self.head(pooled), dim=1)


@dataclass
class SunTask:
    """Sun-BCNN for the training loop: loss 1 - s·ŝ averaged over the batch."""

    config: SunBCNNConfig
    architecture: str = ARCHITECTURE

    def build(self) -> nn.Module:
        return SunBCNN(self.config)

    def loss(self, model: nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        predicted = model(batch["left"])
        return (1.0 - (predicted * batch["sun"]).sum(dim=1)).mean()

    def card(self) -> ModelCard:
        spec = self.config.spec
        return ModelCard(
            architecture=ARCHITECTURE,
            hyperparameters=asdict(self.config),
            input={"size": list(spec.size), "colour": spec.colour, "normalisation": "grey levels / 255, minus 0.5"},
        )


def predict_sun(model: SunBCNN, images: torch.Tensor, samples: int = 25, seed: int = 0) -> NDArray[np.float64]:
    """MC-dropout samples (samples, B, 3) of the unit sun vector for images (B, C, H, W), seeded."""
    generator_state = torch.get_rng_state()
    torch.manual_seed(seed)
    model.train()  # dropout on
    try:
        with torch.no_grad():
            draws = torch.stack([model(images) for _ in range(samples)])
    finally:
        model.eval()
        torch.set_rng_state(generator_state)
    return draws.double().numpy()
