"""`track_monocular`: the VO's features tracked on left images alone (the realism benchmark's measure)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from pvo_frontend.offline import track_monocular


def textured(seed: int = 0, size: tuple[int, int] = (188, 620)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.random((size[0] // 4, size[1] // 4)).astype(np.float32)
    image = cv2.resize(noise, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)
    return np.clip(image * 255, 0, 255).astype(np.uint8)


def test_a_translating_texture_is_tracked_with_consistent_geometry() -> None:
    base = textured()
    frames = [cv2.warpAffine(base, np.float32([[1, 0, -2.5 * k], [0, 1, 0.5 * k]]), base.shape[::-1]) for k in range(6)]
    result = track_monocular(frames)
    assert result.frames == 6
    assert result.tracked > 100
    assert result.inlier_ratio > 0.9


def test_unrelated_images_keep_few_tracks_and_fit_no_geometry() -> None:
    frames = [textured(seed) for seed in range(4)]
    unrelated, same = track_monocular(frames), track_monocular([frames[0]] * 4)
    assert unrelated.tracked < 0.5 * same.tracked
    assert unrelated.inlier_ratio < 0.6 and same.inlier_ratio == 1.0


def test_one_image_is_refused() -> None:
    with pytest.raises(ValueError, match="at least two"):
        track_monocular([textured()])
