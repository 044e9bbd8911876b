"""What a dataset sample carries (no torch: commands read it to build their options)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DataSpec:
    """What every sample carries: the left image at ``size`` (height, width), grey or colour, and optionally
    the right image, the left image ``delta`` frames earlier with the relative pose T_k,k-delta, the sun
    vector, the IMU reading and the left camera's pinhole intrinsics at ``size`` (``camera``)."""

    size: tuple[int, int]
    colour: bool = False
    right: bool = False
    delta: int = 0
    sun: bool = False
    imu: bool = False
    camera: bool = False

    def __post_init__(self) -> None:
        if len(self.size) != 2 or min(self.size) < 8:
            raise ValueError(f"input size must be (height, width) of at least 8 px, got {self.size}")
        if self.delta < 0:
            raise ValueError(f"delta must be >= 0 frames, got {self.delta}")

    @property
    def channels(self) -> int:
        return 3 if self.colour else 1
