"""The fusion's newest state on disk, so that a restarted fusion node resumes where the killed one stopped.

A checkpoint is the newest state's stamp, pose T_map,cam, its marginal covariance (ROS order, left
perturbation), the last VO velocity (motion, covariance, interval) and the VO's bias as each input that teaches it
had learned it (:class:`pvo_fusion.vo_bias.VOBiasTracker`: bias, corrections taken). It is written atomically (temporary
file, then rename): a node killed while writing leaves the previous checkpoint whole.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FusionCheckpoint:
    stamp: int
    pose: Array
    covariance: Array
    velocity: tuple[Array, Array, float] | None
    vo_biases: dict[str, tuple[Array, int]] = field(default_factory=dict)
    #: per input that teaches them, the VO scales' sums (4,) (:attr:`VOBiasTracker.scale_sums`)
    vo_scales: dict[str, Array] = field(default_factory=dict)

    def write(self, path: str | Path) -> None:
        path = Path(path)
        data = {
            "stamp": int(self.stamp),
            "pose": np.asarray(self.pose, dtype=float).reshape(-1).tolist(),
            "covariance": np.asarray(self.covariance, dtype=float).reshape(-1).tolist(),
            "velocity": None
            if self.velocity is None
            else {
                "transform": np.asarray(self.velocity[0], dtype=float).reshape(-1).tolist(),
                "covariance": np.asarray(self.velocity[1], dtype=float).reshape(-1).tolist(),
                "seconds": float(self.velocity[2]),
            },
            "vo_bias": {
                kind: {"bias": np.asarray(bias, dtype=float).tolist(), "updates": int(updates)}
                for kind, (bias, updates) in self.vo_biases.items()
            },
            "vo_scale_sums": {kind: np.asarray(sums, dtype=float).tolist() for kind, sums in self.vo_scales.items()},
        }
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(data))
        os.replace(tmp, path)

    @classmethod
    def read(cls, path: str | Path) -> FusionCheckpoint:
        """``ValueError`` naming the file when it is missing, unreadable or not a checkpoint."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
            pose = np.asarray(data["pose"], dtype=float).reshape(4, 4)
            covariance = np.asarray(data["covariance"], dtype=float).reshape(6, 6)
            velocity = data["velocity"]
            if velocity is not None:
                velocity = (
                    np.asarray(velocity["transform"], dtype=float).reshape(4, 4),
                    np.asarray(velocity["covariance"], dtype=float).reshape(6, 6),
                    float(velocity["seconds"]),
                )
            vo_biases = {  # absent in a checkpoint from before stop 64: nothing learned
                str(kind): (np.asarray(entry["bias"], dtype=float).reshape(6), int(entry["updates"]))
                for kind, entry in (data.get("vo_bias") or {}).items()
            }
            scales = {  # absent in a checkpoint from before stop 65: none learned
                str(kind): np.asarray(sums, dtype=float).reshape(4) for kind, sums in (data.get("vo_scale_sums") or {}).items()
            }
            checkpoint = cls(int(data["stamp"]), pose, covariance, velocity, vo_biases, scales)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"fusion checkpoint {path}: {type(exc).__name__}: {exc}") from None
        if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(covariance))):
            raise ValueError(f"fusion checkpoint {path}: non-finite pose or covariance")
        if not all(np.all(np.isfinite(bias)) and updates >= 0 for bias, updates in vo_biases.values()):
            raise ValueError(f"fusion checkpoint {path}: non-finite VO bias or a negative count")
        if not all(np.all(np.isfinite(sums)) and sums[1] >= 0.0 and sums[3] >= 0.0 for sums in scales.values()):
            raise ValueError(f"fusion checkpoint {path}: non-finite VO scale sums or a negative sum of squares")
        return checkpoint
