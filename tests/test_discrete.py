"""kfkit.discrete against independent oracles: scipy's cont2discrete for the zero-order hold, numerical
integration of Van Loan's integral, and a Monte Carlo of the continuous-time model itself."""

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm
from scipy.signal import cont2discrete

from kfkit.discrete import angle_bias_process_noise, discretize

ANGLE_BIAS_A = np.array([[0.0, -1.0], [0.0, 0.0]])  # θ̇ = ω_m − b − n_g, ḃ = n_b


def test_discretize_matches_cont2discrete_and_the_noise_integral():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    Qc = np.diag(rng.uniform(0.1, 2.0, 3))
    Ad, Bd, Qd = discretize(A, B, 0.05, Qc)
    want_Ad, want_Bd, *_ = cont2discrete((A, B, np.eye(3), np.zeros((3, 2))), 0.05, method="zoh")
    np.testing.assert_allclose(Ad, want_Ad, atol=1e-12)
    np.testing.assert_allclose(Bd, want_Bd, atol=1e-12)
    integral, _ = quad_vec(lambda t: expm(A * t) @ Qc @ expm(A * t).T, 0.0, 0.05, epsabs=1e-14)
    np.testing.assert_allclose(Qd, integral, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("N, K, dt", [(8.7e-5, 2e-5, 0.01), (1e-3, 1e-4, 0.1), (2e-3, 0.0, 0.0096)])
def test_angle_bias_noise_is_van_loans_integral(N, K, dt):
    Qc = np.diag([N**2, K**2])
    integral, _ = quad_vec(lambda t: expm(ANGLE_BIAS_A * t) @ Qc @ expm(ANGLE_BIAS_A * t).T, 0.0, dt, epsabs=1e-20)
    np.testing.assert_allclose(angle_bias_process_noise(N, K, dt), integral, rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(
        angle_bias_process_noise(N, K, dt), discretize(ANGLE_BIAS_A, np.zeros(2), dt, Qc)[2], rtol=1e-9, atol=1e-22
    )


def test_angle_bias_noise_is_what_the_continuous_model_does():
    """Run the continuous model over one step in 400 sub-steps, 40,000 times, and compare the spread of the
    angle and bias errors with Qd (each entry within 5 σ of its sampling error)."""
    rng = np.random.default_rng(1)
    N, K, dt, paths, sub = 1e-3, 5e-3, 0.5, 40000, 400
    h = dt / sub
    theta, bias = np.zeros(paths), np.zeros(paths)
    for _ in range(sub):
        theta += -bias * h - N * np.sqrt(h) * rng.normal(size=paths)
        bias += K * np.sqrt(h) * rng.normal(size=paths)
    sample = np.cov(np.vstack([theta, bias]))
    Q = angle_bias_process_noise(N, K, dt)
    se = np.sqrt((Q**2 + np.outer(np.diag(Q), np.diag(Q))) / paths)  # standard error of a sample covariance
    assert np.all(np.abs(sample - Q) < 5 * se), (sample, Q)
    assert Q[0, 1] < 0  # a bias that grew during the step has turned the angle the other way
