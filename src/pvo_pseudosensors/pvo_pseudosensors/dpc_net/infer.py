"""DPC-Net on a sequence: corrections of the VO's Δp-frame transforms, and the VO and the corrections fused
through :class:`pvo_fusion.FusionGraph` — the thesis's pose-graph relaxation (§6.4.5) done by the fixed-lag
smoother, instead of the authors' shipped code that overwrote every Δp-th pose."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.lie import se3_exp

from ..learning.checkpoint import ModelCard, load_model
from ..learning.data import Source, cached_images
from .config import ARCHITECTURE, DPCNetConfig
from .model import DPCNet

Array = NDArray[np.float64]
CORRECTIONS_HEADER = (
    "frame_first,frame_last,"
    + ",".join(f"t{i}{j}" for i in range(3) for j in range(4))
    + ","
    + ",".join(f"c{i}{j}" for i in range(6) for j in range(6))
)


def load_dpc_net(directory: Path) -> tuple[DPCNet, ModelCard]:
    """The trained network of ``directory`` in eval mode (one clear line for every bad model file)."""
    model, card = load_model(Path(directory), ARCHITECTURE, lambda card: DPCNet(DPCNetConfig.from_card(card)))
    model.eval()
    return model, card


@dataclass
class Corrections:
    """Per window: first and last frame (N,), the corrected transform T_last,first = exp(ξ^) T̂ (N, 4, 4) and its
    covariance (N, 6, 6) in ROS order (x y z rotX rotY rotZ), left perturbation."""

    first: NDArray[np.int64]
    last: NDArray[np.int64]
    transforms: Array
    covariances: Array

    def write_csv(self, path: Path) -> Path:
        rows = [CORRECTIONS_HEADER]
        for a, b, t, c in zip(self.first, self.last, self.transforms, self.covariances, strict=True):
            rows.append(f"{int(a)},{int(b)}," + ",".join(f"{v:.9g}" for v in [*t[:3].reshape(-1), *c.reshape(-1)]))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(rows) + "\n")
        return path


def predict_corrections(model: DPCNet, card: ModelCard, sequence: Path, vo: Array, cache_dir: Path | None = None) -> Corrections:
    """Corrections of the VO's transforms (camera-to-odom poses ``vo`` (N, 4, 4)) over consecutive windows of
    the card's ``test_delta`` frames (0 → Δp, Δp → 2Δp, ...). Pose variant only. The covariance is the training
    targets' (eq. 6.6, in the card), an upper bound on the corrected transform's error."""
    config = DPCNetConfig.from_card(card)
    if config.variant != "pose":
        raise ValueError(f"predicting corrections needs the pose variant; this model is {config.variant!r}")
    source = Source(Path(sequence), Path(sequence).name)
    size = (config.height, config.width)
    left = cached_images(source.images("left", False), size, False, cache_dir)
    right = cached_images(source.images("right", False), size, False, cache_dir)
    if len(vo) != len(left):
        raise ValueError(f"the VO has {len(vo)} poses for the {len(left)} images of {sequence}")
    delta = config.test_delta
    last = np.arange(delta, len(left), delta)
    first = last - delta

    def frames(index: NDArray[np.int64]) -> torch.Tensor:
        return torch.from_numpy(np.concatenate([left[index], right[index]], axis=1).astype(np.float32) / 255.0)

    with torch.no_grad():
        xi = model(frames(first), frames(last)).double().numpy() if len(last) else np.zeros((0, 6))
    estimate = np.linalg.inv(vo[last]) @ vo[first]
    transforms = np.stack([se3_exp(x) @ t for x, t in zip(xi, estimate, strict=True)]) if len(last) else np.zeros((0, 4, 4))
    covariance = np.asarray(card.calibration["target_covariance"], dtype=float)
    return Corrections(first, last, transforms, np.broadcast_to(covariance, (len(last), 6, 6)).copy())
