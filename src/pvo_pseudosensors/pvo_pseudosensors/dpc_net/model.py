"""The DPC-Net network (thesis §6.4, Fig. 6.2, sized for a CPU) and its training task.

Each frame's images (left and right stacked, or the left alone) go through one shared stem; the two stems'
maps are concatenated and reduced by stride-2 convolutions to a correction: ξ (pose), φ (rotation) or a yaw
angle. Every convolution is followed by PReLU and dropout; there is no pooling and no batch norm; the last
layer (a convolution over the whole remaining map) starts at zero, so an untrained network corrects nothing.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from torch import nn

from ..learning.checkpoint import ModelCard
from .config import ARCHITECTURE, DPCNetConfig
from .loss import se3_loss, so3_loss, yaw_loss


def _block(inputs: int, outputs: int, stride: int, dropout: float) -> list[nn.Module]:
    return [nn.Conv2d(inputs, outputs, 3, stride=stride, padding=1), nn.PReLU(outputs), nn.Dropout(dropout)]


class DPCNet(nn.Module):
    def __init__(self, config: DPCNetConfig) -> None:
        super().__init__()
        self.config = config
        channels = 2 if config.stereo else 1
        stem: list[nn.Module] = []
        for width, stride in zip(config.stem, (2, 2, 1), strict=True):
            stem += _block(channels, width, stride, config.dropout)
            channels = width
        self.stem = nn.Sequential(*stem)
        body: list[nn.Module] = []
        channels *= 2
        for width in config.body:
            body += _block(channels, width, 2, config.dropout)
            channels = width
        self.body = nn.Sequential(*body)
        with torch.no_grad():
            sample = torch.zeros(1, 2 if config.stereo else 1, config.height, config.width)
            size = self.body(torch.cat([self.stem(sample), self.stem(sample)], dim=1)).shape[-2:]
        self.head = nn.Conv2d(channels, config.outputs, tuple(size))
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.vo_head: nn.Linear | None = None
        if config.vo_input:
            self.vo_head = nn.Linear(6, config.outputs, bias=False)
            nn.init.zeros_(self.vo_head.weight)

    def forward(self, first: torch.Tensor, last: torch.Tensor, estimate: torch.Tensor | None = None) -> torch.Tensor:
        """The images (B, C, H, W) in [0, 1] of the window's first and last frame (C = 2: left and right, or 1:
        left) and, for a ``vo_input`` model, the VO's estimate (B, 6) log(T̂_last,first) = [ρ (m); φ (rad)] ->
        the correction (B, 6) ξ = [ρ; φ], (B, 3) φ or (B, 1) yaw, applied on the left of the VO's transform
        T_last,first."""
        maps = torch.cat([self.stem(first - 0.5), self.stem(last - 0.5)], dim=1)
        correction = self.head(self.body(maps)).flatten(1)
        if self.vo_head is None:
            return correction
        if estimate is None:
            raise ValueError("this DPC-Net model takes the VO's estimate of the window as input (vo_input), and none was given")
        return correction + self.vo_head(estimate.to(correction.dtype))


def estimate_input(transforms: np.ndarray) -> torch.Tensor:
    """The VO's window transforms T̂_last,first (N, 4, 4) as a ``vo_input`` network takes them: (N, 6) float32
    log(T̂) = [ρ; φ]."""
    from pvo_core.lie import se3_log

    logs = np.array([se3_log(t) for t in np.asarray(transforms, dtype=float)]).reshape(-1, 6)
    return torch.from_numpy(logs.astype(np.float32))


@dataclass
class DPCTask:
    """DPC-Net for the training loop: the variant's loss against the targets T* = T_gt T̂^-1, weighted by the
    inverse of the training targets' covariance (eq. 6.6; ``covariance``, (6, 6) for the pose variant, its
    rotation block for the rotation variant); ``rig``: the training sequences' camera (:func:`.rig.training_rig`),
    which the card records so that the model is not used on another."""

    config: DPCNetConfig
    covariance: np.ndarray = field(default_factory=lambda: np.eye(6))
    rig: dict | None = None
    architecture: str = ARCHITECTURE

    def build(self) -> nn.Module:
        return DPCNet(self.config)

    def loss(self, model: nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        correction = model(batch["first"], batch["last"], batch.get("estimate"))
        target = batch["target"].double()
        if self.config.variant == "pose":
            return se3_loss(correction.double(), target, torch.from_numpy(self.covariance)).to(correction.dtype)
        if self.config.variant == "rotation":
            return so3_loss(correction.double(), target[:, :3, :3], torch.from_numpy(self.covariance[3:, 3:])).to(
                correction.dtype
            )
        return yaw_loss(correction, batch["target_yaw"])

    def card(self) -> ModelCard:
        return ModelCard(
            architecture=ARCHITECTURE,
            hyperparameters=asdict(self.config),
            input={
                "size": [self.config.height, self.config.width],
                "colour": False,
                "normalisation": (
                    "grey levels / 255, minus 0.5; left and right stacked per frame"
                    if self.config.stereo
                    else "grey levels / 255, minus 0.5; left image"
                )
                + ("; and the VO's log(T̂_last,first) = [ρ (m); φ (rad)]" if self.config.vo_input else ""),
            }
            | ({"rig": self.rig} if self.rig else {}),
            calibration={"target_covariance": self.covariance.tolist()},
        )
