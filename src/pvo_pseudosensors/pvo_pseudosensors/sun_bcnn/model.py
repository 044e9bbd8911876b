"""The Sun-BCNN network, its loss and its MC-dropout prediction.

A small CNN for a CPU (input and widths in :class:`SunBCNNConfig`), dropout after the convolutional blocks
and the fully connected layer, a unit-norm 3-vector output in the camera's optical frame (x right, y down,
z forward), trained with the loss 1 - s·ŝ (thesis eq. 5.3). Prediction (MC dropout) is in :mod:`.infer`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..learning.checkpoint import ModelCard
from .config import ARCHITECTURE, SunBCNNConfig


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
            nn.Linear(channels * (1 + config.grid[0] * config.grid[1]), config.hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(config.dropout),
            nn.Linear(config.hidden, 3),
        )

    def pooled(self, image: torch.Tensor) -> torch.Tensor:
        """The backbone: (B, C, H, W) in [0, 1] -> (B, (1 + grid cells) x last width): max-pooled features and
        features average-pooled over a grid of image regions."""
        x = self.features(image - 0.5)
        regions = nn.functional.adaptive_avg_pool2d(x, self.config.grid).flatten(1)
        return torch.cat([x.amax(dim=(2, 3)), regions], dim=1)

    def direction(self, pooled: torch.Tensor) -> torch.Tensor:
        """The head: pooled features -> (B, 3) unit vectors towards the sun."""
        return nn.functional.normalize(self.head(pooled), dim=1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) in [0, 1] -> (B, 3) unit vectors towards the sun."""
        return self.direction(self.pooled(image))


@dataclass
class SunTask:
    """Sun-BCNN for the training loop: loss 1 - s·ŝ averaged over the batch."""

    config: SunBCNNConfig
    architecture: str = ARCHITECTURE

    def build(self) -> nn.Module:
        return SunBCNN(self.config)

    def loss(self, model: nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        images, sun = batch["left"], batch["sun"]
        if self.config.mirror and model.training:
            flip = torch.rand(len(images)) < 0.5  # the global RNG: seeded, and checkpointed for --resume
            images = torch.where(flip[:, None, None, None], images.flip(-1), images)
            sun = torch.where(flip[:, None], sun * torch.tensor([-1.0, 1.0, 1.0]), sun)
        predicted = model(images)
        return (1.0 - (predicted * sun).sum(dim=1)).mean()

    def card(self) -> ModelCard:
        spec = self.config.spec
        return ModelCard(
            architecture=ARCHITECTURE,
            hyperparameters=asdict(self.config),
            input={"size": list(spec.size), "colour": spec.colour, "normalisation": "grey levels / 255, minus 0.5"},
        )
