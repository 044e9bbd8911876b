"""DPC-Net's losses: g(ξ) and L against direct evaluation with pvo_core's maps, zero at the target, the
analytic Jacobian of eq. 6.14 against finite differences (gradcheck) for SE(3) and SO(3), eq. 6.6 against
numpy's covariance, and one line for too few targets."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pvo_core.lie import se3_exp, se3_log, so3_exp, so3_log
from pvo_pseudosensors.dpc_net.loss import GroupLoss, se3_loss, so3_loss, target_covariance, yaw_loss


def random_corrections(rng: np.random.Generator, n: int, scale: float = 0.3) -> np.ndarray:
    return np.column_stack([rng.normal(0, scale, (n, 3)), rng.normal(0, scale, (n, 3))])


def test_the_pose_loss_is_half_the_weighted_log_residual_and_zero_at_the_target() -> None:
    rng = np.random.default_rng(0)
    targets = np.stack([se3_exp(x) for x in random_corrections(rng, 5)])
    xi = random_corrections(rng, 5)
    covariance = np.diag([0.01, 0.02, 0.03, 0.001, 0.002, 0.003])
    loss = se3_loss(torch.tensor(xi), torch.tensor(targets), torch.tensor(covariance))
    g = np.stack([se3_log(se3_exp(x) @ np.linalg.inv(t)) for x, t in zip(xi, targets, strict=True)])
    expected = np.mean(0.5 * np.einsum("bi,ij,bj->b", g, np.linalg.inv(covariance), g))
    assert float(loss) == pytest.approx(expected, rel=1e-12)
    at_target = np.stack([se3_log(t) for t in targets])
    assert float(se3_loss(torch.tensor(at_target), torch.tensor(targets), torch.tensor(covariance))) < 1e-20


def test_the_analytic_jacobians_pass_gradcheck() -> None:
    rng = np.random.default_rng(1)
    targets = torch.tensor(np.stack([se3_exp(x) for x in random_corrections(rng, 4, 0.5)]))
    covariance = np.cov(rng.normal(size=(50, 6)), rowvar=False)
    information = torch.linalg.inv(torch.tensor(covariance))
    xi = torch.tensor(random_corrections(rng, 4, 0.5), requires_grad=True)
    inverse = torch.linalg.inv(targets)
    assert torch.autograd.gradcheck(lambda x: GroupLoss.apply(x, inverse, information), (xi,), eps=1e-6, atol=1e-6)
    rotations = torch.tensor(np.stack([so3_exp(p) for p in rng.normal(0, 0.5, (4, 3))]))
    phi = torch.tensor(rng.normal(0, 0.5, (4, 3)), requires_grad=True)
    info3 = torch.linalg.inv(torch.tensor(covariance[3:, 3:]))
    assert torch.autograd.gradcheck(lambda p: GroupLoss.apply(p, rotations.transpose(-1, -2), info3), (phi,), eps=1e-6, atol=1e-6)


def test_gradient_descent_on_the_loss_reaches_the_target() -> None:
    rng = np.random.default_rng(2)
    target = torch.tensor(se3_exp(random_corrections(rng, 1, 0.4)[0]))[None]
    xi = torch.zeros(1, 6, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.SGD([xi], lr=0.5)
    for _ in range(200):
        optimiser.zero_grad()
        se3_loss(xi, target, torch.eye(6, dtype=torch.float64)).backward()
        optimiser.step()
    np.testing.assert_allclose(xi.detach().numpy()[0], se3_log(target.numpy()[0]), atol=1e-8)


def test_the_rotation_and_yaw_forms() -> None:
    rng = np.random.default_rng(3)
    phi = rng.normal(0, 0.2, (3, 3))
    targets = np.stack([so3_exp(p) for p in rng.normal(0, 0.2, (3, 3))])
    loss = so3_loss(torch.tensor(phi), torch.tensor(targets), torch.eye(3, dtype=torch.float64))
    g = np.stack([so3_log(so3_exp(p) @ t.T) for p, t in zip(phi, targets, strict=True)])
    assert float(loss) == pytest.approx(np.mean(0.5 * np.sum(g**2, axis=1)), rel=1e-12)
    assert float(yaw_loss(torch.tensor([[0.1], [0.3]]), torch.tensor([0.0, 0.1]))) == pytest.approx((0.01 + 0.04) / 2)


def test_the_target_covariance_is_eq_6_6() -> None:
    rng = np.random.default_rng(4)
    logs = random_corrections(rng, 40, 0.1)
    targets = np.stack([se3_exp(x) for x in logs])
    np.testing.assert_allclose(target_covariance(targets), np.cov(logs, rowvar=False), atol=1e-12)
    rotations = np.stack([so3_exp(p) for p in logs[:, 3:]])
    np.testing.assert_allclose(target_covariance(rotations), np.cov(logs[:, 3:], rowvar=False), atol=1e-12)
    with pytest.raises(ValueError, match="at least two training targets"):
        target_covariance(targets[:1])
