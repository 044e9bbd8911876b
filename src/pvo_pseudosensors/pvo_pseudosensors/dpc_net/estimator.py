"""DPC-Net as a sensor: stereo images and the VO's frame-to-frame transforms in, a correction of the VO's
Δp-frame transform out (no ROS; the node wraps it)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.lie import se3_exp

from ..learning.checkpoint import resolve_model as resolve_shipped
from .config import DPCNetConfig
from .infer import load_dpc_net

Array = NDArray[np.float64]
SHIPPED = ("dpc_net",)


def resolve_model(model: str) -> Path:
    """ "" is the shipped model (``dpc_net``), anything else a path."""
    return resolve_shipped(model, SHIPPED)


@dataclass(frozen=True)
class DPCNetSensorConfig:
    """model: the model directory ("" = the shipped one); threads: torch threads. The span Δp is the model's
    (its card's ``test_delta``): one correction every Δp VO frames, from frame k - Δp to frame k."""

    model: str = ""
    threads: int = 1

    def __post_init__(self) -> None:
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")


@dataclass
class Correction:
    """T_k,k-Δp corrected (exp(ξ^) T̂, 4x4) between the frames at ``reference_stamp`` and ``stamp`` (ns), and
    its covariance (6, 6) ROS order, left perturbation."""

    reference_stamp: int
    stamp: int
    transform: Array
    covariance: Array


class DPCNetSensor:
    """Keeps the last Δp + 1 frames' stereo images (resized) and the VO transforms between them; each VO
    transform that completes a window of Δp frames since the last correction gives one. A VO transform that
    does not continue the chain (its reference is not the last frame) starts a new window."""

    def __init__(self, config: DPCNetSensorConfig) -> None:
        torch.set_num_threads(config.threads)
        self.model, self.card = load_dpc_net(resolve_model(config.model))
        self.settings = DPCNetConfig.from_card(self.card)
        if self.settings.variant != "pose":
            raise ValueError(f"the dpc_net sensor needs a pose model; this one is {self.settings.variant!r}")
        self.delta = self.settings.test_delta
        self.covariance = np.asarray(self.card.calibration["target_covariance"], dtype=float)
        self.images: dict[int, NDArray[np.uint8]] = {}
        self.chain: deque[tuple[int, Array]] = deque()  # (stamp, T_k,k-1) since the window's first frame
        self.first: int | None = None

    def add_images(self, stamp: int, left: NDArray[np.uint8], right: NDArray[np.uint8]) -> None:
        """A stereo pair (8-bit grey or RGB, equal sizes); ``ValueError`` naming what is wrong."""
        import cv2

        if left.shape != right.shape:
            raise ValueError(f"left and right images differ in size: {left.shape} and {right.shape}")
        planes = []
        for image in (left, right):
            if image.dtype != np.uint8 or image.ndim not in (2, 3):
                raise ValueError(f"DPC-Net takes 8-bit grey or RGB images, got {image.dtype} of shape {image.shape}")
            grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
            planes.append(cv2.resize(grey, (self.settings.width, self.settings.height), interpolation=cv2.INTER_AREA))
        self.images[stamp] = np.stack(planes)
        while len(self.images) > 4 * (self.delta + 1):  # older than any window can need
            del self.images[min(self.images)]

    def add_vo(self, reference_stamp: int, stamp: int, transform: Array) -> Correction | None:
        """The VO's T_k,k-1; the correction when it completes a window, else None."""
        last = self.chain[-1][0] if self.chain else self.first
        if last is None or reference_stamp != last:  # the first transform, or a broken chain: a new window
            self.first, self.chain = reference_stamp, deque()
        self.chain.append((stamp, np.asarray(transform, dtype=float)))
        if len(self.chain) < self.delta:
            return None
        first, chain = self.first, list(self.chain)
        self.first, self.chain = stamp, deque()
        if first not in self.images or stamp not in self.images:
            return None
        estimate = np.eye(4)
        for _, step in chain:
            estimate = step @ estimate
        frames = [torch.from_numpy(self.images[s].astype(np.float32)[None] / 255.0) for s in (first, stamp)]
        with torch.no_grad():
            xi = self.model(frames[0], frames[1]).double().numpy()[0]
        return Correction(first, stamp, se3_exp(xi) @ estimate, self.covariance.copy())
