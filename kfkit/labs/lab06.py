"""Lab 06 support: the drives as the filters read them, the loops that run a student's functions over a drive (the
linear KF of section 5, the saturating-tyre EKF of section 12), and the tables only this lab prints.

The loops hold the bookkeeping (the speed-bin cache, the previous steering, the affine form that lets the KF step of
section 5 serve the EKF); the model, the discretisation, the filter step, the tyre forces and their Jacobian are the
student's functions, passed in. The checkpoints build their cases from the same helpers.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .. import datasets, plots
from ..filters.sideslip_ekf import SideslipEKFSettings
from ..filters.sideslip_estimate import estimate_sideslip
from ..frames import G
from ..metrics import rmse
from ..vehicle import BicycleParams, linear_model

SIGNALS = ("t", "delta", "yaw_rate", "ay", "vx")  # what the filters read, in their argument order
SLALOM = "06_slalom_20kmh"
RACETRACK = "06_racetrack"
# where a car neither turns nor slides: what its sensors show there needs no β
STRAIGHT_AY, STRAIGHT_YAW_RATE = 1.0, 0.02  # m/s², rad/s


def signals(rec, keep=None) -> list:
    """The five signals of a vehicle recording (t, δ, r, a_y, V_x), optionally only the samples ``keep`` (a mask)."""
    return [rec[c] if keep is None else rec[c][keep] for c in SIGNALS]


def bundled_inputs(name=SLALOM):
    """A lab 06 bundled drive (default the slalom at 20 km/h): ({signal: array}, true β)."""
    rec = datasets.load(name)
    return dict(zip(SIGNALS, signals(rec))), rec["true_beta"]


def straights(rec) -> np.ndarray:
    """The samples where the car neither turns nor slides: |a_y| < 1 m/s² and |r| < 0.02 rad/s."""
    return (np.abs(rec["ay"]) < STRAIGHT_AY) & (np.abs(rec["yaw_rate"]) < STRAIGHT_YAW_RATE)


def published_car(rec, mu=None) -> BicycleParams:
    """The car a recording's metadata describes, with friction ``mu`` when given (the race-track log states none)."""
    return BicycleParams(**rec.meta["vehicle"], **({} if mu is None else {"mu": mu}))


def run_sideslip(
    t,
    delta,
    yaw_rate,
    ay,
    vx,
    params,
    bicycle_model,
    discretize,
    kf_step,
    *,
    q_beta=1e-4,
    q_r=1e-3,
    r_std=(0.003, 0.05),
    vx_step=0.05,
) -> np.ndarray:
    """Section 5's filter over a drive with the student's three functions: β (rad), one per sample.

    Per sample: the model ``bicycle_model(params, V)`` at the speed rounded to ``vx_step`` (m/s; discretised once
    per bin with ``discretize(A, B, dt, Qc)``, Qc = diag(q_beta, q_r)), then ``kf_step`` with the previous sample's
    steering in the prediction and this sample's in the D-term; R = diag(r_std²). Starts at x = 0, P = diag((2°)²);
    assumes V_x > 0 throughout (kfkit's SideslipKF adds the low-speed guard).
    """
    dt = float(np.median(np.diff(t)))
    Qc, R = np.diag([q_beta, q_r]), np.diag(np.square(r_std))
    x, P = np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
    cache, beta = {}, np.empty(len(t))
    for k in range(len(t)):
        key = max(1, round(vx[k] / vx_step))
        if key not in cache:
            A, B, C, D = bicycle_model(params, key * vx_step)
            cache[key] = (*discretize(A, B, dt, Qc), C, D)
        Ad, Bd, Qd, C, D = cache[key]
        x, P, _, _ = kf_step(
            x, P, delta[k - 1] if k else delta[0], np.array([yaw_rate[k], ay[k]]), delta[k], Ad, Bd, Qd, C, D, R
        )
        beta[k] = x[0]
    return beta


