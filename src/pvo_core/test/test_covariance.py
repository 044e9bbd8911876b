"""ROS <-> GTSAM covariance conversion, checked against GTSAM's own Pose3 maps."""

from __future__ import annotations

import gtsam
import numpy as np
from pvo_core.covariance import gtsam_to_ros_covariance, is_positive_definite, ros_to_gtsam_covariance
from pvo_core.lie import se3_exp, se3_inverse

RNG = np.random.default_rng(3)


def random_covariance() -> np.ndarray:
    a = RNG.normal(size=(6, 6))
    return a @ a.T + 1e-3 * np.eye(6)


def test_conversion_is_the_linear_map_gtsam_sees() -> None:
    """A left perturbation xi (ROS order) of T_hat is, in GTSAM, Logmap(T_hat^-1 exp(xi) T_hat)."""
    t_hat = se3_exp(RNG.normal(size=6) * [3, 3, 3, 1, 1, 1])
    eps = 1e-7
    linear_map = np.zeros((6, 6))
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = eps
        perturbed = gtsam.Pose3(se3_inverse(t_hat) @ se3_exp(xi) @ t_hat)
        linear_map[:, k] = gtsam.Pose3.Logmap(perturbed) / eps
    cov = random_covariance()
    np.testing.assert_allclose(ros_to_gtsam_covariance(cov, t_hat), linear_map @ cov @ linear_map.T, rtol=1e-5, atol=1e-6)


def test_round_trip_and_identity_pose() -> None:
    cov = random_covariance()
    pose = se3_exp(RNG.normal(size=6))
    np.testing.assert_allclose(gtsam_to_ros_covariance(ros_to_gtsam_covariance(cov, pose), pose), cov, atol=1e-9)
    np.testing.assert_allclose(gtsam_to_ros_covariance(ros_to_gtsam_covariance(cov.ravel())), cov, atol=0)
    swapped = ros_to_gtsam_covariance(cov)
    np.testing.assert_allclose(swapped[:3, :3], cov[3:, 3:])  # rotation block first in GTSAM
    np.testing.assert_allclose(swapped[3:, :3], cov[:3, 3:])


def test_positive_definite_check() -> None:
    assert is_positive_definite(random_covariance())
    assert not is_positive_definite(-np.eye(6))
    assert not is_positive_definite(np.full((6, 6), np.nan))
    bad = random_covariance()
    bad[0, 1] += 1.0
    assert not is_positive_definite(bad)
