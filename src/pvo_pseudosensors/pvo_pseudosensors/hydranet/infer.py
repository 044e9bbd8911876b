"""HydraNet on a sequence: the flow of every consecutive pair of left images through the network, the mean
rotation with Sigma = Sigma_e + Sigma_a per pair, and the prediction file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.readers import ROTATION_PREDICTIONS_HEADER

from ..learning.checkpoint import ModelCard, load_model
from ..learning.data import Source
from .config import ARCHITECTURE, HydraNetConfig
from .flow import FlowPairs, network_input
from .model import HydraNet, inference_mode, predict_rotations

Array = NDArray[np.float64]


def load_hydranet(directory: Path) -> tuple[HydraNet, ModelCard]:
    """The trained network of ``directory`` in eval mode (one clear line for every bad model file)."""
    model, card = load_model(Path(directory), ARCHITECTURE, lambda card: HydraNet(HydraNetConfig.from_card(card)))
    model.eval()
    return model, card


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


def predict_flows(model: HydraNet, flows: torch.Tensor, batch: int = 64, mirrored: bool = False) -> tuple[Array, Array, Array]:
    """Quaternions (N, 4), Sigma_e and Sigma_a (N, 3, 3) for network inputs (N, C, H, W), in batches
    (``mirrored``: :func:`~.model.predict_rotations`' mirrored inference)."""
    parts = [predict_rotations(model, flows[start : start + batch], mirrored) for start in range(0, len(flows), batch)]
    return tuple(torch.cat([getattr(p, name) for p in parts]).numpy() for name in ("quaternion", "epistemic", "aleatoric"))  # type: ignore[return-value]


def predict_sequence(
    model: HydraNet, card: ModelCard, sequence: Path, batch: int = 64, cache_dir: Path | None = None
) -> RotationPredictions:
    """Every consecutive pair of ``sequence``'s left images (KITTI layout; poses.txt not needed), run as the
    card's ``calibration.mode`` says (plain or mirrored)."""
    config = HydraNetConfig.from_card(card)
    mirrored = inference_mode(card)
    sequence = Path(sequence)
    data = FlowPairs([Source(sequence, sequence.name)], config.size, reverse=False, cache_dir=cache_dir, targets=False)
    pairs = data.pairs[0]
    flows = np.asarray(pairs.forward, dtype=np.float32)
    if config.texture:
        flows = np.stack([network_input(image[0], flow, True) for image, flow in zip(pairs.images[:-1], flows, strict=True)])
    flows = torch.from_numpy(flows)
    quaternions, epistemic, aleatoric = predict_flows(model, flows, batch, mirrored)
    frames = np.arange(1, len(flows) + 1)
    return RotationPredictions(frames - 1, frames, quaternions, epistemic, aleatoric)