def tyre_rates(params, forces, r, vx):
    """The single-track model's rates from the axle forces (N): β̇ = (F_f + F_r)/(m V_x) − r (rad/s),
    ṙ = (a F_f − b F_r)/I_z (rad/s²), as an array, and a_y = (F_f + F_r)/m (m/s²)."""
    ff, fr = forces
    return np.array([(ff + fr) / (params.m * vx) - r, (params.a * ff - params.b * fr) / params.Iz]), (
        ff + fr
    ) / params.m


def run_tyre_ekf(
    t,
    delta,
    yaw_rate,
    ay,
    vx,
    params,
    tyre_force,
    tyre_jacobian,
    discretize,
    kf_step,
    settings: SideslipEKFSettings = SideslipEKFSettings(),
) -> np.ndarray:
    """Section 12's EKF over a drive with the student's functions: β (rad), one per sample.

    ``tyre_force(params, x, δ, V)`` → (F_f, F_r) N; ``tyre_jacobian(params, x, δ, V)`` → (J, H), J = ∂[β̇, ṙ]/∂x,
    H = ∂[r, a_y]/∂x; ``discretize`` and ``kf_step`` those of sections 4–5. Per sample::

        predict   f = [β̇, ṙ] at (x, δ_{k−1});  Ad, Bd, Qd = discretize(J, f, dt, Qc):  x⁻ = x + Bd  (Bd = ∫e^{Jτ}dτ·f)
        update    z = [r, a_y] against [r⁻, a_y(x⁻, δ_k)] with H at x⁻;
                  R = diag(σ_r², σ_a² + ε²(F_f² + F_r²)/m²)  (ε = ``stiffness_std``: the tyre force's own uncertainty)

    both through ``kf_step`` in its affine form (x⁻ = Ad x + (x⁻ − Ad x)·1, the predicted measurement H x⁻ + d·1),
    which is kfkit's :class:`~kfkit.filters.SideslipEKF` (Van Loan's Qd in place of its Simpson rule). Settings as
    :class:`SideslipEKFSettings`; no low-speed guard: every V_x must be at least ``settings.v_min``.
    """
    slow = np.asarray(vx) < settings.v_min
    if slow.any():
        k = int(np.argmax(slow))
        raise ValueError(
            f"run_tyre_ekf: vx[{k}] = {vx[k]:.3g} m/s is below v_min = {settings.v_min:g} m/s; this loop "
            "has no low-speed guard (kfkit's SideslipEKF has): cut the drive to where the car rolls"
        )
    dt = float(np.median(np.diff(t)))
    Qc = np.diag([settings.q_beta, settings.q_r])
    x, P = np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
    beta = np.empty(len(t))
    for k in range(len(t)):
        delta_prev = delta[k - 1] if k else delta[0]
        f, _ = tyre_rates(params, tyre_force(params, x, delta_prev, vx[k]), x[1], vx[k])
        J, _ = tyre_jacobian(params, x, delta_prev, vx[k])
        Ad, Bd, Qd = discretize(np.asarray(J, dtype=float), f[:, None], dt, Qc)
        x_prior = x + Bd[:, 0]
        forces = tyre_force(params, x_prior, delta[k], vx[k])
        _, ay_prior = tyre_rates(params, forces, x_prior[1], vx[k])
        H = np.asarray(tyre_jacobian(params, x_prior, delta[k], vx[k])[1], dtype=float)
        D = np.array([[x_prior[1]], [ay_prior]]) - (H @ x_prior)[:, None]
        R = np.diag(
            [
                settings.gyro_noise**2,
                settings.accel_noise**2 + (settings.stiffness_std / params.m) ** 2 * float(np.sum(np.square(forces))),
            ]
        )
        x, P, _, _ = kf_step(
            x, P, 1.0, np.array([yaw_rate[k], ay[k]]), 1.0, Ad, (x_prior - Ad @ x)[:, None], Qd, H, D, R
        )
        beta[k] = x[0]
    return beta


def beta_rmse_deg(beta, truth, skip=5) -> float:
    """β RMSE (°) after the first ``skip`` samples (the filters start from β = 0)."""
    return math.degrees(rmse(np.asarray(beta)[skip:], np.asarray(truth)[skip:]))


