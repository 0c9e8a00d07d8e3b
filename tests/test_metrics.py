"""Metrics, and filter consistency on a simulated linear-Gaussian system (chi-square bounds)."""

import numpy as np
import pytest
from scipy.stats import chi2

from kfkit import metrics
from kfkit.filters import KalmanFilter, roll_kf
from kfkit.metrics import angle_error, chi2_bounds, fraction_inside, nees, nis, rmse


def test_rmse_and_nan_rows():
    assert rmse([1.0, 2.0, 3.0], [1.0, 2.0, 5.0]) == pytest.approx(np.sqrt(4 / 3))
    assert rmse([1.0, np.nan, 3.0], [0.0, 0.0, 3.0]) == pytest.approx(np.sqrt(0.5))


def test_angle_error_wraps():
    assert angle_error(np.radians(179), np.radians(-179)) == pytest.approx(np.radians(-2))
    assert angle_error(0.1, 0.1 + 4 * np.pi) == pytest.approx(0.0, abs=1e-12)


def test_nees_against_explicit_inverse():
    rng = np.random.default_rng(0)
    e = rng.normal(size=(50, 3))
    L = rng.normal(size=(50, 3, 3))
    P = L @ np.swapaxes(L, 1, 2) + np.eye(3)
    expected = [ei @ np.linalg.inv(Pi) @ ei for ei, Pi in zip(e, P)]
    np.testing.assert_allclose(nees(e, P), expected, rtol=1e-10)
    np.testing.assert_allclose(nis(np.array([2.0, -1.0]), np.array([4.0, 0.5])), [1.0, 2.0])


def test_chi2_bounds_match_textbook_values():
    # Bar-Shalom et al., single run, 2 dof, 95 %: [0.05, 7.38]
    lo, hi = chi2_bounds(2, 1)
    assert (lo, hi) == pytest.approx((0.0506, 7.3778), abs=1e-4)
    lo, hi = chi2_bounds(1, 100)
    assert (lo * 100, hi * 100) == pytest.approx((chi2.ppf(0.025, 100), chi2.ppf(0.975, 100)))


def simulate_linear_gaussian(rng, N):
    """A constant-velocity target with position measurements; returns the model and one run."""
    dt = 0.1
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = 0.05 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.25]])
    x = np.zeros(2)
    xs, zs = [], []
    Lq = np.linalg.cholesky(Q)
    for _ in range(N):
        x = F @ x + Lq @ rng.normal(size=2)
        xs.append(x)
        zs.append(H @ x + np.sqrt(R[0, 0]) * rng.normal(size=1))
    return F, H, Q, R, np.array(xs), np.array(zs)


@pytest.mark.slow
def test_consistent_filter_has_nees_inside_chi2_bounds_over_monte_carlo_runs():
    # Errors are correlated in time, so NEES is averaged over independent runs (Bar-Shalom §5.4).
    rng = np.random.default_rng(42)
    runs, final_nees = 300, []
    for _ in range(runs):
        F, H, Q, R, xs, zs = simulate_linear_gaussian(rng, 60)
        run = KalmanFilter(F, H, Q, R, np.zeros(2), np.eye(2) * 1e-12).run(zs)
        final_nees.append(nees(run.x[-1:] - xs[-1:], run.P[-1:])[0])
    lo, hi = chi2_bounds(2, runs)
    assert lo <= np.mean(final_nees) <= hi


def test_consistent_filter_has_white_innovations_inside_chi2_bounds():
    # Innovations of an optimal filter are white, so one long run gives N independent NIS values.
    F, H, Q, R, xs, zs = simulate_linear_gaussian(np.random.default_rng(41), 4000)
    run = KalmanFilter(F, H, Q, R, np.zeros(2), np.eye(2) * 1e-12).run(zs)
    lo, hi = chi2_bounds(1, len(zs))
    assert lo <= nis(run.y, run.S).mean() <= hi
    assert fraction_inside(nis(run.y, run.S), 1) == pytest.approx(0.95, abs=0.02)


def test_mistuned_filter_fails_the_nis_test():
    F, H, Q, R, xs, zs = simulate_linear_gaussian(np.random.default_rng(43), 4000)
    run = KalmanFilter(F, H, Q, R * 25.0, np.zeros(2), np.eye(2) * 1e-12).run(zs)  # R 25× too large
    lo, _ = chi2_bounds(1, len(zs))
    assert nis(run.y, run.S).mean() < lo


def test_scalar_roll_filter_is_consistent_on_its_own_model():
    rng = np.random.default_rng(5)
    dt, q, r, runs, N = 0.01, 1e-5, 1e-3, 300, 200
    final_nees, all_nis = [], []
    for _ in range(runs):
        omega = rng.normal(0, 1.0, N)
        truth = np.cumsum(omega * dt + rng.normal(0, np.sqrt(q), N))
        z = truth + rng.normal(0, np.sqrt(r), N)
        run = roll_kf(omega, z, dt, q, r, x0=0.0, P0=1e-12)
        final_nees.append(nees(run.x[-1:] - truth[-1:], run.P[-1:])[0])
        all_nis.append(nis(run.y, run.S))
    lo, hi = chi2_bounds(1, runs)
    assert lo <= np.mean(final_nees) <= hi
    lo, hi = chi2_bounds(1, runs * N)
    assert lo <= np.mean(all_nis) <= hi


def test_angle_rmse_deg_wraps_ignores_nan_and_reports_degrees():
    est = np.radians([179.0, 10.0, 0.0])
    truth = np.radians([-179.0, 12.0, np.nan])
    assert metrics.angle_rmse_deg(est, truth) == pytest.approx(2.0)  # 179° vs −179° is 2° off, not 358°
    both = np.column_stack([est, est])
    np.testing.assert_allclose(metrics.angle_rmse_deg(both, np.column_stack([truth, truth])), [2.0, 2.0])
