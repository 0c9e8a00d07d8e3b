"""kfkit.filters against independent oracles: filterpy's KalmanFilter and scipy's DARE."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF
from scipy.linalg import solve_discrete_are

from kfkit.filters import (
    KalmanFilter,
    RollKF,
    RollKFSettings,
    Step,
    roll_kf,
    roll_kf_predict,
    roll_kf_steady_state,
    roll_kf_update,
)


def random_stable_system(rng, n, m, with_input):
    A = rng.normal(size=(n, n))
    F = 0.95 * A / max(1.0, np.max(np.abs(np.linalg.eigvals(A))))  # spectral radius < 1
    H = rng.normal(size=(m, n))
    L = rng.normal(size=(n, n))
    Q = L @ L.T * 0.1 + 1e-3 * np.eye(n)
    M = rng.normal(size=(m, m))
    R = M @ M.T * 0.5 + 1e-2 * np.eye(m)
    B = rng.normal(size=(n, 1)) if with_input else None
    return F, H, Q, R, B


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("with_input", [False, True])
def test_kalman_filter_matches_filterpy(seed, with_input):
    rng = np.random.default_rng(seed)
    n, m, N = rng.integers(1, 5), rng.integers(1, 4), 80
    F, H, Q, R, B = random_stable_system(rng, n, m, with_input)
    x0, P0 = rng.normal(size=n), np.eye(n) * 2.0
    zs = rng.normal(size=(N, m))
    us = rng.normal(size=(N, 1)) if with_input else None

    ours = KalmanFilter(F, H, Q, R, x0, P0, B=B)
    ref = FilterpyKF(dim_x=n, dim_z=m, dim_u=1 if with_input else 0)
    ref.F, ref.H, ref.Q, ref.R, ref.x, ref.P = F, H, Q, R, x0.copy(), P0.copy()
    if with_input:
        ref.B = B
    run = KalmanFilter(F, H, Q, R, x0, P0, B=B).run(zs, us)
    for k in range(N):
        ours.predict(None if us is None else us[k])
        ref.predict(u=None if us is None else us[k])
        np.testing.assert_allclose(ours.P, ref.P, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(run.x_prior[k], ref.x_prior, rtol=1e-9, atol=1e-12)  # what an RTS smoother needs
        np.testing.assert_allclose(run.P_prior[k], ref.P_prior, rtol=1e-9, atol=1e-12)
        ours.update(zs[k])
        ref.update(zs[k])
        np.testing.assert_allclose(ours.x, ref.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ours.P, ref.P, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ours.y, ref.y, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ours.S, ref.S, rtol=1e-9, atol=1e-12)


def test_run_records_history_like_stepping():
    rng = np.random.default_rng(7)
    F, H, Q, R, B = random_stable_system(rng, 2, 1, True)
    zs, us = rng.normal(size=(30, 1)), rng.normal(size=(30, 1))
    run = KalmanFilter(F, H, Q, R, [0, 0], np.eye(2), B=B).run(zs, us)
    ref = FilterpyKF(dim_x=2, dim_z=1, dim_u=1)
    ref.F, ref.H, ref.Q, ref.R, ref.B, ref.x, ref.P = F, H, Q, R, B, np.zeros(2), np.eye(2)
    for k in range(30):
        ref.predict(u=us[k])
        ref.update(zs[k])
    np.testing.assert_allclose(run.x[-1], ref.x, rtol=1e-9)
    assert run.x.shape == (30, 2) and run.P.shape == (30, 2, 2) and run.y.shape == (30, 1) and run.S.shape == (30, 1, 1)


def test_step_returns_this_steps_values_and_run_is_a_loop_of_steps():
    """Step(x, P, y, S) against filterpy each step; the Steps kept in a list are not overwritten by
    later steps (no views into the filter); run from the same start gives the same rows."""
    rng = np.random.default_rng(8)
    F, H, Q, R, B = random_stable_system(rng, 3, 2, True)
    zs, us = rng.normal(size=(25, 2)), rng.normal(size=(25, 1))
    zs[4] = np.nan
    ours = KalmanFilter(F, H, Q, R, np.zeros(3), np.eye(3), B=B)
    ref = FilterpyKF(dim_x=3, dim_z=2, dim_u=1)
    ref.F, ref.H, ref.Q, ref.R, ref.B, ref.x, ref.P = F, H, Q, R, B, np.zeros(3), np.eye(3)
    steps, xs = [], []
    for k in range(25):
        step = ours.step(zs[k], us[k])
        assert isinstance(step, Step)
        ref.predict(u=us[k])
        if k != 4:
            ref.update(zs[k])
            np.testing.assert_allclose(step.y, ref.y, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(step.S, ref.S, rtol=1e-9, atol=1e-12)
        else:
            assert np.isnan(step.y).all() and np.isnan(step.S).all()
        np.testing.assert_allclose(step.x, ref.x, rtol=1e-9, atol=1e-12)
        steps.append(step)
        xs.append(ref.x.copy())
    np.testing.assert_allclose([s.x for s in steps], xs, rtol=1e-9, atol=1e-12)
    run = KalmanFilter(F, H, Q, R, np.zeros(3), np.eye(3), B=B).run(zs, us)
    for name in "xPyS":
        np.testing.assert_array_equal(getattr(run, name), np.array([getattr(s, name) for s in steps]))


def test_nan_measurement_skips_the_update():
    kf = KalmanFilter([[1.0]], [[1.0]], [[0.1]], [[1.0]], [0.0], [[1.0]])
    kf.predict()
    kf.update([np.nan])
    assert kf.x[0] == 0.0 and kf.P[0, 0] == pytest.approx(1.1)
    assert np.isnan(kf.y).all() and np.isnan(kf.S).all()


def test_joseph_form_keeps_covariance_symmetric_positive():
    rng = np.random.default_rng(3)
    F, H, Q, R, _ = random_stable_system(rng, 4, 2, False)
    R = R * 1e-8  # near-perfect measurements stress the covariance update
    run = KalmanFilter(F, H, Q, R, np.zeros(4), np.eye(4) * 1e4).run(rng.normal(size=(200, 2)))
    for P in run.P[::20]:
        np.testing.assert_allclose(P, P.T, atol=1e-12)
        assert np.linalg.eigvalsh(P).min() > -1e-12


def test_shape_errors_name_the_matrix():
    with pytest.raises(ValueError, match="H has shape"):
        KalmanFilter(np.eye(2), np.ones((1, 3)), np.eye(2), [[1.0]], [0, 0], np.eye(2))
    kf = KalmanFilter(np.eye(2), np.ones((1, 2)), np.eye(2), [[1.0]], [0, 0], np.eye(2))
    with pytest.raises(ValueError, match="no B matrix"):
        kf.predict(u=[1.0])


def test_roll_kf_matches_filterpy_scalar_filter():
    rng = np.random.default_rng(11)
    N, dt, q, r = 500, 0.01, 1e-5, 4e-4
    omega, z = rng.normal(0, 0.5, N), rng.normal(0, 0.3, N)
    z[::37] = np.nan  # gated samples
    run = roll_kf(omega, z, dt, q, r, x0=0.1, P0=0.5)
    ref = FilterpyKF(dim_x=1, dim_z=1, dim_u=1)
    ref.F, ref.B, ref.H, ref.Q, ref.R = np.eye(1), np.array([[dt]]), np.eye(1), np.array([[q]]), np.array([[r]])
    ref.x, ref.P = np.array([0.1]), np.array([[0.5]])
    for k in range(N):
        ref.predict(u=np.array([omega[k]]))
        assert (run.x_prior[k], run.P_prior[k]) == pytest.approx(
            (ref.x_prior[0], ref.P_prior[0, 0]), rel=1e-9, abs=1e-12
        )
        if not np.isnan(z[k]):
            ref.update(np.array([z[k]]))
            assert run.y[k] == pytest.approx(ref.y[0], rel=1e-9, abs=1e-12)
            assert run.S[k] == pytest.approx(ref.S[0, 0], rel=1e-9)
        else:
            assert np.isnan(run.y[k]) and np.isnan(run.S[k])
        assert run.x[k] == pytest.approx(ref.x[0], rel=1e-9, abs=1e-12)
        assert run.P[k] == pytest.approx(ref.P[0, 0], rel=1e-9)


def test_roll_kf_step_functions_agree_with_the_general_filter():
    kf = KalmanFilter([[1.0]], [[1.0]], [[2e-4]], [[3e-3]], [0.2], [[0.05]], B=[[0.01]])
    x, P = roll_kf_predict(0.2, 0.05, omega=1.5, dt=0.01, q=2e-4)
    kf.predict([1.5])
    assert (x, P) == pytest.approx((kf.x[0], kf.P[0, 0]))
    x, P, y, S = roll_kf_update(x, P, z=0.3, r=3e-3)
    kf.update([0.3])
    assert (x, P, y, S) == pytest.approx((kf.x[0], kf.P[0, 0], kf.y[0], kf.S[0, 0]))


@pytest.mark.parametrize("q,r", [(1e-6, 1e-3), (1e-4, 1e-4), (1e-2, 1e-5)])
def test_steady_state_gain_matches_the_riccati_equation(q, r):
    P_prior, K = roll_kf_steady_state(q, r)
    dare = solve_discrete_are(np.eye(1), np.eye(1), np.array([[q]]), np.array([[r]]))[0, 0]
    assert P_prior == pytest.approx(dare, rel=1e-9)
    run = roll_kf(np.zeros(5000), np.zeros(5000), 0.01, q, r, x0=0.0, P0=1.0)
    assert run.P[-1] == pytest.approx((1 - K) * P_prior, rel=1e-6)


def test_roll_kf_class_is_the_function_form_step_by_step():
    rng = np.random.default_rng(12)
    omega, z = rng.normal(0, 0.5, 300), rng.normal(0, 0.3, 300)
    z[::11] = np.nan
    run = RollKF(0.01, RollKFSettings(q_angle=1e-5, r=4e-4), x0=0.1, P0=0.5).run(omega, z)
    kf = RollKF(0.01, q_angle=1e-5, r=4e-4, x0=0.1, P0=0.5)
    x, P = 0.1, 0.5
    for k in range(300):
        step = kf.step(omega[k], z[k])
        x, P = roll_kf_predict(x, P, omega[k], 0.01, 1e-5)
        if not np.isnan(z[k]):
            x, P, y, S = roll_kf_update(x, P, z[k], 4e-4)
            assert (step.y, step.S) == (y, S) == (run.y[k], run.S[k])
        else:
            assert np.isnan(step.y) and np.isnan(step.S) and np.isnan(run.y[k])
        assert (step.x, step.P) == (x, P) == (run.x[k], run.P[k])


@pytest.mark.parametrize(
    "make, error, match",
    [
        (lambda: RollKFSettings(q_angle=0.0), ValueError, "RollKFSettings: q_angle must be a positive number, got 0.0"),
        (lambda: RollKFSettings(r=float("nan")), ValueError, "r must be a positive number, got nan"),
        (lambda: RollKFSettings(r=True), ValueError, "RollKFSettings: r must be a positive number, got True"),
        (lambda: RollKF(-0.01), ValueError, "RollKF: dt must be a positive number, got -0.01"),
        (lambda: RollKF(rate_hz=0), ValueError, "RollKF: rate_hz must be a positive number, got 0"),
        (
            lambda: RollKF(100.0),
            ValueError,
            "RollKF: dt = 100 s is longer than 1 s; if 100 is a sample rate, pass rate_hz=100",
        ),
        (
            lambda: RollKF(),
            TypeError,
            r"RollKF: give the sample period dt \(s\) or the sample rate rate_hz \(Hz\), got neither",
        ),
        (lambda: RollKF(0.01, rate_hz=100), TypeError, "RollKF: give the sample period .* not both"),
        (lambda: RollKF(0.01, qq=1e-6), TypeError, "RollKF: unknown setting qq; RollKFSettings has q_angle, r"),
        (lambda: RollKF(0.01, {"q_angle": 1e-6}), TypeError, "RollKF: settings must be a RollKFSettings, got dict"),
        (lambda: RollKF(0.01, x0=[0.1, 0.2]), ValueError, r"RollKF: x0 must have shape \(\), got \(2,\)"),
    ],
)
def test_bad_roll_settings_are_named(make, error, match):
    with pytest.raises(error, match=match):
        make()