def mu_sweep(rec, params, mus) -> dict:
    """β (rad) of kfkit's saturating-tyre EKF on ``rec`` with the car's friction set to each µ of ``mus``: {µ: β}."""
    return {mu: estimate_sideslip(*signals(rec), replace(params, mu=mu)).beta for mu in mus}


def linear_ay(params, beta, r, delta, vx):
    """a_y (m/s²) the linear tyres promise at β, r, δ: the model's C x + D δ."""
    return (
        -(params.Cf + params.Cr) / params.m * beta
        + (params.b * params.Cr - params.a * params.Cf) / (params.m * vx) * r
        + params.Cf / params.m * delta
    )


def by_ay_bins(ay, values, edges, how=np.median) -> list:
    """``how`` (median by default) of ``values`` in each |a_y| bin [edges[i], edges[i+1]) (m/s²); NaN for an empty
    bin."""
    level = np.digitize(np.abs(ay), edges) - 1
    return [float(how(values[level == i])) if np.any(level == i) else math.nan for i in range(len(edges) - 1)]


def sensitivity_table(drives: dict, car: BicycleParams) -> dict:
    """Section 8: β RMSE (°) of kfkit's linear KF per drive (name → recording) and case — nominal, the cornering
    stiffnesses ±20 %, 0.3 m/s² added to a_y, and that bias with the bias state: {drive: {case: RMSE}}."""
    cases = {
        "nominal": (car, 0.0, False),
        "C −20 %": (car.scaled(0.8), 0.0, False),
        "C +20 %": (car.scaled(1.2), 0.0, False),
        "a_y bias +0.3": (car, 0.3, False),
        "bias + state": (car, 0.3, True),
    }
    table = {}
    for label, r in drives.items():
        t, delta, yaw_rate, ay, vx = signals(r)
        table[label] = {
            name: math.degrees(
                rmse(
                    estimate_sideslip(
                        t, delta, yaw_rate, ay + bias, vx, params, model=linear_model, bias_ay=state
                    ).beta,
                    r["true_beta"],
                )
            )
            for name, (params, bias, state) in cases.items()
        }
    return table


def banked_straight(params: BicycleParams, bank: float):
    """A steady straight across a road banked by ``bank`` (rad, high side left): (a_y, β), the accelerometer's
    reading (m/s², ISO y left) and the sideslip (rad) of the linear tyres that hold the car there.

    The road's push, tilted with the car, reads a_y = g sin(bank) toward the high side; the tyres push the car up the
    slope with F_f + F_r = m g sin(bank) and no net moment (a F_f = b F_r), so F_r = m g sin(bank)·a/L; on a
    straight (r = 0) α_r = −β, and F_r = C_r α_r gives β = −F_r / C_r.
    """
    side = params.m * G * math.sin(bank)
    return G * math.sin(bank), -side * params.a / params.wheelbase / params.Cr


def hardest_corner(rec, window_s: float = 0.5) -> int:
    """The sample where the lateral acceleration averaged over ``window_s`` (s) is largest in size."""
    n = max(1, int(round(window_s * rec.rate_hz)))
    return int(np.argmax(np.abs(np.convolve(rec["ay"], np.ones(n) / n, mode="same"))))


def plot_error_by_ay(ax, ay, truth, estimates: dict, edges):
    """Mean β error × sign β (°; < 0: |β| too small) per |a_y| bin for ``estimates`` {label: (β, colour key)}."""
    centres = 0.5 * (np.asarray(edges[:-1]) + np.asarray(edges[1:]))
    for label, (beta, key) in estimates.items():
        err = np.degrees(np.asarray(beta) - truth) * np.sign(truth)
        ax.plot(centres, by_ay_bins(ay, err, edges, how=np.mean), marker="o", color=plots.COLORS[key], label=label)
    ax.axhline(0.0, color=plots.COLORS["truth"], lw=0.8)
    ax.set(xlabel="|a_y| (m/s²)", ylabel="mean β error × sign β (°)")
    plots.legend_on_top(ax, ncols=len(estimates))
