"""Lab 04: the Euler-angle EKF, as the lab teaches it (NumPy step functions) and as a class whose
``run`` is a loop over its ``step``. State x = [φ, θ, ψ] (rad, ZYX):

    predict   x⁻ = x + f(x, ω)·dt,     P⁻ = F P Fᵀ + Q,    F = I + dt·∂f/∂x
              f = [p + (q sφ + r cφ) tθ,   q cφ − r sφ,   (q sφ + r cφ)/cθ]     (÷ cos θ, not cos φ)
              Q = G Σ_ω Gᵀ dt²,   G = ∂f/∂ω (the Euler-rate matrix),   Σ_ω = σ_ω² I
    update    z = [f_b; m_b] (m/s², µT),   h(x) = [R_bn(x)·(−g_n); R_bn(x)·m_n],   g_n = [0, 0, g]
              y = z − h(x⁻),  S = H P⁻ Hᵀ + R,  K = P⁻ Hᵀ S⁻¹,  x = x⁻ + K y (ψ wrapped)

The innovation lives in measurement space (m/s², µT), so it needs no wrapping; the yaw state
is wrapped to (−π, π] after every prediction and update. ψ enters h only through R_bn, so a
yaw of +179° and −179° give the same h. The state is singular at θ = ±90° (gimbal lock: f
divides by cos θ); the MEKF (:mod:`kfkit.filters.mekf`) does not have that problem.

The same filter unrolled on floats, ≈ 10× faster, is :class:`kfkit.filters.euler_ekf_fast.FastEulerAttitudeEKF`
(what :func:`kfkit.filters.estimate_attitude` runs), held equal to this one by a test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..frames import MAG_FIELD_LONDON, G, body_rates_to_euler_rates, euler_to_dcm, wrap_angle
from .attitude_run import AttitudeRun, check_inputs, first_mag_row, tilt_heading
from .contract import State, Step, check_settings, configure, sample_period, shaped


@dataclass(frozen=True)
class EulerAttitudeEKFSettings:
    """Tuning of the lab 04 Euler EKF.

    gyro_noise       σ_ω per sample, rad/s; Q = G Σ_ω Gᵀ dt². The ISM330DHCX's 5 mdps/√Hz at ~100 Hz is
                     0.05 °/s, but a 3-state filter has no bias state, so σ_ω also covers the residual
                     bias after calibration (≈ 0.1–0.3 °/s)                                          0.3 °/s
    accel_noise      σ of each accelerometer axis, m/s², effective: sensor noise ~0.006 m/s² plus the
                     hand's linear acceleration the model calls noise (≈ 0.1–0.5 m/s² RMS)              0.3
    mag_noise        σ of each magnetometer axis, µT: IIS2MDC noise 0.3 µT plus calibration residuals
                     and local field errors                                                            1.0
    accel_gate       |‖f‖ − g| (m/s²) above which the board is clearly accelerating and the
                     accelerometer σ² is multiplied by ``accel_inflation``; None: no gating             1.0
    accel_inflation  that multiplier (the σ grows by its square root)                                 100
    """

    gyro_noise: float = math.radians(0.3)
    accel_noise: float = 0.3
    mag_noise: float = 1.0
    accel_gate: float | None = 1.0
    accel_inflation: float = 100.0

    def __post_init__(self):
        check_settings(
            self,
            positive=("accel_noise", "mag_noise", "accel_gate", "accel_inflation"),
            non_negative=("gyro_noise",),
            optional=("accel_gate",),
        )


def euler_rate_matrix(euler):
    """G(x) = ∂f/∂ω (3×3), the matrix with [φ̇, θ̇, ψ̇] = G·ω_b:

    G = [[1, sφ tθ, cφ tθ], [0, cφ, −sφ], [0, sφ/cθ, cφ/cθ]]
    """
    phi, theta = float(euler[0]), float(euler[1])
    sf, cf, tt, ct = math.sin(phi), math.cos(phi), math.tan(theta), math.cos(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


def euler_process_noise(euler, gyro_noise, dt):
    """Q = G Σ_ω Gᵀ dt² (rad²): gyro white noise σ_ω (rad/s per sample; scalar or (3,)) mapped
    through the Euler-rate matrix G(x) and integrated over one step dt (s)."""
    Gm = euler_rate_matrix(euler)
    var = np.broadcast_to(np.asarray(gyro_noise, dtype=float) ** 2, (3,))
    return (Gm * var) @ Gm.T * dt * dt


def euler_kinematics_jacobian(euler, omega_b):
    """A = ∂f/∂x (3×3, 1/s) of the 3-2-1 kinematics; with u = q sφ + r cφ, v = q cφ − r sφ:

    A = [[v tθ, u/cθ², 0], [−u, 0, 0], [v/cθ, u sθ/cθ², 0]]
    """
    phi, theta = float(euler[0]), float(euler[1])
    p, q, r = (float(v) for v in omega_b)
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    u, v = q * sf + r * cf, q * cf - r * sf
    return np.array([[v * st / ct, u / (ct * ct), 0.0], [-u, 0.0, 0.0], [v / ct, u * st / (ct * ct), 0.0]])


def euler_ekf_predict(x, P, omega_b, dt, Q):
    """EKF prediction: x⁻ = x + f(x, ω)·dt (ψ wrapped),  P⁻ = F P Fᵀ + Q,  F = I + dt·∂f/∂x.

    x [φ, θ, ψ] rad, P (3×3) rad², omega_b (3,) rad/s, dt s, Q (3×3) rad². Returns (x⁻, P⁻).
    """
    x = np.asarray(x, dtype=float)
    F = np.eye(3) + dt * euler_kinematics_jacobian(x, omega_b)
    x_new = x + body_rates_to_euler_rates(x, omega_b) * dt
    x_new[2] = wrap_angle(x_new[2])
    return x_new, F @ np.asarray(P, dtype=float) @ F.T + np.asarray(Q, dtype=float)


def attitude_measurement(x, field_n=MAG_FIELD_LONDON):
    """h(x) = [R_bn(x)·(−g_n); R_bn(x)·m_n] (6,): specific force at rest (m/s²) and the field
    (µT, same unit as ``field_n``, NED) seen in the body frame; g_n = [0, 0, g].

    The first three are g·[sθ, −sφ cθ, −cφ cθ]; at rest and level, [0, 0, −g].
    """
    R_bn = euler_to_dcm(np.asarray(x, dtype=float)[:3]).T
    return np.concatenate([R_bn @ np.array([0.0, 0.0, -G]), R_bn @ np.asarray(field_n, dtype=float)])


def attitude_jacobian(x, field_n=MAG_FIELD_LONDON):
    """H = ∂h/∂x (6×3, or (N, 6, 3) for x of shape (N, 3)) of :func:`attitude_measurement`, analytic.

    With a = cψ m_N + sψ m_E and b = −sψ m_N + cψ m_E (the horizontal field along and across the
    heading), h_m = [cθ a − sθ m_D,  sφ sθ a + cφ b + sφ cθ m_D,  cφ sθ a − sφ b + cφ cθ m_D].
    """
    x = np.asarray(x, dtype=float)
    phi, theta, psi = x[..., 0], x[..., 1], x[..., 2]
    rows = jacobian_rows(
        np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi), *(float(v) for v in field_n)
    )
    return np.stack([np.stack(np.broadcast_arrays(*row), axis=-1) for row in rows], axis=-2)


def jacobian_rows(sf, cf, st, ct, sp, cp, mN, mE, mD):
    """The six rows [∂h_i/∂φ, ∂h_i/∂θ, ∂h_i/∂ψ] of H from the sines and cosines of x = [φ, θ, ψ] and the
    field [m_N, m_E, m_D]: floats (the unrolled loop) or arrays (:func:`attitude_jacobian`) alike."""
    a, b = cp * mN + sp * mE, -sp * mN + cp * mE
    m1 = sf * st * a + cf * b + sf * ct * mD
    m2 = cf * st * a - sf * b + cf * ct * mD
    return (
        (0.0, G * ct, 0.0),
        (-G * cf * ct, G * sf * st, 0.0),
        (G * sf * ct, G * cf * st, 0.0),
        (0.0, -st * a - ct * mD, ct * b),
        (m2, sf * ct * a - sf * st * mD, sf * st * b - cf * a),
        (-m1, cf * ct * a - cf * st * mD, cf * st * b + sf * a),
    )


def euler_ekf_update(x, P, z, R, field_n=MAG_FIELD_LONDON):
    """EKF update with z = [f_b; m_b] (6,), m/s² and µT; R (6×6, or (6,) variances).

    y = z − h(x⁻),  S = H P⁻ Hᵀ + R,  K = P⁻ Hᵀ S⁻¹,  x = x⁻ + K y (ψ wrapped),
    P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ (Joseph form).
    A NaN in the magnetometer part (z[3:]) means no new magnetometer sample: only the three
    accelerometer rows are used, and y (3,), S (3×3) are returned. Returns (x, P, y, S).
    """
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    z = np.asarray(z, dtype=float)
    R = np.asarray(R, dtype=float)
    if R.ndim == 1:
        R = np.diag(R)
    if z.shape != (6,) or R.shape != (6, 6):
        raise ValueError(f"euler_ekf_update: z must have shape (6,) and R (6, 6) or (6,); got {z.shape} and {R.shape}")
    if np.isnan(z[:3]).any():
        raise ValueError(f"euler_ekf_update: the accelerometer part of z is NaN ({z[:3]})")
    rows = slice(0, 3) if np.isnan(z[3:]).any() else slice(0, 6)
    H = attitude_jacobian(x, field_n)[rows]
    R = R[rows, rows]
    y = z[rows] - attitude_measurement(x, field_n)[rows]
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T
    x_new = x + K @ y
    x_new[2] = wrap_angle(x_new[2])
    IKH = np.eye(3) - K @ H
    return x_new, IKH @ P @ IKH.T + K @ R @ K.T, y, S


class EulerAttitudeEKF:
    """The lab 04 filter: 3-state Euler-angle EKF, gyro predicts, accelerometer + magnetometer update; a
    :class:`~kfkit.filters.contract.TunedFilter`.

    dt        sample period, s (or ``rate_hz``, Hz)
    settings  :class:`EulerAttitudeEKFSettings`; keyword changes apply on top:
              ``EulerAttitudeEKF(rate_hz=104, accel_noise=0.5)``
    field_n   reference field in NED (µT); sets the yaw reference (north of ``field_n``)
    x0, P0    initial state [φ, θ, ψ] (rad; None: from the first samples, see :func:`tilt_heading`)
              and covariance (rad²; default (5°)² tilt, (10°)² yaw), one step before the first sample

    :meth:`step` runs one predict + update on one sample with the NumPy step functions the lab
    writes; :meth:`run` is a loop over :meth:`step`.
    """

    method = "euler-ekf"

    def __init__(
        self,
        dt=None,
        settings: EulerAttitudeEKFSettings | None = None,
        *,
        rate_hz=None,
        field_n=MAG_FIELD_LONDON,
        x0=None,
        P0=None,
        **changes,
    ):
        owner = type(self).__name__
        self.dt = sample_period(owner, dt, rate_hz)
        self.settings = configure(EulerAttitudeEKFSettings, settings, changes, owner)
        self.field_n = np.asarray(field_n, dtype=float)
        if self.field_n.shape != (3,):
            raise ValueError(f"{owner}: field_n must be a 3-vector in NED (µT), got shape {self.field_n.shape}")
        self._x0, self._P0 = None, np.diag(np.radians([5.0, 5.0, 10.0]) ** 2)
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start; a given x0 [φ, θ, ψ] or P0 (3×3) replaces the start's."""
        owner = type(self).__name__
        if x0 is not None:
            self._x0 = shaped(owner, "x0", x0, (3,))
        if P0 is not None:
            self._P0 = shaped(owner, "P0", P0, (3, 3))
        self.state = State(None if self._x0 is None else self._x0.copy(), self._P0.copy())

    def measurement_noise(self, acc):
        """(R, gated): R = diag of the 6 measurement variances [σ_a², σ_a², σ_a², σ_m², σ_m², σ_m²] (m²/s⁴, µT²)
        for this specific force ``acc`` (m/s²), with σ_a² × accel_inflation where gated = |‖f‖ − g| > accel_gate."""
        st = self.settings
        gated = st.accel_gate is not None and abs(float(np.linalg.norm(acc)) - G) > st.accel_gate
        ra = st.accel_noise**2 * (st.accel_inflation if gated else 1.0)
        return np.array([ra, ra, ra] + [st.mag_noise**2] * 3), gated

    def step(self, gyr, acc, mag=None) -> Step:
        """One predict (gyro, rad/s) + update (accel, m/s², and mag, µT, unless None/NaN) with the NumPy
        step functions → Step(x, P, y (6,), S (6×6), x⁻, P⁻); the magnetometer part of y and S is NaN without one."""
        s = self.state
        acc = np.asarray(acc, dtype=float)
        mag = np.full(3, np.nan) if mag is None else np.asarray(mag, dtype=float)
        if s.x is None:
            s.x = tilt_heading(acc, mag, self.field_n)
        Q = euler_process_noise(s.x, self.settings.gyro_noise, self.dt)
        x_prior, P_prior = euler_ekf_predict(s.x, s.P, gyr, self.dt, Q)
        R, _ = self.measurement_noise(acc)
        s.x, s.P, y_used, S_used = euler_ekf_update(x_prior, P_prior, np.concatenate([acc, mag]), R, self.field_n)
        y, S = np.full(6, np.nan), np.full((6, 6), np.nan)
        m = len(y_used)
        y[:m], S[:m, :m] = y_used, S_used
        return Step(s.x, s.P, y, S, x_prior, P_prior)

    def run(self, gyr, acc, mag=None, *, resume=False) -> AttitudeRun:
        """:meth:`step` over a recording: gyr (N, 3) rad/s, acc (N, 3) m/s², mag (N, 3) µT or None;
        NaN magnetometer rows mean no new sample. From the start (x0 None: from the first samples), or from the
        current state with ``resume=True``."""
        gyr, acc, mag = self._start(gyr, acc, mag, resume)
        N = len(gyr)
        mags = np.full((N, 3), np.nan) if mag is None else mag
        x, P, y, S = np.empty((N, 3)), np.empty((N, 3, 3)), np.empty((N, 6)), np.empty((N, 6, 6))
        x_prior, P_prior = np.empty((N, 3)), np.empty((N, 3, 3))
        gated = np.zeros(N, dtype=bool)
        for k in range(N):
            s = self.step(gyr[k], acc[k], mags[k])
            x[k], P[k], y[k], S[k], x_prior[k], P_prior[k] = s.x, s.P, s.y, s.S, s.x_prior, s.P_prior
            gated[k] = self.measurement_noise(acc[k])[1]
        used = ~np.isnan(y)
        nis = np.array([y[k, u] @ np.linalg.solve(S[k][np.ix_(u, u)], y[k, u]) for k, u in enumerate(used)])
        return AttitudeRun(
            x,
            P,
            y,
            S,
            x_prior,
            P_prior,
            nis=nis,
            accel_gated=gated,
            mag_used=used[:, 3],
            mag_gated=np.zeros(N, dtype=bool),
            method=self.method,
        )

    def _start(self, gyr, acc, mag, resume):
        """Checked inputs of a run; the state at the start unless ``resume``, and from the first samples (the first
        accelerometer sample and the first magnetometer sample) if it has none yet."""
        gyr, acc, mag = check_inputs(gyr, acc, mag)
        if not resume:
            self.reset()
        if self.state.x is None:
            first = first_mag_row(mag)
            self.state.x = tilt_heading(acc[0], None if first is None else mag[first], self.field_n)
        return gyr, acc, mag
