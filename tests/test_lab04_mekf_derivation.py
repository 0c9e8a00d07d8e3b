"""Lab 04's derivation of the MEKF against the physics and the code.

Oracle: rotations composed by scipy (``Rotation.from_rotvec``), independent of kfkit's quaternion code: the
derivation's error δθ is a small rotation in the NED frame, R_true = Exp(δθ)·R, so that δθ_N, δθ_E are the tilt
error and δθ_D the heading error.
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
def test_a_reference_vector_seen_in_ned_moves_by_the_cross_product_with_the_error(seed):
    # A reference vector v_n measured in the body, turned into NED with the estimate: R (Exp(δθ) R)ᵀ v_n, whose
    # Jacobian at δθ = 0 is [v_n×] — for gravity's reaction −g e_D the rows g e_E, −g e_N and 0 (the
    # accelerometer sees the tilt and not the heading), whatever the attitude R.
    rng = np.random.default_rng(seed)
    R, v_n = Rotation.random(random_state=seed).as_matrix(), rng.normal(0.0, 10.0, 3)
    eps = 1e-6

    def seen(d):
        return R @ (exp_so3(d) @ R).T @ v_n

    fd = np.column_stack([(seen(eps * e) - seen(-eps * e)) / (2 * eps) for e in np.eye(3)])
    np.testing.assert_allclose(fd, skew(v_n), atol=1e-6)
    np.testing.assert_allclose(skew([0.0, 0.0, -G]), [[0.0, G, 0.0], [-G, 0.0, 0.0], [0.0, 0.0, 0.0]])


@pytest.mark.parametrize("seed", range(5))
def test_one_step_of_the_error_is_F_times_the_error(seed):
    # nominal R turned by ω̂Δt, the truth Exp(δθ)·R by (ω̂ − δb)Δt: the new error is δθ − R_next δb Δt (first order)
    rng = np.random.default_rng(seed)
    R, dt = Rotation.random(random_state=seed).as_matrix(), 0.01
    w_hat = rng.normal(0.0, 3.0, 3)
    d_theta, d_b = rng.normal(0.0, 1e-4, 3), rng.normal(0.0, 1e-4, 3)
    R_next = R @ exp_so3(w_hat * dt)
    true_next = exp_so3(d_theta) @ R @ exp_so3((w_hat - d_b) * dt)
    got = log_so3(true_next @ R_next.T)
    want = d_theta - R_next @ d_b * dt
    np.testing.assert_allclose(got, want, atol=1e-7)  # second-order terms: |δ|² ~ 1e-8


def test_the_kit_mekf_propagates_with_the_derived_F():
    # MultiplicativeEKF's prediction matrix is the derivation's F = [[I, −R Δt], [0, I]], ω̂ = ω − b
    rate, bias, w = 100.0, np.array([0.01, -0.02, 0.015]), np.array([1.0, -2.0, 0.5])
    ekf = MultiplicativeEKF(rate_hz=rate, field_n=np.array([20.0, 0.0, 45.0]), x0=np.r_[1.0, 0.0, 0.0, 0.0, bias])
    ekf._begin(np.array([w]), np.array([[0.0, 0.0, -G]]), None)
    P = ekf.state.P
    ekf._predict(w.tolist())
    dt = 1.0 / rate
    R = exp_so3((w - bias) * dt)  # the nominal attitude turned by ω̂Δt in the body frame: R ← R·Exp(ω̂Δt)
    np.testing.assert_allclose(quat_to_dcm(np.array(ekf.state.q)), R, atol=1e-12)
    F = np.block([[np.eye(3), -dt * R], [np.zeros((3, 3)), np.eye(3)]])
    st = ekf.settings  # Q = diag(σ_g² Δt² I, σ_bw² Δt I), σ_g = gyro_density·√rate
    Q = np.diag([st.gyro_density**2 * rate * dt**2] * 3 + [st.gyro_bias_rw**2 * dt] * 3)
    np.testing.assert_allclose(ekf.state.P, F @ P @ F.T + Q, rtol=1e-12, atol=1e-15)
