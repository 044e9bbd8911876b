"""DPC-Net's settings (no torch)."""

from __future__ import annotations

from collections.abc import Mapping
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
    which the images alone show only as well as a second VO would. vo_settings: the stereo VO whose errors it
    learns, as its settings that differ from the defaults (``NAME=VALUE`` items separated by spaces, as ``pvo vo
    -p``); the card records every setting (``input.rig.vo_settings``)."""

    height: int = 64
    width: int = 208
    stem: tuple[int, ...] = (16, 16, 32)
    body: tuple[int, ...] = (64, 128, 256, 256)
    dropout: float = 0.3
    variant: str = "pose"
    deltas: tuple[int, ...] = (3, 4, 5)
    test_delta: int = 4
    vo_input: bool = False
    vo_settings: str = ""

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown variant {self.variant!r}: choose one of {', '.join(VARIANTS)}")
        if len(self.stem) != 3 or not self.body or min(self.height, self.width) < 16:
            raise ValueError("DPC-Net needs three stem widths, at least one body width and an input of >= 16 px")
        if not self.deltas or min(self.deltas) < 1 or self.test_delta < 1:
            raise ValueError(f"the frame spans must be >= 1, got deltas {self.deltas} and test_delta {self.test_delta}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if self.vo_settings:
            try:
                vo_config(self.vo_settings)
            except ValueError as exc:
                raise ValueError(f"vo_settings {self.vo_settings!r}: {exc}") from None

    @property
    def outputs(self) -> int:
        return VARIANTS[self.variant]

    @property
    def stereo(self) -> bool:
        """Whether each frame's input is the stereo pair (pose) or the left image alone (rotation, yaw)."""
        return self.variant == "pose"

    @classmethod
    def from_card(cls, card: Any) -> DPCNetConfig:
        """The card's settings; ``vo_settings`` from the VO its rig record names (every setting, so a card stays
        bound to its VO when the VO's defaults change)."""
        values = dict(card.hyperparameters)
        for name in ("stem", "body", "deltas"):
            values[name] = tuple(values[name])
        rig = (getattr(card, "input", None) or {}).get("rig") or {}
        if rig.get("vo_settings"):
            values["vo_settings"] = settings_against_defaults(rig["vo_settings"])
        return cls(**values)


def vo_config(settings: str | Mapping[str, Any] = "") -> Any:
    """The stereo VO (a ``pvo_frontend.vo.VOConfig``) with ``settings`` over its defaults: ``NAME=VALUE`` items
    separated by spaces (shell-quoted; values read as YAML, as ``pvo vo -p``) or a mapping of dotted names. A bad
    item is a ``ValueError`` naming it."""
    import shlex

    from pvo_core.config import parse_assignments
    from pvo_frontend.vo import from_flat

    if isinstance(settings, str):
        try:
            settings = parse_assignments(shlex.split(settings))
        except ValueError as exc:
            raise ValueError(f"VO setting {exc}") from None
    return from_flat(dict(settings))


def vo_differences(settings: dict[str, Any]) -> dict[str, Any]:
    """Those of the stereo VO ``settings`` (every one, by dotted name, lists for tuples, as a card records them:
    ``flatten``) that differ from the VO's defaults now; ``ValueError`` for a name this VO does not have."""
    from pvo_frontend.vo import VOConfig, flatten

    defaults = flatten(VOConfig())
    unknown = sorted(set(settings) - set(defaults))
    if unknown:
        raise ValueError(f"the card's VO settings name {', '.join(unknown)}, which this VO does not have")
    return {name: value for name, value in settings.items() if defaults[name] != value}


def settings_against_defaults(settings: dict[str, Any]) -> str:
    """The stereo VO ``settings`` (every one, by dotted name) as the ``NAME=VALUE`` items that differ from the
    VO's defaults now (shell-quoted, as ``--vo-settings`` takes them)."""
    import json
    import shlex

    return " ".join(
        shlex.quote(f"{name}={json.dumps(value, separators=(',', ':'))}") for name, value in vo_differences(settings).items()
    )
