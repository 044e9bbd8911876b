"""SO(3) and SE(3) for pvo: exponential and logarithm maps, Jacobians, adjoint, quaternions.

Conventions (thesis app. B, Barfoot's "State Estimation for Robotics"):

- An se(3) tangent vector is ``xi = [rho; phi]``: translation part first (metres), rotation part
  second (radians), shape (6,).
- ``se3_exp(xi) = [[so3_exp(phi), so3_left_jacobian(phi) @ rho], [0, 1]]``.
- Perturbations are on the LEFT: ``T = se3_exp(dxi) @ T_nominal``.
- ``T_ab`` maps coordinates in frame b to frame a (``p_a = T_ab @ p_b``).
- Quaternions are ``(w, x, y, z)`` with the sign fixed so that ``w >= 0``.

GTSAM orders its Pose3 tangent rotation first (``[omega; v]``) and perturbs on the right; the
conversion lives in :mod:`pvo_core.covariance`. All functions take and return float64 numpy arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Below this rotation angle (rad) series expansions replace the closed forms.
SMALL_ANGLE = 1e-6
#: Within this distance of pi the logarithm extracts the axis from the symmetric part.
NEAR_PI = 1e-2


def hat(phi: ArrayLike) -> Array:
    """The skew-symmetric 3x3 matrix ``phi^`` with ``phi^ @ v = phi x v``."""
    x, y, z = np.asarray(phi, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(matrix: ArrayLike) -> Array:
    """Inverse of :func:`hat` for a 3x3 skew-symmetric matrix (its antisymmetric part is used)."""
    m = np.asarray(matrix, dtype=float)
    return 0.5 * np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])


def so3_exp(phi: ArrayLike) -> Array:
    """Rotation matrix ``exp(phi^)`` for an axis-angle vector ``phi`` (rad), Rodrigues' formula."""
    phi = np.asarray(phi, dtype=float)
    theta = float(np.linalg.norm(phi))
    phi_hat = hat(phi)
    if theta < SMALL_ANGLE:
        return np.eye(3) + phi_hat + 0.5 * phi_hat @ phi_hat
    a = np.sin(theta) / theta
    b = (1.0 - np.cos(theta)) / theta**2
    return np.eye(3) + a * phi_hat + b * phi_hat @ phi_hat


def so3_log(rotation: ArrayLike) -> Array:
    """Axis-angle vector ``phi`` (rad, ``|phi| <= pi``) with ``so3_exp(phi) == rotation``.

    Three branches: the series near the identity, the closed form in general, and near pi the
    unit quaternion's vector part (where the closed form divides by ``sin(theta) ~ 0``).
    """
    rot = np.asarray(rotation, dtype=float)
    cos_theta = np.clip(0.5 * (np.trace(rot) - 1.0), -1.0, 1.0)
    axis_sin = vee(rot)  # = sin(theta) * axis
    theta = float(np.arctan2(np.linalg.norm(axis_sin), cos_theta))  # accurate where arccos is not
    if theta < SMALL_ANGLE:
        return axis_sin * (1.0 + theta**2 / 6.0)
    if np.pi - theta < NEAR_PI:
        # The closed form divides by sin(theta) ~ 0 here. The quaternion (Shepperd's method) takes
        # the axis from the symmetric part and the small scalar w from the antisymmetric part, both
        # to machine precision, so theta = 2 atan2(|v|, w) keeps full accuracy up to pi.
        q = rotation_to_quaternion(rot)
        v = q[1:]
        norm_v = float(np.linalg.norm(v))
        return 2.0 * np.arctan2(norm_v, q[0]) * v / norm_v
    return theta / np.sin(theta) * axis_sin


def so3_left_jacobian(phi: ArrayLike) -> Array:
    """Left Jacobian ``J_l(phi)`` of SO(3): ``exp((phi + d)^) ~ exp((J_l d)^) exp(phi^)``."""
    phi = np.asarray(phi, dtype=float)
    theta = float(np.linalg.norm(phi))
    phi_hat = hat(phi)
    if theta < SMALL_ANGLE:
        return np.eye(3) + 0.5 * phi_hat + phi_hat @ phi_hat / 6.0
    a = (1.0 - np.cos(theta)) / theta**2
    b = (theta - np.sin(theta)) / theta**3
    return np.eye(3) + a * phi_hat + b * phi_hat @ phi_hat


