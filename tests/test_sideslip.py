"""kfkit.filters.sideslip: the bicycle-model KF against filterpy, NEES bounds, bundled drives, bad input.

The KF runs as ``estimate_sideslip(..., model=linear_model)`` (:func:`estimate_kf`); the default
saturating-tyre EKF has its own tests (test_sideslip_ekf.py)."""

import math
import warnings

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from kfkit import datasets, discrete
from kfkit import vehicle as V
from kfkit.filters import (
    SideslipKF,
    SideslipKFSettings,
    SideslipRun,
    Step,
    copied_kinematic_kf,
    estimate_sideslip,
    kinematic_sideslip,
    sideslip_step,
)
from kfkit.metrics import chi2_bounds, nees, rmse

CAR = V.BicycleParams()
SIGNALS = ("t", "delta", "yaw_rate", "ay", "vx")


def estimate_kf(*args, **kwargs):
    """estimate_sideslip with lab 06's linear KF."""
    return estimate_sideslip(*args, model=V.linear_model, **kwargs)


def linear_drive(vx=15.0, n=600, dt=0.01, q=(1e-4, 1e-3), r=(0.003, 0.05), seed=0):
    """Data simulated from the discrete linear model itself (the filter's own assumptions)."""
    rng = np.random.default_rng(seed)
    A, B, C, D = V.linear_model(CAR, vx)
    Ad, Bd, Qd = discrete.discretize(A, B, dt, np.diag(q))
    t = np.arange(n) * dt
    delta = 0.02 * np.sin(2 * np.pi * 0.5 * t) + 0.01 * np.sin(2 * np.pi * 1.3 * t)
    x = np.zeros(2)
    xs, zs = np.empty((n, 2)), np.empty((n, 2))
    Lq = np.linalg.cholesky(Qd)
    for k in range(n):
        x = Ad @ x + Bd[:, 0] * delta[k - 1 if k else 0] + Lq @ rng.standard_normal(2)
        xs[k] = x
        zs[k] = C @ x + D[:, 0] * delta[k] + np.asarray(r) * rng.standard_normal(2)
    return t, delta, zs, np.full(n, vx), xs


