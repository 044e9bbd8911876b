"""DPC-Net's training windows: this project's stereo VO run over each sequence once (its poses cached beside
the decoded images), and for every window of Δp frames the images at both ends with the target correction
T* = T_gt T̂^-1 of the VO's transform T̂_k,k-Δp (thesis §6.4.1).

A correction learned this way is for this VO on this camera: the card names both.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.errors import DataFormatError
from pvo_core.lie import so3_log

from ..learning.data import Source, cached_images
from .config import DPCNetConfig, vo_config
from .model import estimate_input
from .rig import Rig, sequence_rig

Array = NDArray[np.float64]


#: VO settings added after cards began to record the VO, each at the value that keeps the VO as it was: left
#: out of the signature, so that an older card still names the same VO (and its cached runs stay valid)
SIGNATURE_NEUTRAL: dict[str, Any] = {"solver.noise_model": "uvd", "probe.gate_threshold": 16.0}


def settings_text(config: Any, prefix: str = "") -> str:
    """``repr`` of a (nested) settings dataclass without the :data:`SIGNATURE_NEUTRAL` entries it holds."""
    if not dataclasses.is_dataclass(config):
        return repr(config)
    parts = []
    for f in dataclasses.fields(config):
        name, value = f"{prefix}{f.name}", getattr(config, f.name)
        if f.repr and not (name in SIGNATURE_NEUTRAL and SIGNATURE_NEUTRAL[name] == value):
            parts.append(f"{f.name}={settings_text(value, f'{name}.')}")
    return f"{type(config).__qualname__}({', '.join(parts)})"


def vo_signature(config: Any = None) -> str:
    """Which VO a correction is for: a digest of this project's stereo VO settings (``config``, a ``VOConfig``;
    the defaults when None). A model card records it; another VO's errors are not the ones it learned."""
    from pvo_frontend.vo import VOConfig

    return hashlib.sha256(settings_text(config or VOConfig()).encode()).hexdigest()[:16]


def card_vo_config(rig: Mapping[str, Any] | None) -> Any:
    """The VO whose errors a model learned, from its card's rig record: ``vo_settings`` (every VO setting by dotted
    name) when the card has them, else the VO's defaults (a card that names its VO by signature alone; the rig
    check warns when the defaults have changed since). Every tool that runs the VO for a model runs this one."""
    if rig and rig.get("vo_settings"):
        config = vo_config(rig["vo_settings"])
        if rig.get("vo") not in (None, vo_signature(config)):
            raise ValueError(f"the card's vo_settings are not the VO {rig['vo']} it names (signature {vo_signature(config)})")
        return config
    return vo_config()


