"""Lab 04b's support code (kfkit.labs.lab04b) against independent oracles: its BROAD inputs are lab 04's, the error
state's finite differences are scipy's, and the reset's J = diag(I − [δθ/2 ×], I) is the derivative of the new error
with respect to the old one, by finite differences of scipy's rotations."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit.labs import lab04b
from kfkit.labs.lab04 import real_inputs


def scalar_first(r):
    return r.as_quat()[[3, 0, 1, 2]]


@pytest.mark.slow
@pytest.mark.parametrize("name", lab04b.TRIALS)
def test_the_broad_inputs_are_lab_04s_cut_at_the_end_of_the_movement(name):
    mine, lab04 = lab04b.broad(name), real_inputs(name)
    end = np.flatnonzero(lab04[6])[-1] + 1
    assert len(mine[1]) == end
    for a, b in zip(mine[1:], lab04[1:]):
        b = np.asarray(b)[:end] if np.ndim(b) == 2 or len(b) > 3 else b
        assert np.allclose(a, b, rtol=0.0, atol=1e-9, equal_nan=True)


def test_error_state_finite_differences_turn_on_the_right():
    """h(q ⊗ exp(δθ/2)) differentiated by scipy's composition R(q)·exp(δθ): gravity seen in the body frame."""
    q = scalar_first(Rotation.from_euler("ZYX", [1.0, -0.2, 0.3]))
    h = lambda p: Rotation.from_quat(p[[1, 2, 3, 0]]).inv().apply(lab04b.UP_N)
    eps = 1e-6
    expected = np.column_stack(
        [
            (Rotation.from_quat(q[[1, 2, 3, 0]]) * Rotation.from_rotvec(e)).inv().apply(lab04b.UP_N)
            - (Rotation.from_quat(q[[1, 2, 3, 0]]) * Rotation.from_rotvec(-e)).inv().apply(lab04b.UP_N)
            for e in np.eye(3) * eps
        ]
    ) / (2 * eps)
    assert np.allclose(lab04b.error_state_fd(h, q), expected, atol=1e-8)
    assert np.allclose(lab04b.accel_jacobian(q)[:, :3], expected, atol=1e-6)


def test_the_reset_jacobian_is_the_derivative_of_the_new_error():
    """After q⁺ = q ⊗ exp(δθ̂), a true error δθ (q_true = q ⊗ exp(δθ)) becomes δθ⁺ = log(exp(δθ̂)⁻¹ ⊗ exp(δθ)); its
    derivative at δθ = δθ̂ is I − [δθ̂/2 ×] to first order in δθ̂ (the sign matters: I + [δθ̂/2 ×] is off by |δθ̂|)."""
    rng = np.random.default_rng(5)
    d_hat = np.radians(3.0) * rng.normal(size=3)
    new_error = lambda d: (Rotation.from_rotvec(d_hat).inv() * Rotation.from_rotvec(d)).as_rotvec()
    eps = 1e-6
    derivative = np.column_stack([(new_error(d_hat + e) - new_error(d_hat - e)) / (2 * eps) for e in np.eye(3) * eps])
    J = lab04b.mekf_reset(np.array([1.0, 0, 0, 0]), np.zeros(3), np.eye(6), np.r_[d_hat, 0, 0, 0])[2][:3, :3]
    # J P Jᵀ with P = I is J Jᵀ: compare J itself, rebuilt from the same formula the reset applies
    J_reset = np.eye(3) - lab04b.cross_matrix(d_hat / 2)
    assert np.allclose(J, J_reset @ J_reset.T)
    size = np.linalg.norm(d_hat)
    assert np.abs(derivative - J_reset).max() < 0.25 * size**2  # the second-order terms the reset leaves out
    assert np.abs(derivative - (np.eye(3) + lab04b.cross_matrix(d_hat / 2))).max() > 0.3 * size