def test_matches_filterpy_on_the_linear_model():
    t, delta, zs, vx, _ = linear_drive()
    ours = estimate_kf(t, delta, zs[:, 0], zs[:, 1], vx, CAR)
    A, B, C, D = V.linear_model(CAR, 15.0)
    kf = FilterpyKF(dim_x=2, dim_z=2, dim_u=1)
    kf.F, kf.B, _ = discrete.discretize(A, B, 0.01, np.diag([1e-4, 1e-3]))
    kf.Q = discrete.discretize(A, B, 0.01, np.diag([1e-4, 1e-3]))[2]
    kf.H, kf.R = C, np.diag([0.003**2, 0.05**2])
    kf.x, kf.P = np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
    xs, Ps, priors = [], [], []
    for k in range(len(t)):
        kf.predict(u=np.array([delta[k - 1 if k else 0]]))
        priors.append((kf.x.copy(), kf.P.copy()))
        kf.update(zs[k] - D[:, 0] * delta[k])  # filterpy has no D: move D δ to the measurement side
        xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
    np.testing.assert_allclose(ours.x, np.array(xs), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(ours.P, np.array(Ps), rtol=1e-7, atol=1e-16)
    np.testing.assert_allclose(ours.x_prior, np.array([p[0] for p in priors]), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(ours.P_prior, np.array([p[1] for p in priors]), rtol=1e-7, atol=1e-16)


def test_nees_is_inside_chi_square_bounds_on_linear_model_data():
    runs = 25
    values = []
    for seed in range(runs):
        t, delta, zs, vx, xs = linear_drive(seed=seed, n=400)
        res = estimate_kf(t, delta, zs[:, 0], zs[:, 1], vx, CAR, x0=xs[0], P0=np.diag([1e-8, 1e-8]))
        values.append(np.mean(nees(res.x - xs, res.P)[50:]))
    lo, hi = chi2_bounds(2, runs)  # runs are independent; the time average only narrows each run's spread
    assert lo < np.mean(values) < hi


def test_bundled_slalom_beta_rmse_is_under_half_a_degree():
    rec = datasets.load("06_slalom_20kmh")
    res = estimate_kf(*(rec[c] for c in SIGNALS), CAR)
    assert np.degrees(rmse(res.beta, rec["true_beta"])) < 0.5
    np.testing.assert_allclose(res.vy, rec["vx"] * np.tan(res.beta))
    assert res.low_speed[0] and not res.low_speed[len(rec) // 2]


@pytest.mark.parametrize("name", ["06_slalom_80kmh", "06_lane_change"])
def test_correct_model_beats_the_copied_ones(name):
    rec = datasets.load(name)
    truth = rec["true_beta"]
    good = rmse(estimate_kf(*(rec[c] for c in SIGNALS), CAR).beta, truth)
    wrong = rmse(estimate_sideslip(*(rec[c] for c in SIGNALS), CAR, model=V.miscopied_linear_model).beta, truth)
    naive = rmse(copied_kinematic_kf(rec.t, rec["yaw_rate"], rec["ay"], rec["vx"])[1], truth)
    assert good < wrong / 3 and good < naive / 3


def test_bias_state_recovers_an_accelerometer_bias():
    d = V.slalom(80.0, cone_spacing=18.0, cones=30)
    rec = V.simulate_drive(d, seed=11, accel_bias=0.3)
    res = estimate_kf(*(rec[c] for c in SIGNALS), CAR, bias_ay=True)
    assert res.bias_ay[-1] == pytest.approx(0.3, abs=0.05)
    assert estimate_kf(*(rec[c] for c in SIGNALS), CAR).bias_ay is None


def test_kinematic_integration_drifts_by_bias_times_time():
    # 1 kHz: the truth holds δ over each sample, so a_y steps by (Cf/m)·Δδ at every sample, which the
    # trapezoid smooths: an O(dt) artefact of the simulation (1.7 mm/s here), not of the kinematics
    d = V.slalom(80.0, cone_spacing=18.0, cones=4, lead=1.0, rate_hz=1000.0)
    truth = V.simulate_nonlinear(CAR, d.t, d.delta, d.vx, substeps=1)
    exact, _ = kinematic_sideslip(d.t, truth["r"], truth["ay"], d.vx)
    assert np.max(np.abs(exact - truth["vy"])) < 0.02 * np.max(np.abs(truth["vy"]))  # no noise, no bias: exact
    biased, _ = kinematic_sideslip(d.t, truth["r"], truth["ay"] + 0.2, d.vx)
    np.testing.assert_allclose(biased - exact, 0.2 * d.t, atol=1e-9)


def test_low_speed_guard_stops_and_restarts_without_blowing_up():
    t = np.arange(0.0, 12.0, 0.01)
    vx = np.clip(np.abs(t - 6.0) * 3.0 - 3.0, 0.0, None)  # 15 m/s → stop (5–7 s) → 15 m/s
    delta = 0.03 * np.sin(2 * np.pi * 0.3 * t)
    rng = np.random.default_rng(3)
    yaw, ay = rng.normal(0, 0.003, t.size), rng.normal(0, 0.05, t.size)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = estimate_kf(t, delta, yaw, ay, vx, CAR)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))
    low = vx < 2.0
    np.testing.assert_array_equal(res.low_speed, low)
    np.testing.assert_allclose(res.beta[low], CAR.b / CAR.wheelbase * delta[low], atol=1e-12)
    assert np.all(np.isnan(res.y[low, 1])) and np.all(np.isfinite(res.y[~low]))
    assert np.all(np.linalg.eigvalsh(res.P) > 0)


def test_speed_bins_do_not_change_the_estimate():
    """The 20 km/h drive spends 6 s between 1 and 5.6 m/s, where 0.05 m/s bins matter most."""
    rec = datasets.load("06_slalom_20kmh")
    coarse = estimate_kf(*(rec[c] for c in SIGNALS), CAR)
    fine = estimate_kf(*(rec[c] for c in SIGNALS), CAR, vx_step=1e-4)
    assert np.max(np.abs(coarse.beta - fine.beta)) < math.radians(0.01)


def filterpy_reference(t, delta, yaw_rate, ay, vx, model_at):
    """filterpy's KalmanFilter with the matrices ``model_at(k, dt)`` → (Ad, Bd, Qd, C, D) of each step."""
    kf = FilterpyKF(dim_x=2, dim_z=2, dim_u=1)
    kf.R, kf.x, kf.P = np.diag([0.003**2, 0.05**2]), np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
    dt0 = float(np.median(np.diff(t)))
    beta = np.empty(len(t))
    for k in range(len(t)):
        kf.F, kf.B, kf.Q, kf.H, D = model_at(k, t[k] - t[k - 1] if k else dt0)
        kf.predict(u=np.array([delta[k - 1] if k else delta[0]]))
        kf.update(np.array([yaw_rate[k], ay[k]]) - D[:, 0] * delta[k])
        beta[k] = kf.x[0]
    return beta


def exact_model(vx):
    """The model discretised at each sample's own speed and interval (no bins)."""

    def model_at(k, dt):
        A, B, C, D = V.linear_model(CAR, vx[k])
        return discrete.discretize(A, B, dt, np.diag([1e-4, 1e-3])) + (C, D)

    return model_at


@pytest.mark.slow
def test_matches_filterpy_while_braking_and_with_jittery_timestamps():
    """Lane change braking 60 → 50 km/h, timestamps jittered by ±0.3 ms like a logger's: the binned model
    cache (speed and interval) gives what filterpy gives with the model recomputed at every sample."""
    rec = datasets.load("06_lane_change")
    t = rec.t + np.random.default_rng(8).uniform(-3e-4, 3e-4, len(rec))
    signals = (t, rec["delta"], rec["yaw_rate"], rec["ay"], rec["vx"])
    ours = estimate_kf(*signals, CAR)
    ref = filterpy_reference(*signals, exact_model(rec["vx"]))
    assert np.max(np.abs(ours.beta - ref)) < math.radians(0.002)
    assert rmse(ours.beta, rec["true_beta"]) < math.radians(0.05)


def test_low_speed_guard_hands_over_to_the_model_when_starting_from_a_crawl():
    """Truth from 0.5 m/s (the nonlinear model's lowest speed) up to 36 km/h while weaving: β tracked throughout."""
    t = np.arange(0.0, 12.0, 0.01)
    vx = 0.5 + 9.5 * np.clip(t / 6.0, 0.0, 1.0) ** 2
    drive = V.Drive(t, 0.06 * np.sin(2 * np.pi * 0.4 * t), vx, [], "pull away from a crawl while weaving")
    rec = V.simulate_drive(drive, seed=12)
    res = estimate_kf(*(rec[c] for c in SIGNALS), CAR)
    low = res.low_speed
    assert low[:100].all() and not low[-100:].any()
    err = np.abs(res.beta - rec["true_beta"])
    # below v_min: the kinematic β = bδ/L (up to 2° here), well within its stated σ; above: the model's estimate
    assert np.max(err[low]) < math.radians(0.15) and np.all(err[low] < 2 * np.sqrt(res.P[low, 0, 0]))
    handover = int(np.argmax(~low))
    assert np.max(err[handover + 50 :]) < math.radians(0.1)


def test_tuning_and_speed_bins_are_validated():
    d = good_inputs()
    with pytest.raises(ValueError, match="vx_step = 3 m/s is coarser than v_min = 2.0 m/s"):
        estimate_kf(**d, params=CAR, vx_step=3)
    with pytest.raises(ValueError, match="SideslipKFSettings: q_beta must be a positive number, got -0.001"):
        estimate_kf(**d, params=CAR, q_beta=-1e-3)


def good_inputs(n=50):
    t = np.arange(n) * 0.01
    return {"t": t, "delta": np.zeros(n), "yaw_rate": np.zeros(n), "ay": np.zeros(n), "vx": np.full(n, 10.0)}


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["ay"].__setitem__(7, np.nan), r"ay\[7\] is nan \(at t = 0.07 s\); 1 non-finite"),
        (lambda d: d.update(vx=d["vx"][:-1]), r"mismatched lengths: t 50, delta 50, yaw_rate 50, ay 50, vx 49"),
        (lambda d: d["vx"].__setitem__(3, -1.0), r"vx\[3\] = -1.0 m/s is negative"),
        (lambda d: d["t"].__setitem__(5, 0.02), r"t must increase; t\[5\] = 0.02 s after t\[4\] = 0.04 s"),
        (lambda d: d.update(delta=np.zeros((50, 1))), r"delta must be a 1-D array"),
        (lambda d: d.update({k: v[:1] for k, v in d.items()}), r"at least 2 samples, got 1"),
    ],
)
def test_bad_input_gives_a_clear_error(change, message):
    d = good_inputs()
    change(d)
    with pytest.raises(ValueError, match=message):
        estimate_sideslip(**d, params=CAR)


