"""DPC-Net as a sensor: stereo images and the VO's frame-to-frame transforms in, a correction of the VO's
Δp-frame transform out (no ROS; the node wraps it)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.lie import se3_exp

from ..learning.checkpoint import resolve_model as resolve_shipped
from .config import DPCNetConfig
from .infer import UNMEASURED, correction_outputs, load_dpc_net, measurement_covariance, mirror_baseline, residual_mean
from .rig import Rig, rig_problems

Array = NDArray[np.float64]
SHIPPED = ("dpc_net", "dpc_net_clean")  # the lens rig (Table 6.2), the clean rig (the demo's sample)


def resolve_model(model: str) -> Path:
    """ "" is the shipped model (``dpc_net``), ``dpc_net_clean`` the shipped clean-rig one, anything else a path."""
    return resolve_shipped(model, SHIPPED)


@dataclass(frozen=True)
class DPCNetSensorConfig:
    """model: the model directory ("" = the shipped one); threads: torch threads; lost_variance: a VO transform
    with a variance at least this (m², rad²) is a lost frame (the fusion's ``inputs.vo.lost_variance``); any_rig:
    use the model even on a camera its card's rig check refuses. The span Δp is the model's (its card's
    ``test_delta``): one correction every Δp VO frames, from frame k - Δp to frame k."""

    model: str = ""
    threads: int = 1
    lost_variance: float = 1000.0
    any_rig: bool = False

    def __post_init__(self) -> None:
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")
        if not self.lost_variance > 0.0:
            raise ValueError(f"lost_variance must be positive, got {self.lost_variance}")


@dataclass
class Correction:
    """T_k,k-Δp corrected (exp(ξ^) T̂, 4x4) between the frames at ``reference_stamp`` and ``stamp`` (ns), and
    its covariance (6, 6) ROS order, left perturbation."""

    reference_stamp: int
    stamp: int
    transform: Array
    covariance: Array


class DPCNetSensor:
    """Keeps the last frames' stereo images (resized) and the VO transforms since the window's first frame; each
    VO transform that completes a window of Δp frames gives one correction. A window the model cannot correct
    gives none, and :attr:`dropped` says why: a VO transform that does not continue the chain (a gap: a new
    window starts at its reference), a lost VO frame inside the window, a stereo pair missing at either end,
    or the images changing size between the ends. A window whose stereo pair has not arrived yet when its last
    VO transform does (in a node graph the VO can answer before this sensor has the images) waits for it:
    :meth:`add_images` gives its correction then; the next completed window gives the waiting one up."""

    def __init__(self, config: DPCNetSensorConfig) -> None:
        torch.set_num_threads(config.threads)
        self.config = config
        self.model, self.card = load_dpc_net(resolve_model(config.model))
        self.settings = DPCNetConfig.from_card(self.card)
        if self.settings.variant != "pose":
            raise ValueError(f"the dpc_net sensor needs a pose model; this one is {self.settings.variant!r}")
        self.delta = self.settings.test_delta
        self.covariance = measurement_covariance(self.settings, self.card.calibration)
        # exp(b^): the validation mean error taken off every correction where the card chose it (identity otherwise)
        self.mean_removal = se3_exp(residual_mean(self.card.calibration))
        # each window also through the mirror, the two corrections averaged, where the card was calibrated so
        self.mirrored = bool(self.card.calibration.get("mirrored", False))
        self.baseline = mirror_baseline(self.card)
        self.images: dict[int, NDArray[np.uint8]] = {}
        self.sizes: dict[int, tuple[int, ...]] = {}
        self.chain: deque[tuple[int, Array]] = deque()  # (stamp, T_k,k-1) since the window's first frame
        self.first: int | None = None
        self.lost_at: int | None = None  # a lost VO frame inside the current window
        self.dropped: str | None = None  # why the last window gave no correction
        self.pending: tuple[int, int, Array] | None = None  # (first, last, VO estimate): a window awaiting images

    @property
    def vo_differences(self) -> dict[str, Any]:
        """The settings (dotted names) in which the VO the model learned differs from the VO's defaults now."""
        from .config import vo_differences

        return vo_differences((self.card.input.get("rig") or {}).get("vo_settings") or {})

    @property
    def measures_anything(self) -> bool:
        """Whether the card's calibration measures any axis (none when its validation drives refused every weighing,
        ``fused_axes: []``): else the corrections carry no weight in the fusion."""
        return bool(np.any(np.diag(self.covariance) < UNMEASURED))

    def check_camera(self, width: int, height: int, focal_px: float, baseline_m: float) -> tuple[list[str], list[str]]:
        """(refusals, warnings) of the model's rig check for a camera of this size and calibration (what its
        camera_info states; the lens and a calibration error cannot be seen there)."""
        rig = Rig((int(width), int(height)), float(focal_px), float(baseline_m), None, None, None)
        return rig_problems(self.card.input.get("rig"), rig)

    def add_images(self, stamp: int, left: NDArray[np.uint8], right: NDArray[np.uint8]) -> Correction | None:
        """A stereo pair (8-bit grey or RGB, equal sizes); ``ValueError`` naming what is wrong. The correction of a
        window that was waiting for this pair, else None."""
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
        self.sizes[stamp] = left.shape[:2]
        while len(self.images) > 4 * (self.delta + 1):  # older than any window can need
            oldest = min(self.images)
            del self.images[oldest], self.sizes[oldest]
        if self.pending is not None and all(s in self.images for s in self.pending[:2]):
            first, last, estimate = self.pending
            self.pending = None
            return self._correct(first, last, estimate)
        return None

    def add_vo(self, reference_stamp: int, stamp: int, transform: Array, covariance: Array | None = None) -> Correction | None:
        """The VO's T_k,k-1 (and its covariance (6, 6), if known); the correction when it completes a window, else
        None — with :attr:`dropped` saying why when a window was given up."""
        self.dropped = None
        last = self.chain[-1][0] if self.chain else self.first
        if last is None or reference_stamp != last:  # the first transform, or a broken chain: a new window
            if self.chain:
                self.dropped = (
                    f"VO gap: the transform to {stamp * 1e-9:.3f} s starts at {reference_stamp * 1e-9:.3f} s, not at the "
                    f"window's last frame {last * 1e-9:.3f} s; the window from {self.first * 1e-9:.3f} s is dropped"
                )
            self.first, self.chain, self.lost_at = reference_stamp, deque(), None
        variances = np.diag(np.asarray(covariance, dtype=float)) if covariance is not None else np.zeros(6)
        if self.lost_at is None and (not np.all(np.isfinite(variances)) or variances.max() >= self.config.lost_variance):
            self.lost_at = stamp
        self.chain.append((stamp, np.asarray(transform, dtype=float)))
        if len(self.chain) < self.delta:
            return None
        first, chain, lost_at = self.first, list(self.chain), self.lost_at
        self.first, self.chain, self.lost_at = stamp, deque(), None
        span = f"the window {first * 1e-9:.3f}-{stamp * 1e-9:.3f} s"
        if lost_at is not None:
            self.dropped = (
                f"{span} is dropped: the VO was lost at {lost_at * 1e-9:.3f} s (variance >= {self.config.lost_variance:g})"
            )
            return None
        if self.pending is not None:  # its images never came; this window is newer
            waited = self.pending
            self.dropped = (
                f"the window {waited[0] * 1e-9:.3f}-{waited[1] * 1e-9:.3f} s is dropped: no stereo pair at "
                + ", ".join(f"{s * 1e-9:.3f} s" for s in waited[:2] if s not in self.images)
            )
            self.pending = None
        estimate = np.eye(4)
        for _, step in chain:
            estimate = step @ estimate
        if first not in self.images or stamp not in self.images:
            self.pending = (first, stamp, estimate)
            return None
        return self._correct(first, stamp, estimate)

    def _correct(self, first: int, last: int, estimate: Array) -> Correction | None:
        """The corrected window ``first``-``last`` (both pairs here) from the VO's composed ``estimate``."""
        if self.sizes[first] != self.sizes[last]:
            self.dropped = (
                f"the window {first * 1e-9:.3f}-{last * 1e-9:.3f} s is dropped: the images changed size from "
                f"{self.sizes[first][1]}x{self.sizes[first][0]} to {self.sizes[last][1]}x{self.sizes[last][0]}"
            )
            return None
        frames = [torch.from_numpy(self.images[s].astype(np.float32)[None] / 255.0) for s in (first, last)]
        xi = correction_outputs(self.model, self.settings, *frames, estimate[None], self.mirrored, self.baseline)[0]
        return Correction(first, last, self.mean_removal @ se3_exp(xi) @ estimate, self.covariance.copy())
