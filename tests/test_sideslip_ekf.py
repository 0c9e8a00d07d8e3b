"""kfkit.filters.sideslip_ekf: the saturating-tyre EKF against independent oracles.

Oracles: the linear KF (the EKF with C·α tyres is that filter), finite differences (tyre slope),
scipy's expm (the closed-form 2×2 matrix functions), filterpy's UKF on the same model, a simulated drive of
another car into the tyres' nonlinear range (truth known), and the real race-track log (measured β).
"""

import math
import os
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from scipy.linalg import expm

from kfkit import datasets
from kfkit import vehicle as V
from kfkit.filters import SideslipEKF, SideslipEKFSettings, estimate_sideslip
from kfkit.filters.sideslip_ekf import EXP, EXP_HALF, PHI1, matrix_functions_2x2
from kfkit.metrics import rmse
from kfkit.readers import load_vehicle_csv

SIGNALS = ("t", "delta", "yaw_rate", "ay", "vx")
CAR = V.BicycleParams()
# another car (a light hatchback, rear-heavy stiffness) than the bundled drives' one
OTHER = V.BicycleParams(m=1150.0, Iz=1850.0, a=1.05, b=1.45, Cf=110_000.0, Cr=130_000.0, mu=0.9)
SHARED = (
    Path(os.environ.get("KFKIT_SHARED", Path(__file__).resolve().parents[2] / "shared"))
    / "data/racetrack/racetrack_first_half.csv"
)


class LinearTyre:
    """F = C·α: with these the EKF is the linear KF."""

    def __init__(self, stiffness):
        self.stiffness = stiffness

    def force(self, alpha):
        return self.stiffness * alpha

    def slope(self, alpha):
        return self.stiffness


def beta_rmse_deg(beta, truth):
    return math.degrees(rmse(beta[5:], truth[5:]))


@pytest.mark.parametrize("alpha", np.radians([-12.0, -4.0, -0.5, 0.0, 1.0, 3.0, 7.0, 15.0]))
def test_tyre_slope_is_the_derivative_of_the_force(alpha):
    for tyre in V.axle_tyres(CAR):
        h = 1e-7
        assert tyre.slope(alpha) == pytest.approx(
            (tyre.force(alpha + h) - tyre.force(alpha - h)) / (2 * h), rel=1e-6, abs=1e-3
        )
    front = V.axle_tyres(CAR)[0]
    assert front.slope(0.0) == pytest.approx(CAR.Cf)  # the initial slope is the cornering stiffness


@pytest.mark.parametrize(
    "M",
    [
        [[-3.0, -1.0], [2.0, -4.0]],  # complex eigenvalues (a yaw oscillation)
        [[-5.0, 0.3], [0.1, -1.0]],  # real, distinct
        [[-2.0, 1.0], [0.0, -2.0]],  # repeated, defective
        [[0.0, 0.0], [0.0, 0.0]],
    ],
)
def test_closed_form_matrix_functions_match_scipy(M):
    M = np.array(M) * 0.05
    (a1, b1), (a2, b2), (a3, b3) = matrix_functions_2x2(M, EXP, EXP_HALF, PHI1)
    np.testing.assert_allclose(a1 * np.eye(2) + b1 * M, expm(M), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(a2 * np.eye(2) + b2 * M, expm(M / 2), rtol=1e-10, atol=1e-14)
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2] = M, [0.7, -1.3]  # φ₁(M)·v is expm's top-right column of [[M, v], [0, 0]]
    np.testing.assert_allclose((a3 * np.eye(2) + b3 * M) @ [0.7, -1.3], expm(aug)[:2, 2], rtol=1e-9, atol=1e-14)


def test_with_linear_tyres_it_is_the_linear_kf():
    rec = datasets.load("06_lane_change")
    sig = [rec[c] for c in SIGNALS]
    ekf = SideslipEKF(
        0.01, CAR, tyres=(LinearTyre(CAR.Cf), LinearTyre(CAR.Cr)), accel_noise=0.05, stiffness_std=0.0
    ).run(*sig)
    kf = estimate_sideslip(*sig, CAR, model=V.linear_model, vx_step=1e-4)
    np.testing.assert_allclose(ekf.x, kf.x, atol=1e-7)
    np.testing.assert_allclose(ekf.P, kf.P, rtol=1e-5, atol=1e-14)


def ukf_sideslip(rec, params, settings=SideslipEKFSettings()):
    """filterpy's UKF on the same continuous model (RK4 over the sample) and the same R (model-error term included)."""
    front, rear = V.axle_tyres(params)
    m, Iz, a, b = params.m, params.Iz, params.a, params.b
    dt = float(np.median(np.diff(rec.t)))

    def forces(x, delta, vx):
        return front.force(delta - x[0] - a * x[1] / vx), rear.force(-x[0] + b * x[1] / vx)

    def f(x, delta, vx):
        ff, fr = forces(x, delta, vx)
        return np.array([(ff + fr) / (m * vx) - x[1], (a * ff - b * fr) / Iz])

    def fx(x, dt, delta, vx):
        h = dt / 4
        for _ in range(4):
            k1 = f(x, delta, vx)
            k2 = f(x + h / 2 * k1, delta, vx)
            k3 = f(x + h / 2 * k2, delta, vx)
            k4 = f(x + h * k3, delta, vx)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def hx(x, delta, vx):
        ff, fr = forces(x, delta, vx)
        return np.array([x[1], (ff + fr) / m])

    ukf = UnscentedKalmanFilter(2, 2, dt, hx, fx, MerweScaledSigmaPoints(2, alpha=0.1, beta=2.0, kappa=0.0))
    ukf.x, ukf.P = np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
    ukf.Q = np.diag([settings.q_beta, settings.q_r]) * dt
    beta = np.empty(len(rec))
    for k in range(len(rec)):
        d, v = rec["delta"][k], rec["vx"][k]
        ukf.predict(delta=rec["delta"][k - 1] if k else d, vx=v)
        ff, fr = forces(ukf.x, d, v)
        ukf.R = np.diag(
            [settings.gyro_noise**2, settings.accel_noise**2 + (settings.stiffness_std / m) ** 2 * (ff**2 + fr**2)]
        )
        ukf.update(np.array([rec["yaw_rate"][k], rec["ay"][k]]), delta=d, vx=v)
        beta[k] = ukf.x[0]
    return beta


