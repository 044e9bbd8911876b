"""The fusion graph's factors, each with its error, Jacobian, noise model and frame stated.

States are GTSAM ``Pose3`` values ``T_map,cam_k`` (the camera pose in the map frame; rotation
``C_map,k``). GTSAM perturbs them on the right, ``T = T_hat Exp([omega; v])``, rotation first, and every
Jacobian below is with respect to that tangent vector.

- VO / pose correction: ``BetweenFactorPose3(x_from, x_to, T_from,to)``; error
  ``Log(T_from,to^-1 T_map,from^-1 T_map,to)``. A ``RelativePose`` carries ``T_to,from`` with a LEFT
  perturbation ``exp(eps) T_to,from``; then ``T_from,to = T_to,from^-1`` is perturbed on the RIGHT by
  ``-eps``, so its GTSAM covariance is the message's with the blocks swapped (:func:`between_measurement`).
- Sun (thesis §5.5, eq. 5.7): ``e = f(C_map,k^T s_map) - f(s_meas)``, ``f(s) = [zenith; azimuth]``,
  azimuth difference wrapped to (-pi, pi]; 2x2 measurement covariance, Huber loss. With a sun bias state
  ``b`` (a ``Vector2`` in radians, zenith and azimuth): ``e = f(C_map,k^T s_map) + b - f(s_meas)``, ``de/db = I``;
  the bias walks by ``BetweenFactorVector(b_i, b_j, 0, Q (t_j - t_i))`` (:func:`offset_walk`).
- Relative rotation (thesis eq. 7.22, HydraNet): ``e = Log(C_from,to_meas^T C_map,from^T C_map,to)``
  with the message's 3x3 rotation covariance; with a rotation offset state ``b`` (``Vector3``, rad) shared by the
  readings of an interval, ``e = Log(...) + b``, ``de/db = I``, walking as the sun's.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray
from pvo_core.covariance import ros_to_gtsam_covariance
from pvo_core.lie import hat, so3_inv_left_jacobian, so3_log
from pvo_core.sun import unit_zenith_azimuth

Array = NDArray[np.float64]

_TWO_PI = 2.0 * np.pi
#: Below this horizontal norm the predicted sun is at the camera's zenith, where azimuth is undefined.
_ZENITH_EPS = 1e-9


def between_measurement(transform_to_from: Array, covariance_ros: Array) -> tuple[gtsam.Pose3, Array]:
    """GTSAM ``BetweenFactorPose3`` measurement ``T_from,to`` and its covariance ([omega; v], right).

    ``transform_to_from`` is a ``RelativePose``'s T_to,from and ``covariance_ros`` its ROS-order
    left-perturbation covariance (6x6).
    """
    measured = np.linalg.inv(np.asarray(transform_to_from, dtype=float))
    return gtsam.Pose3(measured), ros_to_gtsam_covariance(covariance_ros)


def zenith_azimuth(s: Array) -> Array:
    """[zenith, azimuth] (rad) of a camera-frame unit vector (eq. 5.7), stable at the zenith."""
    return np.array(unit_zenith_azimuth(s))


def zenith_azimuth_jacobian(s: Array) -> Array:
    """2x3 derivative of :func:`zenith_azimuth` at unit vector ``s`` (azimuth row zero at the zenith)."""
    rho = float(np.hypot(s[0], s[2]))
    if rho < _ZENITH_EPS:
        return np.array([[-s[1], 0.0, 0.0], [0.0, 0.0, 0.0]])
    return np.array(
        [
            [-s[1] * s[0] / rho, rho, -s[1] * s[2] / rho],
            [s[2] / rho**2, 0.0, -s[0] / rho**2],
        ]
    )


def wrap_angle(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + np.pi) % _TWO_PI - np.pi


def sun_error(rotation_map_cam: Array, sun_map: Array, measured_zenith_azimuth: Array) -> tuple[Array, Array]:
    """Sun residual (2,) and its Jacobian (2x6) w.r.t. the pose's right perturbation [omega; v].

    ``rotation_map_cam`` is C_map,k (3x3), ``sun_map`` the unit sun vector in the map frame.
    """
    predicted = rotation_map_cam.T @ sun_map
    za = zenith_azimuth(predicted)
    error = np.array([za[0] - measured_zenith_azimuth[0], wrap_angle(za[1] - measured_zenith_azimuth[1])])
    jacobian = np.zeros((2, 6))
    # C -> C Exp(omega) moves the predicted vector by s x omega = hat(s) omega.
    jacobian[:, :3] = zenith_azimuth_jacobian(predicted) @ hat(predicted)
    return error, jacobian


def sun_factor(
    key: int, sun_map: Array, measured_direction: Array, covariance: Array, huber_k: float, bias_key: int | None = None
) -> gtsam.CustomFactor:
    """A sun factor on pose ``key`` (Huber on the whitened 2-D residual; ``huber_k <= 0``: plain L2); with
    ``bias_key``, on the pose and the readings' (zenith, azimuth) offset state, which is added to the prediction."""
    sun_map = np.asarray(sun_map, dtype=float)
    measured = zenith_azimuth(np.asarray(measured_direction, dtype=float))
    gaussian = gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, dtype=float))
    noise = (
        gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber_k), gaussian) if huber_k > 0 else gaussian
    )

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Array] | None) -> Array:
        rotation = values.atPose3(this.keys()[0]).rotation().matrix()
        e, jacobian = sun_error(rotation, sun_map, measured)
        if jacobians is not None:
            jacobians[0] = jacobian
            if bias_key is not None:
                jacobians[1] = np.eye(2)
        if bias_key is not None:
            e = e + values.atVector(this.keys()[1])
            e[1] = wrap_angle(e[1])
        return e

    return gtsam.CustomFactor(noise, [key] if bias_key is None else [key, bias_key], error)


