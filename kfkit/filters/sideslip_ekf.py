"""Sideslip β with saturating tyres: an EKF on the single-track model whose axle forces follow the tyre curve.

The linear bicycle model (lab 06's :class:`~kfkit.filters.SideslipKF`) gives each axle the force C·α. Real
tyres give less as α grows and level off at µ·F_z: in a hard corner the linear model wants more lateral force
than the tyres make, so the KF, told a_y, answers with too small a |β|. Here each axle's force is F(α) on a
saturating curve, by default the kit's magic formula (:func:`kfkit.vehicle.axle_tyres`: initial slope Cf or Cr,
peak µ·F_z with the static axle loads)::

    α_f = δ − β − a r/V_x,   α_r = −β + b r/V_x                      (the linear model's small-angle slips)
    β̇ = (F_f + F_r)/(m V_x) − r,   ṙ = (a F_f − b F_r)/I_z,   a_y = (F_f + F_r)/m

With F = C·α this *is* the linear model, and the filter is lab 06's KF (a test holds them equal).

EKF step (x = [β, r], z = [r, a_y]): the Jacobian J = ∂f/∂x is the linear model's A with Cf, Cr replaced
by the local slopes k = dF/dα (:meth:`kfkit.vehicle.MagicFormula.slope`), and ∂a_y/∂x its C row::

    predict   x⁻ = x + φ₁(J dt)·f(x, δ_{k−1})·dt,  φ₁(z) = (eᶻ − 1)/z    (exact when f is linear)
              P⁻ = Ad P Adᵀ + Qd,  Ad = e^{J dt},  Qd = ∫₀^dt e^{Jτ} Q e^{Jᵀτ} dτ (Simpson's rule)
    update    y = z − [r⁻, a_y(x⁻, δ_k)],  H = [[0, 1], ∂a_y/∂x],  then the KF update

e^{J dt}, e^{J dt/2} and φ₁(J dt) of the 2×2 matrix come in closed form from its eigenvalues (Cayley–Hamilton;
held equal to scipy's expm by a test): the Jacobian changes every sample, so there is no speed-bin cache as in
the KF, and scipy's expm per sample would cost more than the rest of the step (``benchmarks/bench_sideslip.py``
times it).

Where each setting comes from (physics, the sensors and the log without its β; lab 06, sections 11–12, derives
them on the race-track log, and the benchmark prints what the log shows):

* ``params.mu``: the tyres' peak µ·F_z. The kit's car is simulated with µ = 1 (dry asphalt). A log that does not
  state it shows a lower bound, :func:`kfkit.vehicle.peak_friction` (its largest lateral acceleration averaged
  over half a second, in g), which is µ itself on a drive at the limit. Too small a µ is the costly side: the
  model cannot make the force the car measured.
* ``accel_noise`` 0.5 m/s²: a car body's accelerometer sees engine, road and wheel vibration that an ESC
  cluster's sensor datasheet does not list; the straights of a log (|a_y| < 1 m/s², |r| < 0.02 rad/s, where the
  car neither turns nor slides) show it without β. A filter that believes 0.05 m/s² trusts each vibrating
  sample as a β measurement; a too-large σ costs little on a quiet sensor.
* ``stiffness_std`` 0.2: each axle's force from its curve is known to ±20 % (cornering stiffness and
  friction vary with load, temperature, pressure and wear; published values are chosen, not measured).
  The a_y update's variance grows accordingly: R_ay = σ_a² + ε²(F_f² + F_r²)/m², so in a hard corner the
  measurement says less about β than in a gentle bend, and the filter leans on its model where the tyres
  are least certain.
* ``gyro_noise``, ``q_beta``, ``q_r``, ``v_min``, ``beta_low_std`` as lab 06's KF (:class:`SideslipKFSettings`).

Below ``v_min`` the filter hands over to the same kinematic guard as the KF (β = b·δ/L, yaw-rate update).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from ..vehicle import BicycleParams, axle_tyres
from .contract import Step, check_settings, configure, sample_period
from .sideslip import SideslipRun, SideslipState, _as_inputs, _run_drive, _start, _step2, low_speed_step


@dataclass(frozen=True)
class SideslipEKFSettings:
    """Tuning of :class:`SideslipEKF` (the module doc says where each default comes from).

    q_beta         process noise on β̇, rad²/s                                                   1e-4
    q_r            process noise on ṙ, rad²/s³                                                  1e-3
    gyro_noise     yaw-rate σ per sample, rad/s                                                0.003
    accel_noise    lateral-acceleration σ per sample (vibration included), m/s²                 0.5
    stiffness_std  relative σ of each axle's tyre force (stiffness and friction), 1              0.2
    v_min          below this speed the kinematic β = b·δ/L is used, m/s                         2.0
    beta_low_std   σ of that kinematic β, rad                                                     1°
    """

    q_beta: float = 1e-4
    q_r: float = 1e-3
    gyro_noise: float = 0.003
    accel_noise: float = 0.5
    stiffness_std: float = 0.2
    v_min: float = 2.0
    beta_low_std: float = math.radians(1.0)

    def __post_init__(self):
        check_settings(
            self,
            positive=("q_beta", "q_r", "gyro_noise", "accel_noise", "v_min", "beta_low_std"),
            non_negative=("stiffness_std",),
        )


def matrix_functions_2x2(M, *functions):
    """g(M) for a real 2×2 matrix M and each (g, g′) in ``functions``: a list of (α, β) with g(M) = α I + β M.

    Cayley–Hamilton, from M's eigenvalues λ₁,₂ = s ± √(s² − det M), s = tr M / 2 (complex for a yaw
    oscillation): β = (g(λ₁) − g(λ₂))/(λ₁ − λ₂), α = g(λ₁) − β λ₁; for λ₁ ≈ λ₂ the limit β = g′(s),
    α = g(s) − s g′(s). g and g′ take and return complex numbers; one eigen-solve serves every g.
    """
    (m11, m12), (m21, m22) = M.tolist()
    s = 0.5 * (m11 + m22)
    root = cmath.sqrt(s * s - (m11 * m22 - m12 * m21))
    l1, l2 = s + root, s - root
    out = []
    for g, dg in functions:
        if abs(root) < 1e-7 * (1.0 + abs(s)):
            beta = dg(s)
            alpha = g(s) - s * beta
        else:
            beta = (g(l1) - g(l2)) / (l1 - l2)
            alpha = g(l1) - beta * l1
        out.append((alpha.real, beta.real))
    return out


def _phi1(z):
    """φ₁(z) = (eᶻ − 1)/z, its series near 0."""
    return (cmath.exp(z) - 1.0) / z if abs(z) > 1e-4 else 1.0 + z / 2.0 + z * z / 6.0


def _dphi1(z):
    """φ₁′(z) = (z eᶻ − eᶻ + 1)/z², its series near 0."""
    return (z * cmath.exp(z) - cmath.exp(z) + 1.0) / (z * z) if abs(z) > 1e-3 else 0.5 + z / 3.0 + z * z / 8.0


def _exp_half(z):
    """e^{z/2}, for e^{J dt/2} from J dt's eigenvalues."""
    return cmath.exp(0.5 * z)


