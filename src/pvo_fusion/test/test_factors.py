"""Each factor's error and Jacobian against finite differences on GTSAM's own retraction."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, X
from pvo_core.lie import se3_exp, se3_inverse, so3_exp
from pvo_fusion.factors import (
    between_measurement,
    rotation_error,
    rotation_factor,
    sun_error,
    sun_factor,
    wrap_angle,
    zenith_azimuth,
)

RNG = np.random.default_rng(7)


def random_pose(rng: np.random.Generator = RNG, scale: float = 1.0) -> gtsam.Pose3:
    return gtsam.Pose3(se3_exp(rng.normal(0.0, scale, 6)))


def numerical_jacobian(f, pose: gtsam.Pose3, step: float = 1e-7) -> np.ndarray:
    """d f(pose.retract(xi)) / d xi at 0, central differences, GTSAM tangent order [omega; v]."""
    base = np.asarray(f(pose))
    jac = np.zeros((base.size, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = step
        jac[:, i] = (np.asarray(f(pose.retract(d))) - np.asarray(f(pose.retract(-d)))) / (2 * step)
    return jac


def test_between_measurement_left_perturbation_of_t_to_from_is_right_perturbation_of_its_inverse() -> None:
    transform = se3_exp(np.array([0.3, -0.1, 1.2, 0.02, -0.05, 0.01]))
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6])
    measured, cov = between_measurement(transform, covariance)
    np.testing.assert_allclose(measured.matrix(), se3_inverse(transform), atol=1e-12)
    # GTSAM order: rotation block first, same numbers (no adjoint for this pairing).
    np.testing.assert_allclose(np.diag(cov), [1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])
    # The pairing itself: exp(eps) T  ==  (T^-1 Exp_gtsam(-eps'))^-1 with eps' = eps reordered.
    eps = np.array([0.01, -0.02, 0.03, 0.004, -0.002, 0.003])  # [rho; phi]
    perturbed = se3_exp(eps) @ transform
    via_gtsam = measured.retract(-np.concatenate([eps[3:], eps[:3]])).matrix()
    # retract is the group exponential on Pose3 only to first order in GTSAM's default chart; compare loosely.
    np.testing.assert_allclose(np.linalg.inv(perturbed), via_gtsam, atol=5e-4)
    via_expmap = measured.compose(gtsam.Pose3.Expmap(-np.concatenate([eps[3:], eps[:3]]))).matrix()
    np.testing.assert_allclose(np.linalg.inv(perturbed), via_expmap, atol=1e-12)


def sun_direction(zenith_deg: float, azimuth_deg: float) -> np.ndarray:
    z, a = np.radians(zenith_deg), np.radians(azimuth_deg)
    return np.array([np.sin(z) * np.sin(a), -np.cos(z), np.sin(z) * np.cos(a)])


@pytest.mark.parametrize(
    "zenith_deg, azimuth_deg",
    [(50.0, 20.0), (120.0, -150.0), (0.5, 45.0), (179.0, 10.0), (70.0, 179.999), (30.0, -90.0)],
)
def test_sun_error_jacobian_matches_finite_differences(zenith_deg: float, azimuth_deg: float) -> None:
    pose = random_pose(scale=0.7)
    camera_sun = sun_direction(zenith_deg, azimuth_deg)
    sun_map = pose.rotation().matrix() @ camera_sun  # predicted = camera_sun at this pose
    measured = zenith_azimuth(sun_direction(zenith_deg + 2.0 if zenith_deg < 170 else zenith_deg - 2.0, azimuth_deg - 3.0))

    def f(p: gtsam.Pose3) -> np.ndarray:
        return sun_error(p.rotation().matrix(), sun_map, measured)[0]

    error, jacobian = sun_error(pose.rotation().matrix(), sun_map, measured)
    step = 1e-8 if zenith_deg < 1.0 else 1e-7
    np.testing.assert_allclose(jacobian, numerical_jacobian(f, pose, step), atol=2e-5 if zenith_deg < 1 else 1e-6)
    assert np.all(jacobian[:, 3:] == 0.0)
    assert np.all(np.abs(error) < np.radians(10.0))  # small, including across the azimuth wrap


def test_sun_error_wraps_azimuth_and_is_zero_at_the_truth() -> None:
    pose = random_pose()
    camera_sun = sun_direction(60.0, 179.9)
    sun_map = pose.rotation().matrix() @ camera_sun
    error, _ = sun_error(pose.rotation().matrix(), sun_map, zenith_azimuth(camera_sun))
    np.testing.assert_allclose(error, 0.0, atol=1e-12)
    across = zenith_azimuth(sun_direction(60.0, -179.9))
    error, _ = sun_error(pose.rotation().matrix(), sun_map, across)
    np.testing.assert_allclose(error, [0.0, np.radians(-0.2)], atol=1e-9)
    assert wrap_angle(np.radians(359.0)) == pytest.approx(np.radians(-1.0))


def test_sun_error_follows_eq_5_7() -> None:
    s = np.array([0.3, -0.5, 0.6])
    s /= np.linalg.norm(s)
    zenith, azimuth = zenith_azimuth(s)
    assert zenith == pytest.approx(np.arccos(-s[1]))
    assert azimuth == pytest.approx(np.arctan2(s[0], s[2]))


def test_sun_factor_whitened_jacobian_and_huber() -> None:
    pose = random_pose()
    camera_sun = sun_direction(40.0, 30.0)
    sun_map = pose.rotation().matrix() @ camera_sun
    measured = sun_direction(42.0, 27.0)
    covariance = np.diag([np.radians(2.0) ** 2, np.radians(3.0) ** 2])
    factor = sun_factor(X(0), sun_map, measured, covariance, huber_k=0.0)
    values = gtsam.Values()
    values.insert(X(0), pose)
    expected, jac = sun_error(pose.rotation().matrix(), sun_map, zenith_azimuth(measured))
    np.testing.assert_allclose(factor.unwhitenedError(values), expected, atol=1e-12)
    whitened = np.linalg.cholesky(np.linalg.inv(covariance)).T
    linear = factor.linearize(values)
    a, _ = linear.jacobian()
    np.testing.assert_allclose(np.abs(a), np.abs(whitened @ jac), atol=1e-9)
    assert factor.error(values) == pytest.approx(0.5 * expected @ np.linalg.solve(covariance, expected))
    robust = sun_factor(X(0), sun_map, measured, covariance, huber_k=1.0)
    # Huber grows linearly beyond k: its cost is below the quadratic one for this 2-sigma residual.
    assert robust.error(values) < factor.error(values)


def test_rotation_error_jacobians_match_finite_differences() -> None:
    pose_from, pose_to = random_pose(), random_pose()
    truth = pose_from.rotation().matrix().T @ pose_to.rotation().matrix()
    measured = truth @ so3_exp(np.array([0.01, -0.02, 0.015]))

    e, j_from, j_to = rotation_error(pose_from.rotation().matrix(), pose_to.rotation().matrix(), measured)
    f_from = lambda p: rotation_error(p.rotation().matrix(), pose_to.rotation().matrix(), measured)[0]  # noqa: E731
    f_to = lambda p: rotation_error(pose_from.rotation().matrix(), p.rotation().matrix(), measured)[0]  # noqa: E731
    np.testing.assert_allclose(j_from, numerical_jacobian(f_from, pose_from), atol=1e-6)
    np.testing.assert_allclose(j_to, numerical_jacobian(f_to, pose_to), atol=1e-6)
    assert np.linalg.norm(e) == pytest.approx(np.linalg.norm([0.01, -0.02, 0.015]), rel=1e-9)


def test_rotation_factor_matches_eq_7_22_and_uses_the_rotation_block() -> None:
    pose_from, pose_to = random_pose(), random_pose()
    # RelativePose carries T_to,from; its rotation is C_to,from = C_map,to^T C_map,from.
    t_to_from = pose_to.inverse().compose(pose_from).matrix()
    covariance = np.diag([9.0, 9.0, 9.0, 1e-4, 2e-4, 3e-4])
    factor = rotation_factor(X(0), X(1), t_to_from, covariance)
    values = gtsam.Values()
    values.insert(X(0), pose_from)
    values.insert(X(1), pose_to)
    np.testing.assert_allclose(factor.unwhitenedError(values), 0.0, atol=1e-12)
    # Perturb the measurement by a known rotation: the thesis's log(C_2 C_1^T C_21^T) has that norm.
    bumped = t_to_from.copy()
    bumped[:3, :3] = so3_exp(np.array([0.0, 0.03, 0.0])) @ t_to_from[:3, :3]
    factor = rotation_factor(X(0), X(1), bumped, covariance)
    assert np.linalg.norm(factor.unwhitenedError(values)) == pytest.approx(0.03, rel=1e-9)
    assert factor.error(values) == pytest.approx(0.5 * 0.03**2 / 2e-4, rel=1e-6)
    # With a Huber loss the cost of this 2.1-sigma residual r is k (r - k/2), not r^2 / 2.
    robust = rotation_factor(X(0), X(1), bumped, covariance, huber_k=1.0)
    whitened = 0.03 / np.sqrt(2e-4)
    assert robust.error(values) == pytest.approx(1.0 * (whitened - 0.5), rel=1e-6)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.04, 1.3, np.pi - 1e-7])
def test_the_rotation_factor_computes_rotation_error_and_its_jacobians(angle: float) -> None:
    """The factor runs on GTSAM's Rot3 for speed; its residual and Jacobians are the numpy reference's
    (``rotation_error``, checked by finite differences above), from the identity to nearly pi."""
    pose_from, pose_to = random_pose(), random_pose()
    axis = RNG.normal(size=3)
    measured = pose_from.rotation().matrix().T @ pose_to.rotation().matrix() @ so3_exp(angle * axis / np.linalg.norm(axis))
    reading = np.eye(4)
    reading[:3, :3] = measured.T  # a RelativePose carries C_to,from
    covariance = np.diag([9.0, 9.0, 9.0, 1e-4, 2e-4, 3e-4])
    values = gtsam.Values()
    values.insert(X(0), pose_from)
    values.insert(X(1), pose_to)
    e, j_from, j_to = rotation_error(pose_from.rotation().matrix(), pose_to.rotation().matrix(), measured)
    factor = rotation_factor(X(0), X(1), reading, covariance)
    np.testing.assert_allclose(factor.unwhitenedError(values), e, atol=1e-9)
    whitening = np.linalg.cholesky(np.linalg.inv(covariance[3:, 3:])).T
    jacobian = factor.linearize(values).jacobian()[0]
    np.testing.assert_allclose(jacobian, whitening @ np.hstack([j_from, j_to]), atol=1e-6 * np.abs(jacobian).max())


def test_a_rotation_read_with_an_offset_is_exact_at_that_offset_and_its_jacobian_is_the_identity() -> None:
    pose_from, pose_to = random_pose(), random_pose()
    offset = np.array([0.002, -0.004, 0.001])
    c_from_to = pose_from.rotation().matrix().T @ pose_to.rotation().matrix() @ so3_exp(offset)
    reading = np.eye(4)
    reading[:3, :3] = c_from_to.T  # a RelativePose carries C_to,from
    factor = rotation_factor(X(0), X(1), reading, np.diag([9.0, 9.0, 9.0, 1e-4, 2e-4, 3e-4]), bias_key=B(0))
    values = gtsam.Values()
    values.insert(X(0), pose_from)
    values.insert(X(1), pose_to)
    values.insert(B(0), offset)
    np.testing.assert_allclose(factor.unwhitenedError(values), 0.0, atol=1e-12)
    values.update(B(0), np.zeros(3))
    np.testing.assert_allclose(factor.unwhitenedError(values), -offset, atol=1e-9)  # Log(Exp(-b)) without the state
    jacobians = factor.linearize(values).jacobian()[0]
    whitening = np.linalg.cholesky(np.linalg.inv(np.diag([1e-4, 2e-4, 3e-4]))).T
    np.testing.assert_allclose(np.abs(jacobians[:, 12:]), np.abs(whitening), atol=1e-9)  # de/db = I, whitened


def test_gtsam_between_and_prior_factors_match_finite_differences() -> None:
    """The VO/correction factor is GTSAM's own BetweenFactorPose3 and the prior its PriorFactorPose3:
    their linearisation is checked against finite differences of their errors, as ours are."""
    x1, x2 = random_pose(), random_pose()
    measured = gtsam.Pose3(se3_exp(RNG.normal(0.0, 0.5, 6)))
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-2, 2e-2, 3e-2])
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    factor = gtsam.BetweenFactorPose3(X(0), X(1), measured, noise)
    prior = gtsam.PriorFactorPose3(X(0), measured, noise)
    values = gtsam.Values()
    values.insert(X(0), x1)
    values.insert(X(1), x2)
    whitener = np.linalg.cholesky(np.linalg.inv(covariance)).T

    def between_error(a: gtsam.Pose3, b: gtsam.Pose3) -> np.ndarray:
        return gtsam.Pose3.Logmap(measured.between(a.between(b)))

    a, _ = factor.linearize(values).jacobian()
    j1 = numerical_jacobian(lambda p: between_error(p, x2), x1)
    j2 = numerical_jacobian(lambda p: between_error(x1, p), x2)
    # whitened rows of the linear factor are an orthogonal transform of whitener @ J: compare Gram matrices
    expected = whitener @ np.hstack([j1, j2])
    np.testing.assert_allclose(a.T @ a, expected.T @ expected, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(factor.unwhitenedError(values), between_error(x1, x2), atol=1e-12)
    a, _ = prior.linearize(values).jacobian()
    jp = numerical_jacobian(lambda p: gtsam.Pose3.Logmap(measured.between(p)), x1)
    np.testing.assert_allclose(a.T @ a, (whitener @ jp).T @ whitener @ jp, rtol=1e-5, atol=1e-3)
