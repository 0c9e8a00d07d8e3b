"""Lab 04's optional derivation of the MEKF (section 11's end) against the physics and the code.

Oracle: rotations composed by scipy (``Rotation.from_rotvec``), independent of kfkit's quaternion code: the
derivation's error δθ is a body-frame rotation, R_true = R·Exp(δθ).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit.filters import MultiplicativeEKF
from kfkit.frames import G, quat_to_dcm


def skew(v):
    """[v×], the matrix of v × (·)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def exp_so3(v):
    return Rotation.from_rotvec(v).as_matrix()


def log_so3(R):
    return Rotation.from_matrix(R).as_rotvec()


@pytest.mark.parametrize("seed", range(5))
def test_the_reference_vector_jacobian_is_the_cross_product_matrix_of_the_body_vector(seed):
    # H = [R_bn v_n ×]: finite differences of h(δθ) = (R·Exp(δθ))ᵀ v_n at δθ = 0
    rng = np.random.default_rng(seed)
    R, v_n = Rotation.random(random_state=seed).as_matrix(), rng.normal(0.0, 10.0, 3)
    eps = 1e-6
    fd = np.column_stack(
        [((R @ exp_so3(eps * e)).T @ v_n - (R @ exp_so3(-eps * e)).T @ v_n) / (2 * eps) for e in np.eye(3)]
    )
    np.testing.assert_allclose(fd, skew(R.T @ v_n), atol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_one_step_of_the_error_is_F_times_the_error(seed):
    # nominal R turned by ω̂Δt, the truth R·Exp(δθ) by (ω̂ − δb)Δt: the new error is Exp(−[ω̂Δt]×)δθ − δbΔt (first order)
    rng = np.random.default_rng(seed)
    R, dt = Rotation.random(random_state=seed).as_matrix(), 0.01
    w_hat = rng.normal(0.0, 3.0, 3)
    d_theta, d_b = rng.normal(0.0, 1e-4, 3), rng.normal(0.0, 1e-4, 3)
    R_next = R @ exp_so3(w_hat * dt)
    true_next = R @ exp_so3(d_theta) @ exp_so3((w_hat - d_b) * dt)
    got = log_so3(R_next.T @ true_next)
    want = exp_so3(-w_hat * dt) @ d_theta - d_b * dt
    np.testing.assert_allclose(got, want, atol=1e-7)  # second-order terms: |δ|² ~ 1e-8


def test_the_kit_mekf_propagates_with_the_derived_F():
    # MultiplicativeEKF's prediction matrix is the derivation's F = [[Exp(−[ω̂Δt]×), −IΔt], [0, I]], ω̂ = ω − b
    rate, bias, w = 100.0, np.array([0.01, -0.02, 0.015]), np.array([1.0, -2.0, 0.5])
    ekf = MultiplicativeEKF(rate_hz=rate, field_n=np.array([20.0, 0.0, 45.0]), bias0=bias, q0=[1.0, 0.0, 0.0, 0.0])
    ekf._start(np.array([[0.0, 0.0, -G]]), None)
    ekf._predict(*w)
    dt = 1.0 / rate
    F = np.block([[exp_so3(-(w - bias) * dt), -dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    np.testing.assert_allclose(ekf._F, F, atol=1e-12)
    # and its nominal attitude turned by ω̂Δt in the body frame: R ← R·Exp(ω̂Δt)
    np.testing.assert_allclose(quat_to_dcm(np.array(ekf.state.q)), exp_so3((w - bias) * dt), atol=1e-12)
