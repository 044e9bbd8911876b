"""Unit quaternions for HydraNet (thesis §7.4.3-7.4.4), in torch so that the loss is differentiable.

Quaternions are (w, x, y, z), Hamilton product, q and -q the same rotation. Uncertainty lives in the left
tangent space: q = Exp(eps) (x) q_mean, eps ~ N(0, Sigma) (eq. 7.15), eps a rotation vector (rad).
"""

from __future__ import annotations

import torch

#: Below this half-angle sine the logarithm uses its series (2 v / w, exact to second order).
SMALL = 1e-6


def multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a (x) b of (..., 4) quaternions."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def conjugate(q: torch.Tensor) -> torch.Tensor:
    """q^-1 of unit quaternions (..., 4)."""
    return q * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q.dtype, device=q.device)


def log(q: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) of unit quaternions (..., 4): the angle in [0, pi] about the axis, taking the
    representative with w >= 0 (q and -q give the same vector)."""
    q = torch.where(q[..., :1] < 0.0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    sine = torch.linalg.vector_norm(v, dim=-1)
    safe = torch.where(sine > SMALL, sine, torch.ones_like(sine))
    scale = torch.where(sine > SMALL, 2.0 * torch.atan2(sine, w) / safe, 2.0 / w)
    return v * scale.unsqueeze(-1)


def exp(phi: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4) of rotation vectors (..., 3)."""
    angle = torch.linalg.vector_norm(phi, dim=-1, keepdim=True)
    half = 0.5 * angle
    safe = torch.where(angle > SMALL, angle, torch.ones_like(angle))
    scale = torch.where(angle > SMALL, torch.sin(half) / safe, 0.5 - angle**2 / 48.0)
    return torch.cat([torch.cos(half), phi * scale], dim=-1)


def rotation_matrix(q: torch.Tensor) -> torch.Tensor:
    """The rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    w, x, y, z = q.unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)


def align_signs(heads: torch.Tensor) -> torch.Tensor:
    """Heads (..., H, 4) with each sign chosen to agree with the first head's (q and -q are one rotation)."""
    reference = heads[..., :1, :]
    dots = (heads * reference).sum(dim=-1, keepdim=True)
    return torch.where(dots < 0.0, -heads, heads)


def mean(heads: torch.Tensor) -> torch.Tensor:
    """The quaternionic-metric rotation average (eq. 7.14) of heads (..., H, 4): the normalised sum of the
    sign-aligned heads, with w >= 0."""
    total = align_signs(heads).sum(dim=-2)
    average = total / torch.linalg.vector_norm(total, dim=-1, keepdim=True)
    return torch.where(average[..., :1] < 0.0, -average, average)


def epistemic_covariance(heads: torch.Tensor, average: torch.Tensor) -> torch.Tensor:
    """Sigma_e (..., 3, 3) of eq. 7.16: the sample covariance (1/(H-1)) of phi_i = Log(q_i (x) q_mean^-1)."""
    phi = log(multiply(heads, conjugate(average).unsqueeze(-2)))  # (..., H, 3)
    return phi.transpose(-1, -2) @ phi / (heads.shape[-2] - 1)


def nll(q: torch.Tensor, target: torch.Tensor, covariance: torch.Tensor) -> torch.Tensor:
    """Eq. 7.17 per sample (...,): 1/2 phi^T Sigma^-1 phi + 1/2 log det Sigma, phi = Log(q (x) q_t^-1), for
    predictions q (..., 4), targets (..., 4) and covariances (..., 3, 3)."""
    phi = log(multiply(q, conjugate(target))).unsqueeze(-1)
    solved = torch.linalg.solve(covariance, phi)
    return 0.5 * (phi.transpose(-1, -2) @ solved).squeeze(-1).squeeze(-1) + 0.5 * torch.logdet(covariance)