def so3_inv_left_jacobian(phi: ArrayLike) -> Array:
    """Inverse of :func:`so3_left_jacobian` (singular at ``|phi| = 2 pi``, fine on ``|phi| <= pi``)."""
    phi = np.asarray(phi, dtype=float)
    theta = float(np.linalg.norm(phi))
    phi_hat = hat(phi)
    if theta < SMALL_ANGLE:
        return np.eye(3) - 0.5 * phi_hat + phi_hat @ phi_hat / 12.0
    half = 0.5 * theta
    c = (1.0 - half / np.tan(half)) / theta**2
    return np.eye(3) - 0.5 * phi_hat + c * phi_hat @ phi_hat


def so3_right_jacobian(phi: ArrayLike) -> Array:
    """Right Jacobian ``J_r(phi) = J_l(-phi)`` (GTSAM's ``Rot3.ExpmapDerivative``)."""
    return so3_left_jacobian(-np.asarray(phi, dtype=float))


def se3_exp(xi: ArrayLike) -> Array:
    """4x4 transform ``exp(xi^)`` for ``xi = [rho; phi]`` (m, rad)."""
    xi = np.asarray(xi, dtype=float)
    rho, phi = xi[:3], xi[3:]
    transform = np.eye(4)
    transform[:3, :3] = so3_exp(phi)
    transform[:3, 3] = so3_left_jacobian(phi) @ rho
    return transform


def se3_log(transform: ArrayLike) -> Array:
    """``xi = [rho; phi]`` with ``se3_exp(xi) == transform``."""
    t = np.asarray(transform, dtype=float)
    phi = so3_log(t[:3, :3])
    rho = so3_inv_left_jacobian(phi) @ t[:3, 3]
    return np.concatenate([rho, phi])


