"""The thesis's synthetic point world for PROBE-GK (§4.6.1, Table 4.1's first row).

A stereo camera drives a circle at constant speed through point landmarks; each stereo observation gets
pixel noise whose variance grows with the feature's vertical image coordinate, and a fraction of them are
replaced by uniform outliers. Frames: camera x right, y down, z forward; the circle lies in the x-z plane of
the world (y down), the camera looking along the path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.lie import se3_inverse

from .training import FramePair

Array = NDArray[np.float64]


#: KITTI's grey camera pair at full resolution.
KITTI_LIKE = StereoCamera(f=718.856, cu=607.19, cv=185.22, baseline=0.537, width=1241, height=376)


@dataclass(frozen=True)
class PointWorldConfig:
    """landmarks: how many, in a band ``lateral`` m either side of the path and heights ``heights`` m (y down);
    speed m/s on a circle of ``radius`` m at ``rate`` Hz; noise: standard deviation of u and v in each image
    from ``sigma_top`` px at the top row to ``sigma_bottom`` px at the bottom row (variance linear in v);
    ``outlier_fraction`` of observations replaced by uniform ones within ``outlier_range`` px."""

    landmarks: int = 2000
    radius: float = 20.0
    lateral: tuple[float, float] = (3.0, 25.0)
    heights: tuple[float, float] = (-6.0, 1.5)
    speed: float = 3.0
    rate: float = 10.0
    sigma_top: float = 0.5
    sigma_bottom: float = 4.0
    outlier_fraction: float = 0.05
    outlier_range: float = 20.0
    max_depth: float = 40.0
    camera: StereoCamera = KITTI_LIKE


@dataclass
class PointWorldRun:
    """A traverse: true camera poses T_world,cam (N, 4, 4), true motions T_cur,ref (N-1), the frame pairs with
    the predictors (v of the reference observation, px) and which observations are outliers."""

    poses: Array
    motions: list[Array]
    pairs: list[FramePair]
    outliers: list[NDArray[np.bool_]]


PREDICTORS = ("v_ref",)


def circle_poses(config: PointWorldConfig, frames: int) -> Array:
    """T_world,cam along the circle, camera z along the direction of travel."""
    angle = config.speed / config.radius / config.rate * np.arange(frames)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    # centre at the origin; position (R sin a, 0, -R cos a) ... moving counter-clockwise seen from above
    position = np.stack([config.radius * np.sin(angle), np.zeros(frames), config.radius * (1.0 - np.cos(angle))], axis=1)
    forward = np.stack([np.cos(angle), np.zeros(frames), np.sin(angle)], axis=1)  # d position / d angle
    down = np.tile([0.0, 1.0, 0.0], (frames, 1))
    right = np.cross(down, forward)
    poses[:, :3, 0], poses[:, :3, 1], poses[:, :3, 2], poses[:, :3, 3] = right, down, forward, position
    return poses


def landmarks(config: PointWorldConfig, rng: np.random.Generator) -> Array:
    """(M, 3) world points in a band either side of the circle."""
    angle = rng.uniform(0.0, 2.0 * np.pi, config.landmarks)
    side = rng.choice([-1.0, 1.0], config.landmarks)
    offset = side * rng.uniform(*config.lateral, config.landmarks)
    radius = config.radius + offset
    x = radius * np.sin(angle)
    z = config.radius - radius * np.cos(angle)
    y = rng.uniform(*config.heights, config.landmarks)
    return np.stack([x, y, z], axis=1)


def simulate(config: PointWorldConfig, seconds: float, seed: int) -> PointWorldRun:
    """A traverse of ``seconds`` through a world drawn from ``seed`` (landmarks and noise)."""
    rng = np.random.default_rng(seed)
    camera = config.camera
    points = landmarks(config, rng)
    poses = circle_poses(config, round(seconds * config.rate) + 1)
    observations: list[tuple[Array, Array, NDArray[np.bool_]]] = []
    for pose in poses:
        in_camera = points @ pose[:3, :3] - pose[:3, :3].T @ pose[:3, 3]  # T_cam,world p
        exact = camera.project(np.where(in_camera[:, 2:3] > 0.1, in_camera, np.array([0.0, 0.0, 1.0])))
        visible = (in_camera[:, 2] > 1.0) & (in_camera[:, 2] < config.max_depth)
        visible &= (exact[:, 0] >= 0) & (exact[:, 0] < camera.width) & (exact[:, 1] >= 0) & (exact[:, 1] < camera.height)
        visible &= exact[:, 0] - exact[:, 2] >= 0  # in the right image too
        noisy, outlier = _observe(config, exact, rng)
        observations.append((noisy, visible & (noisy[:, 2] > 0.5), outlier))
    motions, pairs, outliers = [], [], []
    for k in range(1, len(poses)):
        (ref, seen_ref, out_ref), (cur, seen_cur, out_cur) = observations[k - 1], observations[k]
        both = seen_ref & seen_cur
        motions.append(se3_inverse(poses[k]) @ poses[k - 1])
        pairs.append(FramePair(ref[both], cur[both], ref[both][:, 1:2].copy()))
        outliers.append((out_ref | out_cur)[both])
    return PointWorldRun(poses, motions, pairs, outliers)


def _observe(config: PointWorldConfig, exact: Array, rng: np.random.Generator) -> tuple[Array, NDArray[np.bool_]]:
    """Noisy [u, v, d] from exact [u, v, d]: independent noise on the left (u, v) and the right u, the
    variance linear in the row; outliers uniform around the truth."""
    height = config.camera.height
    row = np.clip(exact[:, 1] / height, 0.0, 1.0)
    sigma = np.sqrt(config.sigma_top**2 + (config.sigma_bottom**2 - config.sigma_top**2) * row)
    n = len(exact)
    u_left = exact[:, 0] + sigma * rng.standard_normal(n)
    v_left = exact[:, 1] + sigma * rng.standard_normal(n)
    u_right = exact[:, 0] - exact[:, 2] + sigma * rng.standard_normal(n)
    outlier = rng.random(n) < config.outlier_fraction
    spread = config.outlier_range
    u_left = np.where(outlier, exact[:, 0] + rng.uniform(-spread, spread, n), u_left)
    v_left = np.where(outlier, exact[:, 1] + rng.uniform(-spread, spread, n), v_left)
    return np.stack([u_left, v_left, u_left - u_right], axis=1), outlier
