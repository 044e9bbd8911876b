"""The stereo camera model (thesis eqs. 3.1-3.3, B.17-B.19) against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from pvo_core.camera import StereoCamera

KITTI_P0 = np.array([[707.0912, 0, 601.8873, 0], [0, 707.0912, 183.1104, 0], [0, 0, 1, 0]])
KITTI_P1 = KITTI_P0.copy()
KITTI_P1[0, 3] = -379.8145
CAMERA = StereoCamera.from_projection_matrices(KITTI_P0, KITTI_P1)
RNG = np.random.default_rng(7)


def random_points(n: int) -> np.ndarray:
    return np.column_stack([RNG.uniform(-10, 10, n), RNG.uniform(-3, 3, n), RNG.uniform(2, 80, n)])


def test_projection_matrices_give_kitti_geometry() -> None:
    assert CAMERA.f == pytest.approx(707.0912)
    assert CAMERA.baseline == pytest.approx(379.8145 / 707.0912)
    assert CAMERA.baseline == pytest.approx(0.5372, abs=1e-4)
    # M of eq. 3.1 reproduces project()
    p = random_points(1)[0]
    np.testing.assert_allclose(CAMERA.matrix @ np.append(p, 1.0) / p[2], CAMERA.project(p), atol=1e-12)


def test_project_triangulate_round_trip() -> None:
    points = random_points(100)
    np.testing.assert_allclose(CAMERA.triangulate(CAMERA.project(points)), points, rtol=1e-12)
    # disparity is f b / z
    np.testing.assert_allclose(CAMERA.project(points)[:, 2], CAMERA.f * CAMERA.baseline / points[:, 2])


def test_jacobians_against_finite_differences() -> None:
    eps = 1e-6
    for p in random_points(10):
        numeric = np.column_stack([(CAMERA.project(p + eps * e) - CAMERA.project(p - eps * e)) / (2 * eps) for e in np.eye(3)])
        np.testing.assert_allclose(CAMERA.project_jacobian(p), numeric, rtol=1e-6, atol=1e-7)
        y = CAMERA.project(p)
        numeric = np.column_stack(
            [(CAMERA.triangulate(y + eps * e) - CAMERA.triangulate(y - eps * e)) / (2 * eps) for e in np.eye(3)]
        )
        np.testing.assert_allclose(CAMERA.triangulate_jacobian(y), numeric, rtol=1e-6, atol=1e-9)
    batch = random_points(5)
    np.testing.assert_allclose(CAMERA.project_jacobian(batch), np.stack([CAMERA.project_jacobian(p) for p in batch]))


def test_invalid_geometry_is_rejected() -> None:
    with pytest.raises(ValueError, match="baseline"):
        StereoCamera.from_projection_matrices(KITTI_P0, KITTI_P0)
    with pytest.raises(ValueError, match="focal"):
        StereoCamera(f=-1.0, cu=0, cv=0, baseline=0.5)
    with pytest.raises(ValueError, match="not finite"):
        StereoCamera(f=float("nan"), cu=0, cv=0, baseline=0.5)