def se3_inverse(transform: ArrayLike) -> Array:
    """Inverse of a 4x4 rigid transform without a general matrix inversion."""
    t = np.asarray(transform, dtype=float)
    inv = np.eye(4)
    inv[:3, :3] = t[:3, :3].T
    inv[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return inv


def _se3_q_matrix(rho: Array, phi: Array) -> Array:
    """The coupling block Q(rho, phi) of the SE(3) left Jacobian (Barfoot eq. 7.86)."""
    theta = float(np.linalg.norm(phi))
    rx, px = hat(rho), hat(phi)
    if theta < SMALL_ANGLE:
        # Series of the closed form's coefficients: 1/6, 1/24, -1/120 (and 1/2 for the first term).
        return 0.5 * rx + (px @ rx + rx @ px + px @ rx @ px) / 6.0
    s, c = np.sin(theta), np.cos(theta)
    a = (theta - s) / theta**3
    b = (theta**2 + 2.0 * c - 2.0) / (2.0 * theta**4)
    d = (2.0 * theta - 3.0 * s + theta * c) / (2.0 * theta**5)
    return (
        0.5 * rx
        + a * (px @ rx + rx @ px + px @ rx @ px)
        + b * (px @ px @ rx + rx @ px @ px - 3.0 * px @ rx @ px)
        + d * (px @ rx @ px @ px + px @ px @ rx @ px)
    )


def se3_left_jacobian(xi: ArrayLike) -> Array:
    """6x6 left Jacobian of SE(3) for ``xi = [rho; phi]``: ``[[J, Q], [0, J]]``."""
    xi = np.asarray(xi, dtype=float)
    rho, phi = xi[:3], xi[3:]
    jac = np.zeros((6, 6))
    j = so3_left_jacobian(phi)
    jac[:3, :3] = j
    jac[3:, 3:] = j
    jac[:3, 3:] = _se3_q_matrix(rho, phi)
    return jac


def se3_inv_left_jacobian(xi: ArrayLike) -> Array:
    """Inverse of :func:`se3_left_jacobian`: ``[[J^-1, -J^-1 Q J^-1], [0, J^-1]]``."""
    xi = np.asarray(xi, dtype=float)
    rho, phi = xi[:3], xi[3:]
    j_inv = so3_inv_left_jacobian(phi)
    inv = np.zeros((6, 6))
    inv[:3, :3] = j_inv
    inv[3:, 3:] = j_inv
    inv[:3, 3:] = -j_inv @ _se3_q_matrix(rho, phi) @ j_inv
    return inv


def se3_adjoint(transform: ArrayLike) -> Array:
    """6x6 adjoint ``Ad(T) = [[C, r^ C], [0, C]]`` in ``[rho; phi]`` order.

    It moves a left perturbation through the transform: ``T exp(xi^) = exp((Ad(T) xi)^) T``.
    """
    t = np.asarray(transform, dtype=float)
    c, r = t[:3, :3], t[:3, 3]
    adj = np.zeros((6, 6))
    adj[:3, :3] = c
    adj[3:, 3:] = c
    adj[:3, 3:] = hat(r) @ c
    return adj


def odot(point: ArrayLike) -> Array:
    """The ``p^odot`` operator with ``xi^ p = p^odot xi``.

    ``point`` is a Euclidean point (3,) -> (3, 6) ``[I, -p^]``, a homogeneous point (4,)
    ``[eps; eta]`` -> (4, 6) ``[[eta I, -eps^], [0, 0]]``, or a batch (N, 3) -> (N, 3, 6).
    """
    p = np.asarray(point, dtype=float)
    if p.ndim == 2:
        out = np.zeros((p.shape[0], 3, 6))
        out[:, 0, 0] = out[:, 1, 1] = out[:, 2, 2] = 1.0
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        # -p^ = [[0, z, -y], [-z, 0, x], [y, -x, 0]]
        out[:, 0, 4], out[:, 0, 5] = z, -y
        out[:, 1, 3], out[:, 1, 5] = -z, x
        out[:, 2, 3], out[:, 2, 4] = y, -x
        return out
    if p.shape == (3,):
        return np.hstack([np.eye(3), -hat(p)])
    if p.shape == (4,):
        out = np.zeros((4, 6))
        out[:3, :3] = p[3] * np.eye(3)
        out[:3, 3:] = -hat(p[:3])
        return out
    raise ValueError(f"odot expects a point of shape (3,), (4,) or (N, 3), got {p.shape}")


def rotation_to_quaternion(rotation: ArrayLike) -> Array:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0`` of a rotation matrix (Shepperd's method)."""
    r = np.asarray(rotation, dtype=float)
    trace = np.trace(r)
    candidates = np.array([trace, r[0, 0], r[1, 1], r[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        w = 0.5 * np.sqrt(max(1.0 + trace, 0.0))
        s = 0.25 / w
        q = np.array([w, (r[2, 1] - r[1, 2]) * s, (r[0, 2] - r[2, 0]) * s, (r[1, 0] - r[0, 1]) * s])
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        v = 0.5 * np.sqrt(max(1.0 + r[i, i] - r[j, j] - r[m, m], 0.0))
        s = 0.25 / v
        q = np.empty(4)
        q[0] = (r[m, j] - r[j, m]) * s
        q[1 + i] = v
        q[1 + j] = (r[j, i] + r[i, j]) * s
        q[1 + m] = (r[m, i] + r[i, m]) * s
    q /= np.linalg.norm(q)
    return -q if q[0] < 0.0 else q


def quaternion_to_rotation(quaternion: ArrayLike) -> Array:
    """Rotation matrix of a quaternion ``(w, x, y, z)`` (normalised first; must be non-zero)."""
    q = np.asarray(quaternion, dtype=float)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"quaternion {q} is zero or not finite")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def make_transform(rotation: ArrayLike, translation: ArrayLike) -> Array:
    """4x4 transform from a 3x3 rotation and a 3-vector translation."""
    t = np.eye(4)
    t[:3, :3] = np.asarray(rotation, dtype=float)
    t[:3, 3] = np.asarray(translation, dtype=float)
    return t


def is_rotation(matrix: ArrayLike, tol: float = 1e-6) -> bool:
    """True when ``matrix`` is a finite 3x3 proper rotation within ``tol``."""
    m = np.asarray(matrix, dtype=float)
    if m.shape != (3, 3):
        return False
    deviation = m @ m.T
    deviation[0, 0] -= 1.0
    deviation[1, 1] -= 1.0
    deviation[2, 2] -= 1.0
    # NaN compares False, so a non-finite matrix fails both tests.
    return bool(np.abs(deviation).max() <= tol) and bool(abs(np.linalg.det(m) - 1.0) < tol)


def nearest_rotations(matrices: ArrayLike) -> Array:
    """The closest proper rotations (Frobenius norm) to a stack of 3x3 matrices (..., 3, 3): U diag(1, 1, det) V^T.

    Rotations read from files are orthonormal only to their stored precision; composing thousands of
    them with inverse = transpose (as GTSAM does) and with a general matrix inverse then drifts apart.
    """
    m = np.asarray(matrices, dtype=float)
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt
