"""Camera trajectories for the synthetic world, as T_world,cam (4x4) of the left optical camera.

The world frame is a local East-North-Up frame (x east, y north, z up, metres) whose origin is on the
ground under the first camera; the optical frame is x right, y down, z forward.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import so3_exp
from pvo_core.trajectory import read_kitti_poses

Array = NDArray[np.float64]

#: Optical axes of a level camera looking north, in ENU: x right = east, y down = -up, z forward = north.
ENU_FROM_LEVEL_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
PATH_KINDS = ("loop", "straight", "s-curve")


def heading_rotation(heading_deg: float) -> Array:
    """Rotation about the up axis turning north towards east by ``heading_deg`` (clockwise seen from above)."""
    return so3_exp(np.array([0.0, 0.0, -np.radians(heading_deg)]))


def level_camera_poses(positions: Array, headings: Array) -> Array:
    """Level cameras (no roll/pitch) at ENU ``positions`` (N, 3) facing ``headings`` (N,) rad from north."""
    poses = np.tile(np.eye(4), (len(positions), 1, 1))
    for k, (p, h) in enumerate(zip(positions, headings, strict=True)):
        poses[k, :3, :3] = heading_rotation(np.degrees(h)) @ ENU_FROM_LEVEL_CAMERA
        poses[k, :3, 3] = p
    return poses


def procedural_path(kind: str, frames: int, rate: float, speed: float, camera_height: float, seed: int = 0) -> Array:
    """A driven path: ``loop`` (a rounded rectangle), ``straight`` or ``s-curve``; speed in m/s with a
    gentle seeded speed profile (±20 %)."""
    if kind not in PATH_KINDS:
        raise ValueError(f"unknown path {kind!r}: choose one of {', '.join(PATH_KINDS)}")
    if frames < 2 or rate <= 0 or speed <= 0:
        raise ValueError("a path needs at least 2 frames, a positive rate and a positive speed")
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / rate
    phase = rng.uniform(0, 2 * np.pi)
    profile = 1.0 + 0.2 * np.sin(2 * np.pi * t / max(t[-1], 1.0) + phase)
    s = np.concatenate([[0.0], np.cumsum(speed * profile[1:] / rate)])  # arc length
    if kind == "straight":
        xy = np.stack([np.zeros_like(s), s], axis=1)
    elif kind == "s-curve":
        xy = np.stack([15.0 * np.sin(s / 40.0), s], axis=1)
    else:
        xy = _rounded_rectangle(s, width=120.0, height=80.0, radius=20.0)
    positions = np.column_stack([xy, np.full(frames, camera_height)])
    # heading from the tangent, by differentiating the analytic curve finely
    ahead = {
        "straight": lambda q: np.stack([np.zeros_like(q), q], 1),
        "s-curve": lambda q: np.stack([15.0 * np.sin(q / 40.0), q], 1),
    }
    nxt = ahead[kind](s + 0.01) if kind in ahead else _rounded_rectangle(s + 0.01, 120.0, 80.0, 20.0)
    d = nxt - xy
    headings = np.arctan2(d[:, 0], d[:, 1])
    return level_camera_poses(positions, headings)


def _rounded_rectangle(s: Array, width: float, height: float, radius: float) -> Array:
    """Points at arc length ``s`` on a rounded rectangle driven clockwise (seen from above) from the origin, first north."""
    straight_w, straight_h = width - 2 * radius, height - 2 * radius
    quarter = np.pi * radius / 2
    perimeter = 2 * straight_w + 2 * straight_h + 4 * quarter
    segments = [
        ("line", np.array([0.0, 0.0]), np.array([0.0, 1.0]), straight_h),
        ("arc", np.array([radius, straight_h]), np.pi, quarter),
        ("line", np.array([radius, straight_h + radius]), np.array([1.0, 0.0]), straight_w),
        ("arc", np.array([radius + straight_w, straight_h]), np.pi / 2, quarter),
        ("line", np.array([2 * radius + straight_w, straight_h]), np.array([0.0, -1.0]), straight_h),
        ("arc", np.array([radius + straight_w, 0.0]), 0.0, quarter),
        ("line", np.array([radius + straight_w, -radius]), np.array([-1.0, 0.0]), straight_w),
        ("arc", np.array([radius, 0.0]), -np.pi / 2, quarter),
    ]
    out = np.zeros((len(s), 2))
    u = np.mod(s, perimeter)
    for i, value in enumerate(u):
        rest = value
        for kind, a, b, length in segments:
            if rest <= length:
                if kind == "line":
                    out[i] = a + b * rest
                else:  # clockwise arc of `radius` about centre a, starting at angle b
                    angle = b - rest / radius
                    out[i] = a + radius * np.array([np.cos(angle), np.sin(angle)])
                break
            rest -= length
    return out


def drive_poses(poses_file: Path) -> Array:
    """A KITTI pose file's poses (N, 4, 4), read once per file version: a corpus plans hundreds of windows of the
    same few drives (and resumes by planning them all again), and reading a 4,500-pose file checks every pose.
    Read-only: the cached array is shared."""
    stat = Path(poses_file).stat()
    return _drive_poses(str(Path(poses_file).resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=16)
def _drive_poses(path: str, mtime_ns: int, size: int) -> Array:
    del mtime_ns, size  # the cache key: a rewritten file is read again
    poses = read_kitti_poses(Path(path))
    poses.setflags(write=False)
    return poses


def kitti_path(
    poses_file: Path,
    frames: int | None,
    start: int,
    camera_height: float,
    heading_deg: float = 0.0,
    level_frames: int = 0,
    speed_scale: float = 1.0,
) -> Array:
    """A real KITTI ground-truth trajectory placed on the world's flat ground, facing ``heading_deg`` (from
    north) at the start: KITTI's poses relative to the first camera, tilted so that the cameras' mean up
    direction over the window is the world's up, and every camera at ``camera_height`` above the ground.
    ``level_frames``: the mean up taken over that many frames of the drive centred on the window instead (clipped
    to the drive; never fewer than the window's own), so that a short window pitches and rolls against the ground
    as the same stretch of a long one does — levelled on itself, a 60-frame window loses the drive's slopes and
    its cameras stay within 3 deg of level, where a 1000-frame drive's pitch reaches 10 deg.
    ``speed_scale``: the drive replayed this many times faster — camera k at the drive's frame ``start + k *
    speed_scale`` (positions interpolated linearly, rotations by slerp between the two nearest poses), so the
    window covers that many times the road at the same frame rate: KITTI's urban drives rarely exceed 15 m/s, its
    highway stretches do.

    The world is flat; KITTI's drives are not, and their first camera is not level: replayed as they are, a
    1000-frame window climbed 12 m above the ground or sank 4 m under it, where the cameras see the inside of
    the ground plane. The frame-to-frame rotations (turns, pitch and roll as the car's) are KITTI's exactly;
    each step keeps its horizontal motion and loses its climb."""
    try:
        poses = drive_poses(Path(poses_file))
    except Exception as exc:  # noqa: BLE001 - the reader raises DataFormatError naming the line
        raise ValueError(f"{poses_file}: not a KITTI pose file ({exc})") from None
    if start < 0 or start >= len(poses) - 1:
        raise ValueError(f"{poses_file}: start frame {start} outside its {len(poses)} poses")
    if not np.isfinite(speed_scale) or speed_scale <= 0.0:
        raise ValueError(f"speed_scale must be positive, got {speed_scale}")
    spanned = len(poses) - start if frames is None else int(np.ceil((frames - 1) * speed_scale - 1e-9)) + 1
    end = min(len(poses), start + spanned)
    if level_frames < 0:
        raise ValueError(f"level_frames must be >= 0, got {level_frames}")
    relative = np.linalg.inv(poses[start]) @ poses[start:end]
    context = relative  # the stretch of road driven, levelled as the drive's own poses whatever the replay speed
    if speed_scale != 1.0:
        count = int(np.floor((end - 1 - start) / speed_scale + 1e-9)) + 1
        if frames is not None:
            count = min(count, frames)
        relative = resample_poses(relative, np.arange(count) * speed_scale)
    if level_frames > end - start:
        first = max(0, min(len(poses) - level_frames, (start + end - level_frames) // 2))
        context = np.linalg.inv(poses[start]) @ poses[first : first + level_frames]
    level = np.eye(4)
    level[:3, :3] = _rotation_between(-context[:, :3, 1].mean(axis=0), np.array([0.0, -1.0, 0.0]))
    anchor = np.eye(4)
    anchor[:3, :3] = heading_rotation(heading_deg) @ ENU_FROM_LEVEL_CAMERA
    placed = anchor @ level @ relative
    placed[:, 2, 3] = camera_height
    return placed


def resample_poses(poses: Array, times: Array) -> Array:
    """Poses (N, 4, 4) at fractional indices ``times`` (M,) in [0, N - 1]: translation interpolated linearly,
    rotation by slerp between the two poses around each time (exact at whole indices)."""
    from scipy.spatial.transform import Rotation, Slerp

    times = np.asarray(times, dtype=float)
    if times.size and (times.min() < 0.0 or times.max() > len(poses) - 1 + 1e-9):
        raise ValueError(f"resample times must lie in [0, {len(poses) - 1}], got [{times.min()}, {times.max()}]")
    times = np.clip(times, 0.0, len(poses) - 1)
    index = np.arange(len(poses), dtype=float)
    out = np.tile(np.eye(4), (len(times), 1, 1))
    out[:, :3, :3] = Slerp(index, Rotation.from_matrix(poses[:, :3, :3]))(times).as_matrix()
    whole = np.abs(times - np.round(times)) < 1e-12  # the drive's own rotations there, not a quaternion round trip
    out[whole, :3, :3] = poses[np.round(times[whole]).astype(int), :3, :3]
    for axis in range(3):
        out[:, axis, 3] = np.interp(times, index, poses[:, axis, 3])
    return out


def _rotation_between(a: Array, b: Array) -> Array:
    """The smallest rotation turning direction ``a`` onto direction ``b`` (3-vectors)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    sine, cosine = float(np.linalg.norm(axis)), float(np.dot(a, b))
    if sine < 1e-12:
        if cosine > 0:
            return np.eye(3)
        raise ValueError("the cameras' mean up direction points down")
    return so3_exp(axis / sine * np.arctan2(sine, cosine))
