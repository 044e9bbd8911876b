"""HydraNet's settings (no torch: the `pvo hydranet` options are built from them)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..learning.spec import DataSpec

#: Models installed with the package, by name (``model: NAME``).
#: trained on the synthetic corpus and told the camera's pitch (the default since stop 68) / fine-tuned on KITTI 07 /
#: the level cameras' model without the pitch input (the default until stop 68; opt-in)
SHIPPED = ("hydranet", "hydranet_kitti", "hydranet_level")

ARCHITECTURE = "hydranet"
COVARIANCES = ("cholesky", "diagonal")
FLOW_PRIORS = ("none", "shift")  # where Farnebäck starts: zero (the thesis) / the images' global shift (hydranet.flow)


@dataclass(frozen=True)
class HydraNetConfig:
    """height, width: the size (px) both left images are resized to before the dense optical flow between them
    (Farnebäck, the thesis's parameters) is computed; the flow (2, height, width) in pixels at that size is the
    network's input. widths: channels of the body's stride-2 3x3 convolutions (each with batch norm and ReLU);
    feature: the body's output (a linear layer on the flattened last map); heads: H quaternion heads
    (thesis: 25), each Linear -> PReLU -> Dropout -> Linear(4), normalised; head_hidden, head_dropout: their
    hidden width and dropout (off at prediction, as the authors' code); covariance: the aleatoric head's
    form, "cholesky" (a full lower-triangular factor of the precision, the thesis) or "diagonal" (the
    authors' code); reverse: add every training pair reversed (images swapped, target C_k-1,k), as the
    thesis; bootstrap: each head trains on its own fixed half of the samples (bootstrapped heads), so the heads
    disagree more where the data did not pin them down; mirror: in training, each pair is mirrored left-right
    at random (the flow flipped, its horizontal component negated; the rotation's y and z components negated:
    a mirrored drive turns the other way), so that turns either way are learned alike; texture: a third input
    channel, the texture (log gradient magnitude) of the image the flow starts from, to show the network where
    the flow was measured and where interpolated over flat regions; pitch: one more input channel, constant, the
    camera's pitch below the horizon (deg / 10; a mount calibration: the corpus's sim.yaml records it), so that a
    pitched camera's translational flow is not read as rotation; flow_prior: where Farnebäck starts — "none" (zero,
    the thesis; its two-level pyramid at this size under-reads turns beyond ~3° per frame) or "shift" (the images'
    global shift by phase correlation: turns read 98-99 % up to 6° per frame; ``pvo_pseudosensors.hydranet.flow``);
    depth: one more input channel, the inverse depth of the image the flow starts from by stereo matching (the
    right image and calib.txt needed), so that the translation's flow, proportional to it, is told from the turn's
    (beyond the thesis; stop 74's pilot); coordinates: the network adds two channels of its own, each pixel's
    normalised image coordinates ((u - W/2) / W, (v - H/2) / H), so its convolutions can read a turn's flow, a
    fixed function of where the pixel is ("CoordConv"; beyond the thesis; stop 74's pilot); gap: the frames between
    the two images of a pair (1: consecutive, the thesis; g > 1 reads C_k,k-g, so that a chain of readings every g
    frames drifts by g times fewer reading errors; beyond the thesis, stop 75's pilot)."""

    height: int = 64
    width: int = 208
    widths: tuple[int, ...] = (16, 32, 64, 128, 128)
    feature: int = 256
    heads: int = 25
    head_hidden: int = 128
    head_dropout: float = 0.3
    covariance: str = "cholesky"
    reverse: bool = True
    bootstrap: bool = False
    mirror: bool = False
    texture: bool = False
    pitch: bool = False
    flow_prior: str = "none"
    depth: bool = False
    coordinates: bool = False
    gap: int = 1

    def __post_init__(self) -> None:
        if min(self.height, self.width) < 16 or not self.widths:
            raise ValueError("HydraNet needs a flow of at least 16 px and at least one convolution")
        if self.heads < 2:
            raise ValueError(f"HydraNet needs at least 2 heads for its epistemic covariance, got {self.heads}")
        if not 0.0 <= self.head_dropout < 1.0:
            raise ValueError(f"head_dropout must be in [0, 1), got {self.head_dropout}")
        if self.flow_prior not in FLOW_PRIORS:
            raise ValueError(f"unknown flow_prior {self.flow_prior!r}: choose one of {', '.join(FLOW_PRIORS)}")
        if self.gap < 1:
            raise ValueError(f"gap must be >= 1 frame, got {self.gap}")
        if self.covariance not in COVARIANCES:
            raise ValueError(f"unknown covariance {self.covariance!r}: choose one of {', '.join(COVARIANCES)}")

    @property
    def channels(self) -> int:
        """The network's input channels: the flow's two, the texture's, the pitch's and the depth's."""
        return 2 + int(self.texture) + int(self.pitch) + int(self.depth)

    @property
    def size(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def spec(self) -> DataSpec:
        return DataSpec(self.size, delta=self.gap)

    @classmethod
    def from_card(cls, card: Any) -> HydraNetConfig:
        values = dict(card.hyperparameters)
        values["widths"] = tuple(values["widths"])
        values.setdefault("bootstrap", False)  # models from before the options
        values.setdefault("mirror", False)
        values.setdefault("texture", False)
        values.setdefault("pitch", False)
        values.setdefault("flow_prior", "none")
        values.setdefault("depth", False)
        values.setdefault("coordinates", False)
        values.setdefault("gap", 1)
        return cls(**values)