def _dexp_half(z):
    return 0.5 * cmath.exp(0.5 * z)


EXP, EXP_HALF, PHI1 = (cmath.exp, cmath.exp), (_exp_half, _dexp_half), (_phi1, _dphi1)


def _poly(alpha, beta, M):
    """α I + β M."""
    out = beta * M
    out[0, 0] += alpha
    out[1, 1] += alpha
    return out


class SideslipEKF:
    """Sideslip β with saturating tyres (module doc); the contract of :class:`~kfkit.filters.SideslipKF`.

    dt        nominal sample interval, s (or ``rate_hz``, Hz; the first step's)
    params    the car (:class:`BicycleParams`; its Cf, Cr, mu shape the default tyres)
    settings  :class:`SideslipEKFSettings`; keyword changes apply on top
    tyres     (front, rear) axle curves with ``force(α)`` (N) and ``slope(α)`` (N/rad); default
              :func:`kfkit.vehicle.axle_tyres` (magic formula)
    x0, P0    initial state (default 0) and covariance (default diag((2°)², (2°/s)²))
    """

    def __init__(
        self,
        dt=None,
        params: BicycleParams = BicycleParams(),
        settings: SideslipEKFSettings | None = None,
        *,
        rate_hz=None,
        tyres=None,
        x0=None,
        P0=None,
        **changes,
    ):
        self.dt, self.params = sample_period("SideslipEKF", dt, rate_hz), params
        self.settings = configure(SideslipEKFSettings, settings, changes, "SideslipEKF")
        self.front, self.rear = axle_tyres(params) if tyres is None else tyres
        self._kinematic_gain = params.b / params.wheelbase
        self._Q = np.diag([self.settings.q_beta, self.settings.q_r])
        self._x0, self._P0 = np.zeros(2), np.diag([math.radians(2.0) ** 2] * 2)
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start (a given x0 or P0 replaces the start's); δ_{k−1} and the last time forgotten."""
        self._x0, self._P0 = _start(self, x0, P0)
        self.state = SideslipState(self._x0.copy(), self._P0.copy())

    def axle_forces(self, beta, r, delta, vx):
        """(F_f, F_r, k_f, k_r): axle forces (N) and their slopes dF/dα (N/rad) at the state, steering and speed."""
        p = self.params
        alpha_f, alpha_r = delta - beta - p.a * r / vx, -beta + p.b * r / vx
        return (
            float(self.front.force(alpha_f)),
            float(self.rear.force(alpha_r)),
            float(self.front.slope(alpha_f)),
            float(self.rear.slope(alpha_r)),
        )

    def jacobian(self, kf, kr, vx):
        """J = ∂[β̇, ṙ]/∂[β, r] (the linear model's A with the local slopes) and ∂a_y/∂[β, r] (its C row)."""
        p = self.params
        lat = p.b * kr - p.a * kf
        J = np.array(
            [
                [-(kf + kr) / (p.m * vx), lat / (p.m * vx * vx) - 1.0],
                [lat / p.Iz, -(p.a * p.a * kf + p.b * p.b * kr) / (p.Iz * vx)],
            ]
        )
        return J, (-(kf + kr) / p.m, lat / (p.m * vx))

    def step(self, delta, yaw_rate, ay, vx, dt=None) -> Step:
        """One sample (as :meth:`SideslipKF.step <kfkit.filters.SideslipKF.step>`) → Step(x, P, y, S, x⁻, P⁻)."""
        st, p, s = self.settings, self.params, self.state
        dt = self.dt if dt is None else dt
        delta_prev = delta if s.delta_prev is None else s.delta_prev
        s.delta_prev, s.t_prev = delta, None
        if vx < st.v_min:
            x_prior, P_prior, s.x, s.P, y, S = low_speed_step(s.x, s.P, yaw_rate, delta * self._kinematic_gain, st, dt)
            return Step(s.x, s.P, y, S, x_prior, P_prior)
        beta, r = s.x.tolist()
        ff, fr, kf, kr = self.axle_forces(beta, r, delta_prev, vx)
        J, _ = self.jacobian(kf, kr, vx)
        Jdt = J * dt
        (a1, b1), (a2, b2), (a3, b3) = matrix_functions_2x2(Jdt, PHI1, EXP, EXP_HALF)
        x_prior = s.x + _poly(a1, b1, Jdt) @ np.array([(ff + fr) / (p.m * vx) - r, (p.a * ff - p.b * fr) / p.Iz]) * dt
        Ad, Ah, Q = _poly(a2, b2, Jdt), _poly(a3, b3, Jdt), self._Q
        Qd = (Q + 4.0 * Ah @ Q @ Ah.T + Ad @ Q @ Ad.T) * (dt / 6.0)
        ff, fr, kf, kr = self.axle_forces(*x_prior.tolist(), delta, vx)
        _, (c21, c22) = self.jacobian(kf, kr, vx)
        offset = x_prior - Ad @ s.x  # the predict's x⁻ = Ad x + offset, in _step2's Ad x + Bd·1 form
        d2 = (ff + fr) / p.m - c21 * x_prior[0] - c22 * x_prior[1]  # a_y(x⁻) = C x⁻ + d2·1
        R = np.array(
            ((st.gyro_noise**2, 0.0), (0.0, st.accel_noise**2 + (st.stiffness_std / p.m) ** 2 * (ff * ff + fr * fr)))
        )
        m = (*Ad.ravel().tolist(), *offset.tolist(), Qd[0, 0], Qd[0, 1], Qd[1, 1], c21, c22, d2)
        x_prior, P_prior, s.x, s.P, y, S = _step2(s.x, s.P, 1.0, (yaw_rate, ay), 1.0, m, R)
        return Step(s.x, s.P, y, S, x_prior, P_prior)

    def run(self, t, delta, yaw_rate, ay, vx, *, resume=False) -> SideslipRun:
        """:meth:`step` over a drive (inputs and start as :meth:`SideslipKF.run <kfkit.filters.SideslipKF.run>`)."""
        return _run_drive(self, _as_inputs(t, delta, yaw_rate, ay, vx), resume)