def test_zero_speed_everywhere_is_handled_by_the_guard_not_a_division():
    d = good_inputs()
    d["vx"][:] = 0.0
    res = estimate_sideslip(**d, params=CAR)
    assert res.low_speed.all() and np.all(res.beta == 0.0) and np.all(np.isfinite(res.P))


def test_one_step_with_the_bias_state_matches_filterpy():
    rng = np.random.default_rng(7)
    A, B, C, D = V.linear_model(CAR, 12.0)
    Ab, Bb, Cb = np.pad(A, ((0, 1), (0, 1))), np.vstack([B, [[0.0]]]), np.hstack([C, [[0.0], [1.0]]])
    Ad, Bd, Qd = discrete.discretize(Ab, Bb, 0.01, np.diag([1e-4, 1e-3, 1e-5]))
    L = rng.normal(0, 0.05, (3, 3))
    x, P, R = rng.normal(0, 0.05, 3), L @ L.T + 1e-4 * np.eye(3), np.diag([0.003**2, 0.05**2])
    z, d_prev, d = np.array([0.1, 2.0]), 0.02, 0.03
    got = sideslip_step(x, P, d_prev, z, d, Ad, Bd, Qd, Cb, D, R)
    kf = FilterpyKF(dim_x=3, dim_z=2, dim_u=1)
    kf.F, kf.B, kf.Q, kf.H, kf.R, kf.x, kf.P = Ad, Bd, Qd, Cb, R, x.copy(), P.copy()
    kf.predict(u=np.array([d_prev]))
    kf.update(z - D[:, 0] * d)
    np.testing.assert_allclose(got[0], kf.x, rtol=1e-10)
    np.testing.assert_allclose(got[1], kf.P, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(got[2], kf.y, rtol=1e-10)
    np.testing.assert_allclose(got[3], kf.S, rtol=1e-10)


@pytest.mark.slow
@pytest.mark.parametrize("bias_ay", [False, True])
def test_run_is_a_loop_of_steps_and_estimate_sideslip_is_run(bias_ay):
    """A drive that starts from rest (low-speed steps), with jittered sample intervals: stepping the
    filter by hand (dt from the timestamps, the first the nominal one) gives run()'s rows exactly."""
    rec = datasets.load("06_slalom_20kmh").head(6.0)
    t, delta, yaw, ay, vx = (rec[c] for c in SIGNALS)
    t = t + np.random.default_rng(1).uniform(-2e-4, 2e-4, len(t))
    dt0 = float(np.median(np.diff(t)))
    run = estimate_kf(t, delta, yaw, ay, vx, CAR, bias_ay=bias_ay)
    assert isinstance(run, SideslipRun) and run.low_speed.any() and not run.low_speed.all()
    kf = SideslipKF(dt0, CAR, SideslipKFSettings(bias_ay=bias_ay))
    steps = [kf.step(delta[k], yaw[k], ay[k], vx[k], t[k] - t[k - 1] if k else None) for k in range(len(t))]
    assert all(isinstance(s, Step) for s in steps)
    for name in "xPyS":
        np.testing.assert_array_equal(np.array([getattr(s, name) for s in steps]), getattr(run, name))
    assert np.isnan(run.y[run.low_speed, 1]).all() and np.isfinite(run.y[~run.low_speed]).all()


def test_run_properties_read_the_state():
    rec = datasets.load("06_slalom_80kmh").head(3.0)
    run = estimate_kf(*(rec[c] for c in SIGNALS), CAR, bias_ay=True)
    np.testing.assert_array_equal(run.beta, run.x[:, 0])
    np.testing.assert_array_equal(run.yaw_rate, run.x[:, 1])
    np.testing.assert_array_equal(run.bias_ay, run.x[:, 2])
    np.testing.assert_allclose(run.vy, rec["vx"] * np.tan(run.x[:, 0]), rtol=1e-15)


def test_unknown_or_misplaced_settings_are_named():
    with pytest.raises(TypeError, match="SideslipKF: unknown setting q_yaw; SideslipKFSettings has q_beta, q_r"):
        SideslipKF(0.01, CAR, q_yaw=1.0)
    with pytest.raises(TypeError, match="unknown setting qbeta"):
        estimate_sideslip(**good_inputs(), params=CAR, qbeta=1.0)
    with pytest.raises(TypeError, match="bias_ay is a setting of the linear KF; pass model=kfkit.vehicle.linear_model"):
        estimate_sideslip(**good_inputs(), params=CAR, bias_ay=True)
    with pytest.raises(TypeError, match="tyres is for the default EKF"):
        estimate_sideslip(**good_inputs(), params=CAR, model=V.linear_model, tyres=V.axle_tyres(CAR))
    with pytest.raises(ValueError, match="SideslipKF: dt must be a positive number, got 0"):
        SideslipKF(0, CAR)
