"""Lab 01: the scalar roll filter (gyro predicts, accelerometer roll corrects).

The textbook function forms the lab teaches (``roll_kf_predict``, ``roll_kf_update``, ``roll_kf``)
and the same filter as a :class:`RollKF` with :class:`RollSettings`, after the kit's filter contract.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .linear import FilterRun, Step, configure, require_positive


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


@dataclass(frozen=True)
class RollSettings:
    """Tuning of the lab 01 roll filter (the defaults are lab 05's MPU6050 figures at 100 Hz).

    q  variance the gyro prediction adds per step, rad² (≈ (σ_ω·Δt)² to start)      default 2e-6
    r  variance of the accelerometer roll, rad² ((4 mg noise / 1 g)²)                default 1.6e-5
    """

    q: float = 2e-6
    r: float = 1.6e-5

    def __post_init__(self):
        require_positive("RollSettings", q=self.q, r=self.r)


class RollKF:
    """The lab 01 roll filter, x = roll φ (rad), P its variance (rad²): one sample per :meth:`step`.

    dt        sample period, s
    settings  :class:`RollSettings` (q, r); keyword changes apply on top: ``RollKF(0.01, q=1e-6)``
    x0, P0    initial roll (rad) and variance (rad²), one step before the first sample
    """

    def __init__(self, dt, settings: RollSettings | None = None, x0=0.0, P0=1.0, **changes):
        require_positive("RollKF", dt=dt)
        self.dt = float(dt)
        self.settings = configure(RollSettings, settings, changes, "RollKF")
        self.x, self.P = float(x0), float(P0)

    def step(self, omega, z) -> Step:
        """Predict with gyro rate ω (rad/s), update with accelerometer roll z (rad; NaN skips the
        update) → Step(x, P, y, S) as floats, y and S NaN where skipped."""
        x, P = roll_kf_predict(self.x, self.P, omega, self.dt, self.settings.q)
        y = S = np.nan
        if z == z:  # not NaN
            x, P, y, S = roll_kf_update(x, P, z, self.settings.r)
        self.x, self.P = x, P
        return Step(x, P, y, S)

    def run(self, gyro_rate, roll_acc, x0=None, P0=1.0) -> FilterRun:
        """The same predict and update as :meth:`step` over a recording from (x0, P0) → :class:`FilterRun`
        of (N,) arrays. x0 defaults to the first accelerometer roll.

        Written out on plain floats and locals (no Step per sample), so sliders can re-run it live.
        """
        omega = np.asarray(gyro_rate, dtype=float).tolist()
        zs = np.asarray(roll_acc, dtype=float).tolist()
        N, dt, q, r = len(zs), self.dt, self.settings.q, self.settings.r
        xs, Ps, ys, Ss = [0.0] * N, [0.0] * N, [np.nan] * N, [np.nan] * N
        x = zs[0] if x0 is None else float(x0)
        P = float(P0)
        for k in range(N):
            x, P = roll_kf_predict(x, P, omega[k], dt, q)
            if zs[k] == zs[k]:  # not NaN
                x, P, ys[k], Ss[k] = roll_kf_update(x, P, zs[k], r)
            xs[k], Ps[k] = x, P
        self.x, self.P = x, P
        return FilterRun(np.array(xs), np.array(Ps), np.array(ys), np.array(Ss))


def roll_kf(gyro_rate, roll_acc, dt, q, r, x0=None, P0=1.0) -> FilterRun:
    """Run the lab 01 roll filter: gyro rate (rad/s) predicts, accelerometer roll (rad) corrects.

    ``RollKF(dt, q=q, r=r).run(gyro_rate, roll_acc, x0, P0)``: x0 defaults to the first
    accelerometer roll; NaN in ``roll_acc`` skips that update.
    """
    return RollKF(dt, q=q, r=r).run(gyro_rate, roll_acc, x0, P0)


def roll_kf_steady_state(q, r):
    """Steady-state prior variance P⁻∞ and gain K∞ of the scalar roll filter.

    P⁻ solves (P⁻)² − q·P⁻ − q·r = 0, so P⁻ = (q + √(q² + 4qr)) / 2 and K = P⁻ / (P⁻ + r).
    The filter then is the complementary filter x ← (1 − K)(x + ω dt) + K·z.
    """
    P_prior = 0.5 * (q + np.sqrt(q * q + 4.0 * q * r))
    return P_prior, P_prior / (P_prior + r)
