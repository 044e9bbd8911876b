"""DPC-Net's settings (no torch)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

ARCHITECTURE = "dpc-net"
VARIANTS = {"pose": 6, "rotation": 3, "yaw": 1}  # Table 6.1: SE(3), SO(3) from monocular input, yaw only


@dataclass(frozen=True)
class DPCNetConfig:
    """height, width: the images' size at the input (px); stem: channels of the siamese stem's three 3x3
    convolutions (stride 2, 2, 1), shared by the two frames; body: channels of the stride-2 convolutions on the
    two stems' concatenated maps; dropout: after every convolution (with PReLU, no pooling, no batch norm, as
    the thesis); variant: pose (a 6-vector ξ from both stereo pairs), rotation (3-vector φ from the left
    images) or yaw (one angle); deltas: the frame spans Δp of the training windows (thesis {3, 4, 5}; {2, 3,
    4} for distorted images), test_delta: the span at prediction (4, or 3); vo_input (beyond the thesis): the
    VO's own estimate of the window, log(T̂_last,first) = [ρ; φ], also goes in, through a linear map added to the
    image head's output (zero at the start) — a wrong calibration biases the VO in proportion to its motion,
    which the images alone show only as well as a second VO would."""

    height: int = 64
    width: int = 208
    stem: tuple[int, ...] = (16, 16, 32)
    body: tuple[int, ...] = (64, 128, 256, 256)
    dropout: float = 0.3
    variant: str = "pose"
    deltas: tuple[int, ...] = (3, 4, 5)
    test_delta: int = 4
    vo_input: bool = False

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown variant {self.variant!r}: choose one of {', '.join(VARIANTS)}")
        if len(self.stem) != 3 or not self.body or min(self.height, self.width) < 16:
            raise ValueError("DPC-Net needs three stem widths, at least one body width and an input of >= 16 px")
        if not self.deltas or min(self.deltas) < 1 or self.test_delta < 1:
            raise ValueError(f"the frame spans must be >= 1, got deltas {self.deltas} and test_delta {self.test_delta}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")

    @property
    def outputs(self) -> int:
        return VARIANTS[self.variant]

    @property
    def stereo(self) -> bool:
        """Whether each frame's input is the stereo pair (pose) or the left image alone (rotation, yaw)."""
        return self.variant == "pose"

    @classmethod
    def from_card(cls, card: Any) -> DPCNetConfig:
        values = dict(card.hyperparameters)
        for name in ("stem", "body", "deltas"):
            values[name] = tuple(values[name])
        return cls(**values)
