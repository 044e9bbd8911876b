"""The stereo VO over a KITTI-layout sequence without ROS, and the figures of such a run.

``run_sequence`` is what ``pvo vo``, ``pvo bench vo``, the demo's ROS-free check and the benchmarks call.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.readers import KittiSequence

from pvo_core import metrics

from .vo import FrameResult, FrameStatus, StereoVO, VOConfig
from .vo.pipeline import FeatureNoise

Array = NDArray[np.float64]
STAGES = ("tracking", "feature_noise", "ransac", "gauss_newton", "detection", "stereo_matching", "total")


@dataclass
class VORun:
    """Per frame: the results, the integrated poses T_odom,cam (N, 4, 4) and the process() wall times (N,) in s."""

    results: list[FrameResult]
    poses: Array
    seconds: Array
    config: VOConfig

    @property
    def pose_covariances(self) -> Array:
        """(N, 6, 6) accumulated pose covariances (ROS order, left perturbation)."""
        return np.array([r.pose_covariance for r in self.results])

    def relative(self) -> dict[str, Array]:
        """Per-frame motions after the first: transforms, covariances, ok flags, stamps (for NEES and files)."""
        later = self.results[1:]
        missing = np.eye(6) * self.config.tracking.lost_covariance  # a frame without a motion carries no information
        return {
            "transforms": np.array([r.transform if r.transform is not None else np.eye(4) for r in later]),
            "covariances": np.array([r.covariance if r.covariance is not None else missing for r in later]),
            "ok": np.array([r.status is FrameStatus.TRACKING for r in later]),
            "stamps": np.array([r.stamp for r in later]),
        }


def run_sequence(
    sequence: KittiSequence,
    config: VOConfig,
    images: Sequence[tuple[NDArray[np.uint8], NDArray[np.uint8]]] | None = None,
    progress: Callable[[], None] | None = None,
    feature_noise: FeatureNoise | None = None,
    imu: Array | None = None,
) -> VORun:
    """Every frame of ``sequence`` through one :class:`StereoVO`; ``ValueError`` naming the image of a rejected frame.

    images: the pairs already decoded (benchmarks), else each is read from disk. feature_noise: the VO's
    per-feature noise hook (PROBE), instead of the one ``config.probe.model`` names. imu: the IMU reading per
    frame (N, 6) [wx, wy, wz, fx, fy, fz] (:func:`pvo_core.readers.imu_at_stamps`), for PROBE's IMU predictors.
    """
    vo = StereoVO(sequence.camera(), config, feature_noise)
    results, poses, seconds = [], [], []
    for i in range(len(sequence)):
        left, right = images[i] if images is not None else sequence.load_pair(i)
        tic = time.perf_counter()
        result = vo.process(left, right, float(sequence.stamps[i]), None if imu is None else imu[i])
        seconds.append(time.perf_counter() - tic)
        if result.status is FrameStatus.REJECTED:
            raise ValueError(f"{sequence.left_paths[i]}: frame rejected: {result.message}")
        results.append(result)
        poses.append(result.pose)
        if progress is not None:
            progress()
    return VORun(results, np.array(poses), np.array(seconds), config)


def summarise(run: VORun, gt: Array | None) -> dict[str, Any]:
    """Timing figures of a run and, with ground truth (N, 4, 4), its accuracy: end drift, ATE, ANEES of the motions."""
    later = run.results[1:]
    out: dict[str, Any] = {
        "frames": len(run.results),
        "lost": sum(r.status is FrameStatus.LOST for r in run.results),
        "median_ms": 1e3 * float(np.median(run.seconds[1:])),
        "p95_ms": 1e3 * float(np.percentile(run.seconds[1:], 95)),
        "tracked": float(np.mean([r.tracked for r in later])),
        "inliers": float(np.mean([r.inliers for r in later])),
        "stages_ms": {s: 1e3 * float(np.median([r.timings.get(s, 0.0) for r in later])) for s in STAGES},
    }
    if gt is not None:
        g = np.linalg.inv(gt[0]) @ gt
        dist = metrics.path_distances(g)
        err = metrics.absolute_trajectory_error(g, run.poses)
        out["path_m"] = float(dist[-1])
        out["end_drift_percent"] = 100.0 * float(err[-1]) / float(dist[-1])
        out["ate_mean_m"] = float(err.mean())
        out["ate_rmse_m"] = float(np.sqrt(np.mean(err**2)))
        rel = run.relative()
        ok = rel["ok"]
        e = metrics.relative_motion_errors(g, rel["transforms"])
        nees = metrics.nees(e[ok], rel["covariances"][ok]) / 6.0
        out["anees"] = float(nees.mean())
        out["nees_median"] = float(np.median(nees))
    return out


@dataclass(frozen=True)
class MonocularTracking:
    """Frame-to-frame tracking of the VO's features on left images alone (for data without right images):
    tracks carried per frame (mean), and the fraction of them consistent with one epipolar geometry
    (fundamental-matrix RANSAC, 1 px) — the monocular analogue of the stereo VO's inlier ratio."""

    frames: int
    tracked: float
    inlier_ratio: float


def track_monocular(images: Sequence[NDArray[np.uint8]], config: VOConfig | None = None) -> MonocularTracking:
    """Detect with the VO's detector (bucketed, topped up each frame), track by the VO's KLT with a
    forward-backward check, and count what survives and what fits one epipolar geometry."""
    import cv2

    from .vo.features import StereoMatcher

    config = config or VOConfig()
    if len(images) < 2:
        raise ValueError("monocular tracking needs at least two images")
    matcher = StereoMatcher(config.detector, config.tracker)
    points = matcher.detect(images[0], np.zeros((0, 2)))
    tracked, ratios = [], []
    for prev, image in itertools.pairwise(images):
        moved, ok = matcher._klt(prev, image, points)
        back, ok_back = matcher._klt(image, prev, moved, points)
        ok &= ok_back & (np.linalg.norm(back - points, axis=1) <= 1.0) & matcher._inside(moved, image.shape)
        tracked.append(int(ok.sum()))
        if ok.sum() >= 8:
            _, mask = cv2.findFundamentalMat(points[ok], moved[ok], cv2.FM_RANSAC, 1.0, 0.999)
            ratios.append(float(mask.sum()) / ok.sum() if mask is not None else 0.0)
        else:
            ratios.append(0.0)
        points = moved[ok]
        points = np.vstack([points, matcher.detect(image, points)])
    return MonocularTracking(len(images), float(np.mean(tracked)), float(np.mean(ratios)))
