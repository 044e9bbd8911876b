"""The published online pose: the newest fused state, made continuous.

After a VO gap (a restarted VO, a restarted fusion, dropped frames) the smoother's newest state can move by
metres in one frame when the next sun measurement corrects the heading the gap bridge got wrong. That is the
right estimate, but a controller reading ``/pvo/fusion/odometry`` sees a jump. As REP-105 asks of an odometry
frame, the published pose is kept continuous instead: each frame it moves by the smoother's own motion between
the previous and the newest state, plus at most ``output.max_correction_sigma`` times the motion model's sigma
over the frame interval (``inputs.vo.gap_sigma``: the norm of its translation part, m/s, and of its rotation
part, rad/s) towards the newest estimate. What it has not caught up with yet is added to the published
covariance, so the stated uncertainty covers it. When a correction is within the bound (every frame of a run
without gaps), the published pose is the smoother's estimate exactly; the smoothed path (``/pvo/fusion/path``)
always carries the full correction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import se3_adjoint, se3_exp, se3_inverse, se3_log

if TYPE_CHECKING:
    from .config import FusionConfig
    from .graph import FusionGraph

Array = NDArray[np.float64]


@dataclass
class PublishedPose:
    """One published estimate: T_map,cam (4x4) and the part of the smoother's correction still to catch up
    with (6, [rho; phi], body frame)."""

    pose: Array
    outstanding: Array

    def covariance(self, estimate_covariance: Array) -> Array:
        """The published covariance (6x6, ROS order, left perturbation): the estimate's plus the outer product
        of the outstanding correction moved to the map frame."""
        in_map = se3_adjoint(self.pose) @ self.outstanding
        return np.asarray(estimate_covariance, dtype=float) + np.outer(in_map, in_map)


class ContinuousOutput:
    """Rate-limits corrections of the published pose (see the module notes).

    ``max_correction_sigma``: the bound per frame in motion-model sigmas (0: publish the estimate as it is);
    ``sigma_per_second``: the motion model's sigma per second of interval, (6,) m/s and rad/s, body frame."""

    def __init__(self, max_correction_sigma: float, sigma_per_second: Array) -> None:
        self.max_correction_sigma = float(max_correction_sigma)
        self.sigma_per_second = np.asarray(sigma_per_second, dtype=float)
        self._pose: Array | None = None
        self._stamp: int | None = None

    @property
    def stamp(self) -> int | None:
        """Stamp (ns) of the last published pose."""
        return self._stamp

    def reset(self, stamp: int, pose: Array) -> None:
        """Continue from ``pose`` at ``stamp`` (the first state, a resumed checkpoint)."""
        self._pose, self._stamp = np.array(pose, dtype=float), int(stamp)

    def publish(self, stamp: int, estimate: Array, previous_estimate: Array | None) -> PublishedPose:
        """The pose to publish at ``stamp`` for the smoother's newest ``estimate``. ``previous_estimate``: the
        smoother's current estimate of the previously published state (None when it has left the window or
        none was published: the estimate is published as it is)."""
        estimate = np.asarray(estimate, dtype=float)
        zero = np.zeros(6)
        if self.max_correction_sigma <= 0.0 or self._pose is None or self._stamp is None or previous_estimate is None:
            self.reset(stamp, estimate)
            return PublishedPose(estimate, zero)
        interval = max((stamp - self._stamp) * 1e-9, 0.0)
        predicted = self._pose @ se3_inverse(previous_estimate) @ estimate  # the smoother's motion, from where we are
        offset = se3_log(se3_inverse(predicted) @ estimate)  # body frame: estimate = predicted exp(offset)
        fraction = min(1.0, self.max_correction_sigma * interval / max(self.sigma_units(offset), 1e-300))
        if fraction >= 1.0:
            self.reset(stamp, estimate)
            return PublishedPose(estimate, zero)
        pose = predicted @ se3_exp(fraction * offset)
        self.reset(stamp, pose)
        return PublishedPose(pose, se3_log(se3_inverse(pose) @ estimate))

    def sigma_units(self, step: Array) -> float:
        """How many motion-model sigmas per second a body-frame step (6, [rho; phi]) is: the larger of its
        translation and its rotation, each as a length against the norm of that part's sigma."""
        sigma = self.sigma_per_second
        return max(
            float(np.linalg.norm(step[:3]) / np.linalg.norm(sigma[:3])),
            float(np.linalg.norm(step[3:]) / np.linalg.norm(sigma[3:])),
        )

    @classmethod
    def from_config(cls, config: FusionConfig) -> ContinuousOutput:
        return cls(config.output.max_correction_sigma, np.asarray(config.inputs.vo.gap_sigma, dtype=float))

    def publish_newest(self, graph: FusionGraph) -> PublishedPose:
        """:meth:`publish` for the graph's newest state."""
        stamp = graph.newest_stamp
        if stamp is None:
            raise ValueError("the fusion graph has no state yet")
        previous = None
        if self._stamp is not None and self._stamp != stamp:
            try:
                previous = graph.pose(self._stamp)
            except ValueError:  # left the window
                previous = None
        return self.publish(stamp, graph.pose(), previous)
