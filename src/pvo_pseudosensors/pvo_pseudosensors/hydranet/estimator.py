"""HydraNet as a sensor: consecutive images in, the relative rotation with its covariance out (no ROS; the
node wraps it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from ..learning.checkpoint import ModelFileError
from ..learning.checkpoint import resolve_model as resolve_shipped
from .config import SHIPPED, HydraNetConfig
from .flow import dense_flow, network_input
from .infer import load_hydranet
from .model import inference_mode, predict_rotations
from .shortfall import flow_shortfall

Array = NDArray[np.float64]
UNMEASURED = 9999.0  # variance of a RelativePose's translation block: HydraNet says nothing about it


def resolve_model(model: str) -> Path:
    """The ``model`` parameter as a directory: "" is the shipped synthetic model, ``hydranet``,
    ``hydranet_kitti`` or ``hydranet_level`` (when no such local path exists) a shipped one, anything else a path."""
    return resolve_shipped(model, SHIPPED)


@dataclass(frozen=True)
class HydraNetSensorConfig:
    """model: the model directory ("" = the shipped synthetic model, told the camera's pitch; "hydranet_kitti" =
    the one fine-tuned on KITTI; "hydranet_level" = the level cameras' model without the pitch input); max_gap:
    seconds between two images beyond which they are not paired (a dropped stretch of images: the next one starts
    afresh); threads: torch threads; camera_pitch_deg: the camera's pitch below the horizon (deg, a mount
    calibration; 0 = level, as KITTI's), read only by a model trained with the pitch input (the default is)."""

    model: str = ""
    max_gap: float = 0.5
    threads: int = 1
    camera_pitch_deg: float = 0.0

    def __post_init__(self) -> None:
        if not self.max_gap > 0.0:
            raise ValueError(f"max_gap must be > 0 s, got {self.max_gap}")
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")
        if not -90.0 <= self.camera_pitch_deg <= 90.0:  # also NaN
            raise ValueError(f"camera_pitch_deg must be in [-90, 90] deg, got {self.camera_pitch_deg}")


@dataclass
class RotationEstimate:
    """C_k,k-1 between the images at ``earlier_stamp`` and ``stamp`` (ns): unit quaternion (4,) (w, x, y, z),
    Sigma_e and Sigma_a (3, 3) in rad², left tangent space."""

    earlier_stamp: int
    stamp: int
    quaternion: Array
    epistemic: Array
    aleatoric: Array

    @property
    def covariance(self) -> Array:
        return self.epistemic + self.aleatoric

    @property
    def pose_covariance(self) -> Array:
        return pose_covariance(self.covariance)


def pose_covariance(rotation_covariance: Array) -> Array:
    """(6, 6) in ROS order (x y z rotX rotY rotZ) as a ``RelativePose`` carries a rotation: Sigma (3, 3) in the
    rotation block, the translation marked unmeasured (:data:`UNMEASURED` on its diagonal)."""
    covariance = np.diag([UNMEASURED] * 3 + [0.0] * 3)
    covariance[3:, 3:] = rotation_covariance
    return covariance


class HydraNetSensor:
    """Loads the model once (``ModelFileError``, one line, when it cannot) and pairs each 8-bit image with the
    one before it (resized to the model's input; colour converted to grey). :meth:`estimate` returns None for
    an image with no usable predecessor (the first, one after a gap) and raises ``ValueError`` naming what is
    wrong with a bad image (that image is dropped; the last good one stays the predecessor) or a size change
    (the new image starts afresh)."""

    def __init__(self, config: HydraNetSensorConfig) -> None:
        self.config = config
        torch.set_num_threads(config.threads)
        self.model, self.card = load_hydranet(resolve_model(config.model))
        self.height, self.width = (int(v) for v in self.card.input["size"])
        network = HydraNetConfig.from_card(self.card)
        if network.depth:  # it would need the right image and the stereo calibration with every left one
            raise ModelFileError(
                f"{resolve_model(config.model)}: a HydraNet with the depth input (stereo) is read by `pvo hydranet "
                "predict` only; the sensor and the hydranet node read the left image alone"
            )
        if network.gap != 1:  # it would pair each image with the one `gap` frames before, every gap-th frame
            raise ModelFileError(
                f"{resolve_model(config.model)}: a HydraNet reading images {network.gap} frames apart is read by `pvo "
                "hydranet predict` only; the sensor and the hydranet node pair consecutive images"
            )
        self.texture, self.flow_prior = network.texture, network.flow_prior
        self.pitch_deg = self.config.camera_pitch_deg if network.pitch else None
        self.mode = inference_mode(self.card)
        self.previous: NDArray[np.uint8] | None = None
        self.previous_stamp = 0
        self.previous_shape: tuple[int, ...] = ()

    def reset(self) -> None:
        self.previous = None

    def estimate(self, image: NDArray[np.uint8], stamp: int) -> RotationEstimate | None:
        import cv2

        if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
            raise ValueError(f"HydraNet takes 8-bit grey or RGB images, got {image.dtype} of shape {image.shape}")
        if self.previous is not None and stamp <= self.previous_stamp:
            raise ValueError(f"stamp {stamp * 1e-9:.3f} s is not after the previous image's {self.previous_stamp * 1e-9:.3f} s")
        shape = image.shape
        grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        resized = cv2.resize(grey, (self.width, self.height), interpolation=cv2.INTER_AREA)
        previous, previous_stamp, previous_shape = self.previous, self.previous_stamp, self.previous_shape
        self.previous, self.previous_stamp, self.previous_shape = resized, stamp, shape
        if previous is None or (stamp - previous_stamp) * 1e-9 > self.config.max_gap:
            return None
        if shape != previous_shape:
            raise ValueError(f"image size changed from {previous_shape} to {shape}: this image starts a new pair")
        forward = dense_flow(previous, resized, self.flow_prior)
        flow = torch.from_numpy(network_input(previous, forward, self.texture, self.pitch_deg))[None]
        backward = None
        if self.mode == "reversed":
            backward = torch.from_numpy(
                network_input(resized, dense_flow(resized, previous, self.flow_prior), self.texture, self.pitch_deg)
            )[None]
        output = predict_rotations(self.model, flow, self.mode == "mirrored", backward)
        epistemic, aleatoric = output.epistemic[0].numpy(), output.aleatoric[0].numpy()
        shortfall = getattr(self.model, "shortfall_widening", None)
        if shortfall is not None:  # where the flow did not follow the image: Sigma_a widened, counted in Sigma_e
            d = flow_shortfall(previous, resized, forward, shortfall.min_response)
            epistemic = shortfall.widen(epistemic[None], aleatoric[None], [d])[0]
        return RotationEstimate(previous_stamp, stamp, output.quaternion[0].numpy(), epistemic, aleatoric)
