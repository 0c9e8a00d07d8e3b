"""Lab 01: the scalar roll filter (gyro predicts, accelerometer roll corrects).

The textbook function forms the lab teaches (``roll_kf_predict``, ``roll_kf_update``, ``roll_kf``)
and the same filter as a :class:`RollKF` with :class:`RollKFSettings`, after the kit's filter contract.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .contract import FilterRun, State, Step, check_settings, configure, sample_period, shaped


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
class RollKFSettings:
    """Tuning of the lab 01 roll filter (the defaults are lab 05's MPU6050 figures at 100 Hz).

    q_angle  variance the gyro prediction adds per step, rad² (≈ (σ_ω·Δt)² to start)        2e-6
    r        variance of the accelerometer roll, rad² ((4 mg noise / 1 g)²)                  1.6e-5
    """

    q_angle: float = 2e-6
    r: float = 1.6e-5

    def __post_init__(self):
        check_settings(self, positive=("q_angle", "r"))


class RollKF:
    """The lab 01 roll filter, x = roll φ (rad), P its variance (rad²): one sample per :meth:`step`, a
    :class:`~kfkit.filters.contract.TunedFilter`.

    dt        sample period, s (or ``rate_hz``, Hz)
    settings  :class:`RollKFSettings`; keyword changes apply on top: ``RollKF(0.01, q_angle=1e-6)``
    x0, P0    initial roll (rad) and variance (rad², default 1), one step before the first sample; x0 None: the
              first accelerometer roll (0 if there is none)
    """

    def __init__(self, dt=None, settings: RollKFSettings | None = None, *, rate_hz=None, x0=None, P0=None, **changes):
        self.dt = sample_period("RollKF", dt, rate_hz)
        self.settings = configure(RollKFSettings, settings, changes, "RollKF")
        self._x0, self._P0 = None, 1.0
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start; a given x0 or P0 replaces the start's."""
        if x0 is not None:
            self._x0 = float(shaped("RollKF", "x0", x0, ()))
        if P0 is not None:
            self._P0 = float(shaped("RollKF", "P0", P0, ()))
        self.state = State(self._x0, self._P0)

    def step(self, omega, z) -> Step:
        """Predict with gyro rate ω (rad/s), update with accelerometer roll z (rad; NaN skips the
        update) → Step as floats, y and S NaN where skipped."""
        s = self.state
        x = (z if z == z else 0.0) if s.x is None else s.x
        x_prior, P_prior, s.x, s.P, y, S = _roll_sample(
            x, s.P, omega, z, self.dt, self.settings.q_angle, self.settings.r
        )
        return Step(s.x, s.P, y, S, x_prior, P_prior)

    def run(self, gyro_rate, roll_acc, *, resume=False) -> FilterRun:
        """:meth:`step` over a recording → :class:`FilterRun` of (N,) arrays: from the start (x0 None: the first
        accelerometer roll that is not NaN), or from the current state with ``resume=True``.

        Written out on plain floats and locals (no Step per sample), so sliders can re-run it live.
        """
        if not resume:
            self.reset()
        omega = np.asarray(gyro_rate, dtype=float).tolist()
        zs = np.asarray(roll_acc, dtype=float).tolist()
        N, dt, q, r = len(zs), self.dt, self.settings.q_angle, self.settings.r
        rows = [None] * N
        x, P = self.state.x, self.state.P
        if x is None:
            x = next((z for z in zs if z == z), 0.0)
        for k in range(N):
            rows[k] = _roll_sample(x, P, omega[k], zs[k], dt, q, r)
            x, P = rows[k][2], rows[k][3]
        self.state = State(x, P)
        x_prior, P_prior, x, P, y, S = np.array(rows, dtype=float).reshape(N, 6).T
        return FilterRun(x, P, y, S, x_prior, P_prior)


def _roll_sample(x, P, omega, z, dt, q, r):
    """One predict + update on floats → (x⁻, P⁻, x, P, y, S), y and S NaN where z is NaN."""
    x_prior, P_prior = roll_kf_predict(x, P, omega, dt, q)
    if z != z:  # NaN: no update
        return x_prior, P_prior, x_prior, P_prior, math.nan, math.nan
    return (x_prior, P_prior, *roll_kf_update(x_prior, P_prior, z, r))


def roll_kf(gyro_rate, roll_acc, dt, q, r, x0=None, P0=1.0) -> FilterRun:
    """Run the lab 01 roll filter: gyro rate (rad/s) predicts, accelerometer roll (rad) corrects.

    ``RollKF(dt, q_angle=q, r=r, x0=x0, P0=P0).run(gyro_rate, roll_acc)``: x0 defaults to the first
    accelerometer roll; NaN in ``roll_acc`` skips that update.
    """
    return RollKF(dt, q_angle=q, r=r, x0=x0, P0=P0).run(gyro_rate, roll_acc)


def roll_kf_steady_state(q, r):
    """Steady-state prior variance P⁻∞ and gain K∞ of the scalar roll filter.

    P⁻ solves (P⁻)² − q·P⁻ − q·r = 0, so P⁻ = (q + √(q² + 4qr)) / 2 and K = P⁻ / (P⁻ + r).
    The filter then is the complementary filter x ← (1 − K)(x + ω dt) + K·z.
    """
    P_prior = 0.5 * (q + np.sqrt(q * q + 4.0 * q * r))
    return P_prior, P_prior / (P_prior + r)
