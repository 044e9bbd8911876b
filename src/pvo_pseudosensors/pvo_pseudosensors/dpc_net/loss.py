"""DPC-Net's losses (thesis §6.3): the correction ξ against the target T* = T_gt T̂^-1, through
g(ξ) = log(exp(ξ^) T*^-1)^∨ and L = ½ g^T Σ^-1 g (eq. 6.2), with the analytic Jacobian
∂g/∂ξ = J(g)^-1 J(ξ) (eq. 6.14, J the left Jacobian) in the backward pass instead of differentiating through
the matrix exponential and logarithm. The SO(3) form (monocular, rotation only) is the same with SO(3)
maps; the yaw form is a squared error on one angle.

ξ = [ρ; φ] (m, rad), left perturbations, as :mod:`pvo_core.lie`. The maps run in float64 numpy per sample:
a batch is tens of 4x4 matrices, and the Jacobians are exact to first order, so ``gradcheck`` holds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from pvo_core.lie import (
    se3_exp,
    se3_inv_left_jacobian,
    se3_left_jacobian,
    se3_log,
    so3_exp,
    so3_inv_left_jacobian,
    so3_left_jacobian,
    so3_log,
)

Array = NDArray[np.float64]
#: per variant: dimension, exp, log, left Jacobian, its inverse
GROUPS: dict[int, tuple[Any, Any, Any, Any]] = {
    6: (se3_exp, se3_log, se3_left_jacobian, se3_inv_left_jacobian),
    3: (so3_exp, so3_log, so3_left_jacobian, so3_inv_left_jacobian),
}


def target_covariance(targets: ArrayLike) -> Array:
    """Eq. 6.6: the sample covariance (1/(N-1), about the mean) of log(T*) over the training targets
    (N, 4, 4) for SE(3) or (N, 3, 3) rotations for SO(3); (6, 6) or (3, 3)."""
    targets = np.asarray(targets, dtype=float)
    logs = np.stack([(se3_log if targets.shape[-1] == 4 else so3_log)(t) for t in targets])
    if len(logs) < 2:
        raise ValueError("the target covariance needs at least two training targets")
    return np.cov(logs, rowvar=False)


def residuals(xi: Array, target_inverse: Array) -> tuple[Array, Array]:
    """g(ξ) (B, d) and ∂g/∂ξ (B, d, d) for corrections ξ (B, d) and T*^-1 (B, 4, 4) or C*^T (B, 3, 3)."""
    d = xi.shape[1]
    exp, log, jacobian, inverse_jacobian = GROUPS[d]
    g = np.stack([log(exp(x) @ t) for x, t in zip(xi, target_inverse, strict=True)])
    dg = np.stack([inverse_jacobian(gi) @ jacobian(x) for gi, x in zip(g, xi, strict=True)])
    return g, dg


class GroupLoss(torch.autograd.Function):
    """L = mean over the batch of ½ g(ξ)^T Σ^-1 g(ξ); the gradient from eq. 6.14."""

    @staticmethod
    def forward(ctx: Any, xi: torch.Tensor, target_inverse: torch.Tensor, information: torch.Tensor) -> torch.Tensor:
        g, dg = residuals(xi.detach().double().cpu().numpy(), target_inverse.detach().double().cpu().numpy())
        info = information.detach().double().cpu().numpy()
        weighted = g @ info  # (B, d): g^T Σ^-1 per sample (Σ^-1 symmetric)
        loss = 0.5 * float(np.mean(np.einsum("bi,bi->b", weighted, g)))
        # dL/dξ_b = (1/B) (∂g/∂ξ)^T Σ^-1 g
        grad = np.einsum("bij,bi->bj", dg, weighted) / len(g)
        ctx.save_for_backward(torch.from_numpy(grad).to(xi.device, xi.dtype))
        return torch.tensor(loss, dtype=xi.dtype, device=xi.device)

    @staticmethod
    def backward(ctx: Any, upstream: torch.Tensor) -> tuple[torch.Tensor, None, None]:
        (grad,) = ctx.saved_tensors
        return upstream * grad, None, None


def se3_loss(xi: torch.Tensor, target: torch.Tensor, covariance: torch.Tensor) -> torch.Tensor:
    """The pose loss for corrections ξ (B, 6) against targets T* (B, 4, 4) with the covariance of eq. 6.6."""
    return GroupLoss.apply(xi, _inverse_transforms(target), torch.linalg.inv(covariance))


def so3_loss(phi: torch.Tensor, target: torch.Tensor, covariance: torch.Tensor) -> torch.Tensor:
    """The rotation loss for corrections φ (B, 3) against target rotations C* (B, 3, 3), Σ (3, 3)."""
    return GroupLoss.apply(phi, target.transpose(-1, -2), torch.linalg.inv(covariance))


def yaw_loss(yaw: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The yaw form: squared error of the correction's yaw (B, 1) against the target yaw (B,) (rad), as the
    authors' code (a plain mean squared error)."""
    return torch.mean((yaw[:, 0] - target) ** 2)


def _inverse_transforms(transforms: torch.Tensor) -> torch.Tensor:
    rotation_t = transforms[..., :3, :3].transpose(-1, -2)
    out = torch.zeros_like(transforms)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -(rotation_t @ transforms[..., :3, 3:])[..., 0]
    out[..., 3, 3] = 1.0
    return out
