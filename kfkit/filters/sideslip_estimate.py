"""Lab 06's front door: ``estimate_sideslip`` over a drive, and the estimators the lab compares.

    estimate_sideslip(t, δ, r, a_y, V_x, car)                          saturating-tyre EKF (the default)
    estimate_sideslip(t, δ, r, a_y, V_x, car, model=linear_model)      the linear bicycle-model KF of lab 06

The default is :class:`~kfkit.filters.sideslip_ekf.SideslipEKF` because a real car leaves the tyres' linear
range in any brisk corner, where the linear KF underestimates |β|; inside the linear range the two filters agree.
Their errors on the bundled drives and the race-track log are ``benchmarks/bench_sideslip.py``'s tables (the
README's results).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from ..vehicle import BicycleParams, linear_model, miscopied_linear_model
from .sideslip import SideslipKF, SideslipKFSettings, SideslipRun, _as_inputs, copied_kinematic_kf, kinematic_sideslip
from .sideslip_ekf import SideslipEKF, SideslipEKFSettings


def estimate_sideslip(
    t,
    delta,
    yaw_rate,
    ay,
    vx,
    params: BicycleParams = BicycleParams(),
    *,
    model=None,
    tyres=None,
    x0=None,
    P0=None,
    **settings,
) -> SideslipRun:
    """Sideslip β over a drive, filtered at the drive's median sample interval from (x0, P0).

    t (s), delta (rad, road wheel), yaw_rate (rad/s), ay (m/s²), vx (m/s ≥ 0): equal-length 1-D arrays,
    ISO 8855 signs; ``params``: the car. ``model=None`` (default): :class:`SideslipEKF` with the tyre curves
    ``tyres`` (default the magic formula from params' Cf, Cr, mu) and any :class:`SideslipEKFSettings` field;
    ``model=f`` (``f(params, vx)`` → (A, B, C, D), e.g. :func:`kfkit.vehicle.linear_model`): lab 06's linear
    :class:`SideslipKF` with any :class:`SideslipKFSettings` field (bias_ay, vx_step, …).
    """
    d = _as_inputs(t, delta, yaw_rate, ay, vx)
    dt = float(np.median(np.diff(d["t"])))
    if model is None:
        linear_only = sorted(
            set(settings)
            & ({f.name for f in fields(SideslipKFSettings)} - {f.name for f in fields(SideslipEKFSettings)})
        )
        if linear_only:
            raise TypeError(
                f"estimate_sideslip: {', '.join(linear_only)} is a setting of the linear KF; pass "
                "model=kfkit.vehicle.linear_model to run it (the default saturating-tyre EKF has "
                f"{', '.join(f.name for f in fields(SideslipEKFSettings))})"
            )
        kf = SideslipEKF(dt, params, tyres=tyres, x0=x0, P0=P0, **settings)
    else:
        if tyres is not None:
            raise TypeError(
                "estimate_sideslip: tyres is for the default EKF (model=None); a linear model has C·α tyres"
            )
        kf = SideslipKF(dt, params, model=model, x0=x0, P0=P0, **settings)
    return kf.run(*d.values())


def compare_estimators(rec, params: BicycleParams = BicycleParams(), **tuning) -> dict:
    """β (rad) of every estimator lab 06 compares, on a vehicle recording: name → (N,) array.

    The saturating-tyre EKF (the default of :func:`estimate_sideslip`); the linear KF with the correct model,
    with an a_y bias state, with the miscopied model; the copied "kinematic" KF; open-loop kinematic
    integration; and β = 0 (what not estimating gives). ``tuning``: :class:`SideslipKFSettings` fields for the KFs.
    """
    signals = [rec[c] for c in ("t", "delta", "yaw_rate", "ay", "vx")]
    return {
        "EKF, saturating tyres": estimate_sideslip(*signals, params).beta,
        "KF, correct model": estimate_sideslip(*signals, params, model=linear_model, **tuning).beta,
        "KF + a_y bias state": estimate_sideslip(*signals, params, model=linear_model, bias_ay=True, **tuning).beta,
        "KF, miscopied model": estimate_sideslip(*signals, params, model=miscopied_linear_model, **tuning).beta,
        "copied kinematic KF": copied_kinematic_kf(rec["t"], rec["yaw_rate"], rec["ay"], rec["vx"])[1],
        "kinematic integration": kinematic_sideslip(rec["t"], rec["yaw_rate"], rec["ay"], rec["vx"])[1],
        "β = 0": np.zeros(len(signals[0])),
    }