def offset_walk(bias_from: int, bias_to: int, walk_sigma: Array, seconds: float) -> gtsam.BetweenFactorVector:
    """An offset state's random walk (a sun's or a rotation sensor's) between two of its states ``seconds`` apart:
    ``b_to - b_from ~ N(0, walk_sigma² t)``, as many dimensions as ``walk_sigma`` has."""
    sigma = np.asarray(walk_sigma, dtype=float) * np.sqrt(max(seconds, 1e-3))
    return gtsam.BetweenFactorVector(bias_from, bias_to, np.zeros(len(sigma)), gtsam.noiseModel.Diagonal.Sigmas(sigma))


_IDENTITY3 = np.eye(3)  # an offset's Jacobian (GTSAM copies what it is given)


def so3_inv_right_jacobian(phi: Array) -> Array:
    """J_r(phi)^-1 = J_l(-phi)^-1."""
    return so3_inv_left_jacobian(-np.asarray(phi, dtype=float))


def rotation_error(rotation_from: Array, rotation_to: Array, measured_from_to: Array) -> tuple[Array, Array, Array]:
    """Relative-rotation residual (3,) and Jacobians (3x6 each) w.r.t. the two poses' right perturbations: the
    numpy reference of what :func:`rotation_factor` computes on GTSAM's ``Rot3``.

    ``rotation_from`` = C_map,from, ``rotation_to`` = C_map,to, ``measured_from_to`` = C_from,to.
    """
    predicted = rotation_from.T @ rotation_to
    error = so3_log(measured_from_to.T @ predicted)
    jr_inv = so3_inv_right_jacobian(error)
    j_from = np.zeros((3, 6))
    j_to = np.zeros((3, 6))
    j_to[:, :3] = jr_inv
    j_from[:, :3] = -jr_inv @ predicted.T
    return error, j_from, j_to


def rotation_factor(
    key_from: int,
    key_to: int,
    transform_to_from: Array,
    covariance_ros: Array,
    huber_k: float = 0.0,
    bias_key: int | None = None,
) -> gtsam.CustomFactor:
    """Rotation-only factor from a ``RelativePose`` (T_to,from; ROS-order left covariance, rotation block used;
    Huber on the whitened 3-D residual when ``huber_k`` > 0); with ``bias_key``, also on the readings' offset state
    b (``Vector3``, rad): ``e = Log(C_from,to_meas^T C_map,from^T C_map,to) + b``, ``de/db = I`` — the reading is
    taken as ``C_from,to Exp(b)``, so b is what the sensor adds on the right.

    A left perturbation of C_to,from is a right perturbation (negated) of C_from,to = C_to,from^T,
    so the 3x3 rotation block applies unchanged.
    """
    measured_from_to = np.asarray(transform_to_from, dtype=float)[:3, :3].T.copy()
    gaussian = gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance_ros, dtype=float)[3:, 3:].copy())
    noise = (
        gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber_k), gaussian) if huber_k > 0 else gaussian
    )

    measured = gtsam.Rot3(measured_from_to)

    # rotation_error's maths on GTSAM's own Rot3 (C++): iSAM2 calls this for every relinearised factor of the window
    # on every update, and numpy's per-call overhead made it most of the fusion's time (stop 67: 185 -> 47 us a call)
    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Array] | None) -> Array:
        keys = this.keys()
        predicted = values.atPose3(keys[0]).rotation().between(values.atPose3(keys[1]).rotation())  # C_from,to
        e = gtsam.Rot3.Logmap(measured.between(predicted))
        if jacobians is not None:
            jr_inv = gtsam.Rot3.LogmapDerivative(e)
            j_from = np.zeros((3, 6))
            j_to = np.zeros((3, 6))
            j_to[:, :3] = jr_inv
            j_from[:, :3] = -jr_inv @ predicted.matrix().T
            jacobians[0] = j_from
            jacobians[1] = j_to
            if bias_key is not None:
                jacobians[2] = _IDENTITY3
        if bias_key is not None:
            e = e + values.atVector(keys[2])
        return e

    keys = [key_from, key_to] if bias_key is None else [key_from, key_to, bias_key]
    return gtsam.CustomFactor(noise, keys, error)
