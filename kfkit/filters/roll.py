"""Lab 01: the scalar roll filter (gyro predicts, accelerometer roll corrects)."""
from __future__ import annotations

import numpy as np

from .linear import FilterRun


def integrate_rate(rate, dt, x0=0.0):
    """Dead reckoning: x_k = x0 + Σ_{i≤k} ω_i·dt (rad), the KF's prediction with no updates."""
    return x0 + np.cumsum(np.asarray(rate, dtype=float) * dt)


def roll_kf_predict(x, P, omega, dt, q):
    """Scalar roll prediction: x⁻ = x + ω·dt (rad),  P⁻ = P + q (rad²)."""
    return x + omega * dt, P + q


def roll_kf_update(x, P, z, r):
    """Scalar roll update with an accelerometer roll z (rad), variance r (rad²).

    y = z − x,  S = P + r,  K = P / S,  x ← x + K·y,  P ← (1 − K)·P.  Returns (x, P, y, S).
    """
    y = z - x
    S = P + r
    K = P / S
    return x + K * y, (1.0 - K) * P, y, S


def roll_kf(gyro_rate, roll_acc, dt, q, r, x0=None, P0=1.0) -> FilterRun:
    """Run the lab 01 roll filter: gyro rate (rad/s) predicts, accelerometer roll (rad) corrects.

    x0 defaults to the first accelerometer roll. NaN in ``roll_acc`` skips that update.
    A plain-Python loop on floats (no small-matrix overhead), so sliders can re-run it live.
    """
    omega = np.asarray(gyro_rate, dtype=float).tolist()
    zs = np.asarray(roll_acc, dtype=float).tolist()
    N = len(zs)
    xs, Ps, ys, Ss = [0.0] * N, [0.0] * N, [np.nan] * N, [np.nan] * N
    x = zs[0] if x0 is None else float(x0)
    P = float(P0)
    for k in range(N):
        x, P = roll_kf_predict(x, P, omega[k], dt, q)
        if zs[k] == zs[k]:  # not NaN
            x, P, ys[k], Ss[k] = roll_kf_update(x, P, zs[k], r)
        xs[k], Ps[k] = x, P
    return FilterRun(np.array(xs), np.array(Ps), np.array(ys), np.array(Ss))


def roll_kf_steady_state(q, r):
    """Steady-state prior variance P⁻∞ and gain K∞ of the scalar roll filter.

    P⁻ solves P⁻² − q·P⁻ − q·r = 0, so P⁻ = (q + √(q² + 4qr)) / 2 and K = P⁻ / (P⁻ + r).
    The filter then is the complementary filter x ← (1 − K)(x + ω dt) + K·z.
    """
    P_prior = 0.5 * (q + np.sqrt(q * q + 4.0 * q * r))
    return P_prior, P_prior / (P_prior + r)
