"""Lab 06's support (kfkit.labs.lab06) and the friction a log shows (vehicle.peak_friction), against oracles.

Oracles: kfkit's SideslipKF and SideslipEKF (each held to filterpy elsewhere) for the loops that run a student's
functions; central finite differences for the Jacobian the checkpoint judges by; the nonlinear single-track model
driven to its limit for the friction bound; a force balance on the magic-formula tyres, solved by scipy, for the
banked straight.
"""

import math

import numpy as np
import pytest
from scipy.optimize import fsolve

from kfkit import datasets, vehicle
from kfkit.checkpoints.lab06 import SPORTS_CAR, random_car, random_tyre_state, reference_jacobian
from kfkit.discrete import discretize
from kfkit.filters import SideslipEKF, estimate_sideslip
from kfkit.filters.sideslip import sideslip_step
from kfkit.frames import G
from kfkit.labs import lab06

CAR = vehicle.BicycleParams()


def kit_tyre_force(params, x, delta, vx):
    return SideslipEKF(0.01, params).axle_forces(x[0], x[1], delta, vx)[:2]


def test_the_linear_loop_with_kfkits_pieces_is_kfkits_kf():
    """Above v_min and with the same speed bins the loop is SideslipKF (the lab's check relies on it)."""
    sig, truth = lab06.bundled_inputs("06_slalom_80kmh")
    ours = lab06.run_sideslip(*sig.values(), CAR, vehicle.linear_model, discretize, sideslip_step)
    kit = estimate_sideslip(*sig.values(), CAR, model=vehicle.linear_model).beta
    np.testing.assert_allclose(ours, kit, atol=1e-9)
    assert lab06.beta_rmse_deg(ours, truth) < 0.03


@pytest.mark.parametrize("name, samples", [("06_racetrack", 3000), ("06_lane_change", None)])
def test_the_ekf_loop_with_kfkits_pieces_is_kfkits_ekf(name, samples):
    """run_tyre_ekf through the KF step's affine form is SideslipEKF (which uses Simpson's Qd, not Van Loan's):
    on the race track's hard corners and on a simulated drive."""
    rec = datasets.load(name)
    params = lab06.published_car(rec, vehicle.peak_friction(rec.t, rec["ay"])) if name == "06_racetrack" else CAR
    sig = [s[:samples] for s in lab06.signals(rec)]
    ours = lab06.run_tyre_ekf(*sig, params, kit_tyre_force, reference_jacobian, discretize, sideslip_step)
    kit = estimate_sideslip(*sig, params).beta
    assert np.degrees(np.abs(ours - kit).max()) < 1e-5


def test_the_ekf_loop_refuses_a_crawl_and_names_the_sample():
    t = np.arange(0.0, 1.0, 0.01)
    vx = np.full_like(t, 10.0)
    vx[37] = 1.0
    with pytest.raises(ValueError, match=r"vx\[37\] = 1 m/s is below v_min = 2 m/s"):
        lab06.run_tyre_ekf(
            t, 0 * t, 0 * t, 0 * t, vx, CAR, kit_tyre_force, reference_jacobian, discretize, sideslip_step
        )


def model_outputs(params, x, delta, vx):
    """[β̇, ṙ, r, a_y] of the saturating-tyre model (what J and H differentiate)."""
    rates, ay = lab06.tyre_rates(params, kit_tyre_force(params, x, delta, vx), x[1], vx)
    return np.array([*rates, x[1], ay])


@pytest.mark.parametrize("seed", range(5))
def test_the_checkpoints_jacobian_is_the_models_derivative(seed):
    """The reference 06.tyre_jacobian judges by, against central differences of the model it linearises."""
    rng = np.random.default_rng(seed)
    for params in (SPORTS_CAR, random_car(rng)):
        params = vehicle.BicycleParams(**{**params.__dict__, "mu": float(rng.uniform(0.5, 1.6))})
        x, delta, vx = random_tyre_state(rng, params)
        J, H = reference_jacobian(params, x, delta, vx)
        eps = 1e-7
        numeric = np.column_stack(
            [
                (model_outputs(params, x + e, delta, vx) - model_outputs(params, x - e, delta, vx)) / (2 * eps)
                for e in eps * np.eye(2)
            ]
        )
        np.testing.assert_allclose(np.vstack([J, H]), numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())


def limit_drive(params, seed=3):
    """Steering ramped to 12° at 20 m/s over 30 s: the nonlinear car is driven past its limit; its a_y (true)
    and a vibrating sensor's (white noise of σ 0.5 m/s², as a race car's body shows on straights)."""
    t = np.arange(0.0, 30.0, 0.01)
    truth = vehicle.simulate_nonlinear(params, t, np.radians(12.0) * t / t[-1], 20.0)
    return t, truth["ay"], truth["ay"] + np.random.default_rng(seed).normal(0.0, 0.5, t.size)


@pytest.mark.parametrize("mu", [0.4, 0.9, 1.2])
def test_peak_friction_is_a_lower_bound_that_a_limit_drive_reaches(mu):
    """|a_y| ≤ µ g for any state of the model (each axle ≤ µ F_z); a drive past the limit comes within 5 % of it."""
    params = vehicle.BicycleParams(Cf=110_000.0, Cr=130_000.0, mu=mu)
    t, ay, _ = limit_drive(params)
    found = vehicle.peak_friction(t, ay)
    assert 0.95 * mu < found <= mu


def test_peak_friction_averages_out_vibration_that_one_sample_would_count():
    t, ay, measured = limit_drive(vehicle.BicycleParams(mu=0.9))
    clean = vehicle.peak_friction(t, ay)
    assert abs(vehicle.peak_friction(t, measured) - clean) < 0.03  # half a second: σ 0.07 m/s², 4σ
    assert vehicle.peak_friction(t, measured, window_s=0.01) > clean + 0.1  # one sample: a 3–4σ spike


def test_a_gentle_drive_gives_only_a_bound_far_under_the_friction():
    rec = datasets.load("06_slalom_80kmh")
    assert vehicle.peak_friction(rec.t, rec["ay"]) < 0.5 * CAR.mu


def test_peak_friction_names_bad_input():
    t = np.arange(0.0, 1.0, 0.01)
    ay = np.ones_like(t)
    ay[12] = np.nan
    with pytest.raises(ValueError, match=r"ay\[12\] is nan"):
        vehicle.peak_friction(t, ay)
    with pytest.raises(ValueError, match=r"shorter than the 2 s window \(200 samples\)"):
        vehicle.peak_friction(t, np.ones_like(t), window_s=2.0)


@pytest.mark.parametrize("bank_deg", [1.0, 3.0, 8.0])
def test_the_banked_straight_is_the_force_balance_on_the_tyre_curves(bank_deg):
    """Oracle: r = 0, both axles on their magic formula, F_f + F_r = m g sin(bank), a F_f = b F_r, solved for (β, δ)
    by scipy; the linear tyres' β of lab06.banked_straight agrees within the curve's bend at these small forces."""
    bank = math.radians(bank_deg)
    front, rear = vehicle.axle_tyres(CAR)

    def balance(v):
        beta, delta = v
        ff, fr = front.force(delta - beta), rear.force(-beta)
        return [(ff + fr) - CAR.m * G * math.sin(bank), CAR.a * ff - CAR.b * fr]

    beta, _ = fsolve(balance, [0.0, 0.0])
    ay, beta_linear = lab06.banked_straight(CAR, bank)
    assert ay == pytest.approx(G * math.sin(bank), rel=1e-12)
    assert beta_linear == pytest.approx(beta, rel=0.02)
