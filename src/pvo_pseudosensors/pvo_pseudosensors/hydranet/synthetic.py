"""Rotation-only sequences in the KITTI layout: a distant textured scene seen by a camera that only turns.

Under pure rotation an image maps to the next through the homography K C K^-1 whatever the depth, so the
true relative rotation is exact and the flow depends on it alone: a set a small HydraNet must learn in
seconds (the tests), and one where its error has nothing to hide behind.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.lie import so3_exp

Array = NDArray[np.float64]


def scene_texture(size: tuple[int, int], seed: int) -> NDArray[np.uint8]:
    """A (height, width) grey texture of blobs at several scales (the distant scene, seen by a wide camera)."""
    import cv2

    rng = np.random.default_rng(seed)
    texture = np.zeros(size, np.float64)
    for sigma, weight in ((1.5, 0.5), (4.0, 1.0), (12.0, 1.0)):
        texture += weight * cv2.GaussianBlur(rng.normal(size=size), (0, 0), sigma) * sigma
    texture = (texture - texture.mean()) / texture.std()
    return np.clip(128 + 45 * texture, 0, 255).astype(np.uint8)


def write_rotation_sequence(
    root: Path,
    frames: int = 20,
    seed: int = 0,
    size: tuple[int, int] = (48, 144),
    focal: float = 70.0,
    step_deg: float = 0.8,
) -> Array:
    """Write ``root/image_0/NNNNNN.png`` and ``root/poses.txt`` (camera-to-world, no translation) of a camera
    turning by a random rotation of about ``step_deg`` per axis each frame; returns the poses (frames, 4, 4)."""
    import cv2

    height, width = size
    rng = np.random.default_rng(seed)
    margin = 3.0  # the scene camera sees three times the field of view
    scene_size = (int(height * margin), int(width * margin))
    scene = scene_texture(scene_size, seed)
    camera = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
    wide = np.array([[focal, 0.0, scene_size[1] / 2.0], [0.0, focal, scene_size[0] / 2.0], [0.0, 0.0, 1.0]])
    (root / "image_0").mkdir(parents=True, exist_ok=True)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    orientation = np.eye(3)
    for k in range(frames):
        if k:
            orientation = orientation @ so3_exp(np.radians(step_deg) * rng.normal(size=3))
        poses[k, :3, :3] = orientation
        # pixel of camera k -> direction in the world (C_w,ck K^-1 x) -> pixel of the wide scene camera
        homography = wide @ orientation @ np.linalg.inv(camera)
        image = cv2.warpPerspective(scene, homography, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        cv2.imwrite(str(root / "image_0" / f"{k:06d}.png"), image)
    lines = [" ".join(f"{v:.12e}" for v in pose[:3].reshape(-1)) for pose in poses]
    (root / "poses.txt").write_text("\n".join(lines) + "\n")
    return poses
