"""HydraNet's quaternion maths against independent implementations and hand-computed cases: the logarithm
against pvo_core's SO(3) log, the mean with sign flips and heads near +-q, Sigma_e, and the NLL's value and
gradient (finite differences)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pvo_core.lie import quaternion_to_rotation, so3_exp, so3_log
from pvo_pseudosensors.hydranet import quaternion as quat


def as_tensor(values: object) -> torch.Tensor:
    return torch.tensor(np.asarray(values, dtype=float), dtype=torch.float64)


def test_log_and_exp_agree_with_so3_of_the_rotation_matrix() -> None:
    rng = np.random.default_rng(0)
    cases = [rng.normal(size=4) for _ in range(50)] + [np.array([1.0, 1e-9, 0.0, 0.0]), np.array([-0.5, 0.5, 0.5, 0.5])]
    for q in cases:
        q = q / np.linalg.norm(q)
        phi = quat.log(as_tensor(q)).numpy()
        np.testing.assert_allclose(phi, so3_log(quaternion_to_rotation(q * np.sign(q[0] or 1.0))), atol=1e-9)
        np.testing.assert_allclose(quat.log(as_tensor(-q)).numpy(), phi, atol=1e-12)  # -q is the same rotation
        back = quat.exp(as_tensor(phi)).numpy()
        np.testing.assert_allclose(quaternion_to_rotation(back), quaternion_to_rotation(q), atol=1e-9)
    np.testing.assert_allclose(
        quaternion_to_rotation(quat.exp(as_tensor([0.3, -0.2, 0.1])).numpy()), so3_exp([0.3, -0.2, 0.1]), atol=1e-12
    )


def test_mean_ignores_sign_flips_and_is_the_centre_of_symmetric_heads() -> None:
    centre = quat.exp(as_tensor([0.2, 0.1, -0.4]))
    offsets = as_tensor([[0.01, 0, 0], [-0.01, 0, 0], [0, 0.02, 0], [0, -0.02, 0]])
    heads = quat.multiply(quat.exp(offsets), centre.expand(4, 4))
    np.testing.assert_allclose(quat.mean(heads).numpy(), centre.numpy(), atol=1e-12)
    flipped = heads * as_tensor([[1.0], [-1.0], [1.0], [-1.0]])  # half the heads output -q
    np.testing.assert_allclose(quat.mean(flipped).numpy(), centre.numpy(), atol=1e-12)
    # near w = 0 (180 degrees): heads on both sides of the sign cut still average to the rotation
    half_turn = quat.exp(as_tensor([np.pi - 1e-3, 0.0, 0.0]))
    around = quat.multiply(quat.exp(as_tensor([[0.0, 0.01, 0.0], [0.0, -0.01, 0.0]])), half_turn.expand(2, 4))
    around = around * as_tensor([[1.0], [-1.0]])
    average = quat.mean(around)
    assert float(average[0]) >= 0.0
    np.testing.assert_allclose(quaternion_to_rotation(average.numpy()), quaternion_to_rotation(half_turn.numpy()), atol=1e-9)


def test_epistemic_covariance_of_two_heads_either_side_of_the_mean() -> None:
    a = 0.05
    centre = quat.exp(as_tensor([0.0, 0.3, 0.0]))
    heads = quat.multiply(quat.exp(as_tensor([[a, 0, 0], [-a, 0, 0]])), centre.expand(2, 4))
    sigma = quat.epistemic_covariance(heads, quat.mean(heads)).numpy()
    np.testing.assert_allclose(sigma, np.diag([2 * a * a, 0.0, 0.0]), atol=1e-12)  # sum of phi phi^T over H - 1 = 1


def test_nll_value_and_gradient() -> None:
    q = quat.exp(as_tensor([0.1, -0.05, 0.02]))
    target = quat.exp(as_tensor([0.08, -0.04, 0.05]))
    covariance = as_tensor(np.diag([0.01, 0.02, 0.04]))
    phi = so3_log(quaternion_to_rotation(q.numpy()) @ quaternion_to_rotation(target.numpy()).T)
    expected = 0.5 * phi @ np.linalg.solve(covariance.numpy(), phi) + 0.5 * np.log(np.linalg.det(covariance.numpy()))
    assert float(quat.nll(q, target, covariance)) == pytest.approx(expected, rel=1e-10)
    # gradient by finite differences through an unnormalised output and a Cholesky factor, as a network has them
    raw = as_tensor([0.98, 0.05, -0.03, 0.01]).requires_grad_()
    factor = as_tensor([[0.1, 0.0, 0.0], [0.02, 0.14, 0.0], [-0.01, 0.03, 0.2]]).requires_grad_()

    def loss(raw: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
        lower = torch.tril(factor)
        return quat.nll(raw / torch.linalg.vector_norm(raw), target, lower @ lower.T + 1e-9 * torch.eye(3, dtype=raw.dtype))

    assert torch.autograd.gradcheck(loss, (raw, factor), eps=1e-6, atol=1e-6)