def hard_slalom(params=OTHER, seed=5):
    """A slalom of another car at 70 km/h into the tyres' nonlinear range (linear-model a_y 7 m/s²)."""
    drive = V.slalom(70.0, cone_spacing=25.0, cones=8, peak_ay=7.0, params=params)
    return V.simulate_drive(drive, params, seed=seed)


@pytest.mark.slow
def test_agrees_with_filterpys_ukf_on_the_same_model():
    rec = hard_slalom()
    ekf = estimate_sideslip(*(rec[c] for c in SIGNALS), OTHER).beta
    ukf = ukf_sideslip(rec, OTHER)
    truth = rec["true_beta"]
    assert np.max(np.abs(ekf - ukf)) < 0.1 * np.max(np.abs(truth))  # two approximations of one Bayes filter
    assert beta_rmse_deg(ekf, truth) < 1.2 * beta_rmse_deg(ukf, truth)


def test_another_car_beyond_the_linear_range_beats_the_linear_kf():
    rec = hard_slalom()
    sig, truth = [rec[c] for c in SIGNALS], rec["true_beta"]
    peak_ay = np.max(np.abs(rec["ay"]))
    assert peak_ay > 0.6 * OTHER.mu * 9.80665  # the drive does leave the linear range
    ekf = beta_rmse_deg(estimate_sideslip(*sig, OTHER).beta, truth)
    kf = beta_rmse_deg(estimate_sideslip(*sig, OTHER, model=V.linear_model).beta, truth)
    assert ekf < 0.3 * kf and ekf < 0.1 * math.degrees(np.max(np.abs(truth)))  # 5x better, a tenth of the peak β


@pytest.mark.parametrize("name", ["06_slalom_20kmh", "06_slalom_80kmh", "06_lane_change"])
def test_bundled_simulated_drives_keep_their_accuracy(name):
    rec = datasets.load(name)
    assert beta_rmse_deg(estimate_sideslip(*(rec[c] for c in SIGNALS), CAR).beta, rec["true_beta"]) <= 0.03


RACE_CAR = dict(m=982.0, Iz=982.0 / 12 * (1.7**2 + 4.09**2), a=1.33, b=1.07, Cf=70_000.0, Cr=120_000.0)  # published


def check_race_track(rec):
    """Default settings, the published parameters and the friction the log's a_y shows (no β): under 0.35° and
    under 0.65 of the open-loop linear model's error."""
    car = V.BicycleParams(**RACE_CAR, mu=V.peak_friction(rec.t, rec["ay"]))
    sig, truth = [rec[c] for c in SIGNALS], rec["true_beta"]
    ekf = beta_rmse_deg(estimate_sideslip(*sig, car).beta, truth)
    open_loop = beta_rmse_deg(estimate_sideslip(*sig, car, model=V.linear_model, accel_noise=1e6).beta, truth)
    assert ekf <= 0.35 and ekf < 0.65 * open_loop


@pytest.mark.slow
def test_bundled_race_track_log():
    check_race_track(datasets.load("06_racetrack"))


@pytest.mark.slow
@pytest.mark.skipif(not SHARED.exists(), reason=f"no shared race-track file at {SHARED}")
def test_shared_race_track_file():
    check_race_track(
        load_vehicle_csv(
            SHARED,
            {
                "t": "t_s",
                "delta": "steer_road_wheel_rad",
                "yaw_rate": "yaw_rate_rad_s",
                "ay": "ay_cg_m_s2",
                "vx": "vx_m_s",
                "true_beta": "beta_true_rad",
            },
        )
    )


def test_stop_and_restart_uses_the_low_speed_guard():
    t = np.arange(0.0, 12.0, 0.01)
    vx = np.clip(np.abs(t - 6.0) * 3.0 - 3.0, 0.0, None)
    delta = 0.03 * np.sin(2 * np.pi * 0.3 * t)
    rng = np.random.default_rng(3)
    res = estimate_sideslip(t, delta, rng.normal(0, 0.003, t.size), rng.normal(0, 0.05, t.size), vx, CAR)
    low = vx < 2.0
    np.testing.assert_array_equal(res.low_speed, low)
    np.testing.assert_allclose(res.beta[low], CAR.b / CAR.wheelbase * delta[low], atol=1e-12)
    assert np.all(np.isfinite(res.x)) and np.all(np.linalg.eigvalsh(res.P) > 0)


def test_settings_are_validated_and_named():
    with pytest.raises(ValueError, match="SideslipEKFSettings: accel_noise must be a positive number, got -0.5"):
        SideslipEKFSettings(accel_noise=-0.5)
    assert SideslipEKFSettings(stiffness_std=0.0).stiffness_std == 0.0
    with pytest.raises(TypeError, match="SideslipEKF: unknown setting q_yaw; SideslipEKFSettings has q_beta"):
        SideslipEKF(0.01, CAR, q_yaw=1.0)