def vo_poses(source: Source, cache_dir: Path | None, config: Any = None) -> Array:
    """The stereo VO's camera poses T_odom,k (N, 4, 4) over ``source`` (``config``: a ``VOConfig``, the defaults
    when None), cached by the VO's settings and the images."""
    from pvo_core.readers import KittiSequence
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig

    config = config or VOConfig()
    sequence = KittiSequence(source.root, rate_hz=10.0)
    file = None
    if cache_dir is not None:
        digest = hashlib.sha256(settings_text(config).encode())
        for path in [*sequence.left_paths, *sequence.right_paths, source.root / "calib.txt"]:
            stat = path.stat()
            digest.update(f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
        file = Path(cache_dir) / f"vo-{digest.hexdigest()[:24]}.npy"
        if file.is_file():
            return np.load(file)
    poses = run_sequence(sequence, config).poses
    if file is not None:
        file.parent.mkdir(parents=True, exist_ok=True)
        np.save(file, poses)
    return poses


def window_targets(ground_truth: Array, estimates: Array, first: NDArray[np.int64], last: NDArray[np.int64]) -> Array:
    """T* = T_gt T̂^-1 (N, 4, 4) for windows from ``first`` to ``last`` (frame indices), T = T_last,first of
    camera-to-world poses: the left correction that turns the VO's transform into the true one."""
    truth = np.linalg.inv(ground_truth[last]) @ ground_truth[first]
    return truth @ np.linalg.inv(window_estimates(estimates, first, last))


def window_estimates(estimates: Array, first: NDArray[np.int64], last: NDArray[np.int64]) -> Array:
    """The VO's T̂_last,first (N, 4, 4) from its camera-to-world poses ``estimates``."""
    return np.linalg.inv(estimates[last]) @ estimates[first]


@dataclass
class DPCWindows(torch.utils.data.Dataset):
    """Samples, one per window (k - Δp, k) of every sequence and every Δp in ``config.deltas`` (``deltas`` to
    override, e.g. the test span): ``first``, ``last`` (C, H, W) float32 in [0, 1] (left and right stacked for
    the pose variant); ``target`` (4, 4) T*; ``estimate`` (6,) the VO's log(T̂_last,first); ``target_yaw`` its
    rotation about the camera's y axis (rad); ``sequence``, ``frame`` (k), ``delta``; ``rigs``: each sequence's
    camera (:mod:`.rig`). The VO whose errors are learned: ``config.vo_settings``."""

    sources: Sequence[Source]
    config: DPCNetConfig
    cache_dir: Path | None = None
    deltas: tuple[int, ...] | None = None
    progress: Callable[[], None] | None = None
    images: list[tuple[NDArray[np.uint8], NDArray[np.uint8] | None]] = field(init=False, default_factory=list)
    index: NDArray[np.int64] = field(init=False)
    targets: Array = field(init=False)
    estimates: torch.Tensor = field(init=False)
    rigs: list[Rig] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        from pvo_core.trajectory import read_kitti_poses

        size = (self.config.height, self.config.width)
        rows, targets, window_logs = [], [], []
        for number, source in enumerate(self.sources):
            poses_file = source.root / "poses.txt"
            if not poses_file.is_file():
                raise DataFormatError(poses_file, f"needed for DPC-Net's targets but missing ({source.name})")
            truth = read_kitti_poses(poses_file)
            estimates = vo_poses(source, self.cache_dir, vo_config(self.config.vo_settings))
            if len(truth) != len(estimates):
                raise DataFormatError(poses_file, f"{len(truth)} poses for {len(estimates)} frames")
            left = cached_images(source.images("left", False), size, False, self.cache_dir, self.progress)
            right = (
                cached_images(source.images("right", False), size, False, self.cache_dir, self.progress)
                if self.config.stereo
                else None
            )
            self.images.append((left, right))
            self.rigs.append(sequence_rig(source.root))
            for delta in self.deltas or self.config.deltas:
                last = np.arange(delta, len(truth))
                rows.append(np.column_stack([np.full(len(last), number), last, np.full(len(last), delta)]))
                targets.append(window_targets(truth, estimates, last - delta, last))
                window_logs.append(estimate_input(window_estimates(estimates, last - delta, last)))
        if not rows or sum(len(r) for r in rows) == 0:
            raise ValueError("the dataset holds no window (every sequence shorter than its span)")
        self.index = np.vstack(rows)
        self.targets = np.concatenate(targets)
        self.estimates = torch.cat(window_logs)

    def __len__(self) -> int:
        return len(self.index)

    def frame(self, number: int, k: int) -> torch.Tensor:
        left, right = self.images[number]
        stacked = np.concatenate([left[k], right[k]]) if right is not None else np.asarray(left[k])
        return torch.from_numpy(stacked.astype(np.float32) / 255.0)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        number, k, delta = (int(v) for v in self.index[item])
        target = self.targets[item]
        return {
            "first": self.frame(number, k - delta),
            "last": self.frame(number, k),
            "target": torch.from_numpy(target.astype(np.float32)),
            "estimate": self.estimates[item],
            "target_yaw": torch.tensor(float(so3_log(target[:3, :3])[1]), dtype=torch.float32),
            "sequence": torch.tensor(number),
            "frame": torch.tensor(k),
            "delta": torch.tensor(delta),
        }
