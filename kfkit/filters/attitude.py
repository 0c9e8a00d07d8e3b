"""Lab 04: attitude (roll, pitch, yaw) from gyro + accelerometer + magnetometer.

Two filters, both reporting through :class:`AttitudeResult`:

``euler-ekf`` — the lab's 3-state EKF, state x = [φ, θ, ψ] (rad, ZYX):

    predict   x⁻ = x + f(x, ω)·dt,     P⁻ = F P Fᵀ + Q,    F = I + dt·∂f/∂x
              f = [p + (q sφ + r cφ) tθ,   q cφ − r sφ,   (q sφ + r cφ)/cθ]     (÷ cos θ, not cos φ)
              Q = G Σ_ω Gᵀ dt²,   G = ∂f/∂ω (the Euler-rate matrix),   Σ_ω = σ_ω² I
    update    z = [f_b; m_b] (m/s², µT),   h(x) = [R_bn(x)·(−g_n); R_bn(x)·m_n],   g_n = [0, 0, g]
              y = z − h(x⁻),  S = H P⁻ Hᵀ + R,  K = P⁻ Hᵀ S⁻¹,  x = x⁻ + K y (ψ wrapped)

The innovation lives in measurement space (m/s², µT), so it needs no wrapping; the yaw state
is wrapped to (−π, π] after every prediction and update. ψ enters h only through R_bn, so a
yaw of +179° and −179° give the same h. The state is singular at θ = ±90° (gimbal lock: f
divides by cos θ); the ``mekf`` filter below does not have that problem.

``mekf`` — see :class:`MultiplicativeEKF`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..frames import (G, MAG_FIELD_LONDON, accel_tilt, declination, euler_to_dcm, euler_to_quat, quat_to_dcm,
                      quat_to_euler, tilt_compensated_heading, wrap_angle)

TWO_PI = 2.0 * math.pi

#: Default per-sample gyro noise σ_ω (rad/s) of the Euler EKF: the ISM330DHCX's 5 mdps/√Hz at
#: ~100 Hz is 0.05 °/s, but a 3-state filter has no bias state, so σ_ω also has to cover the
#: residual bias after calibration (≈ 0.1–0.3 °/s): 0.3 °/s.
EULER_GYRO_NOISE = math.radians(0.3)
#: Default accelerometer σ (m/s²): sensor noise is ~0.006 m/s², but hand motion adds linear
#: acceleration the model calls noise (≈ 0.1–0.5 m/s² RMS).
EULER_ACCEL_NOISE = 0.3
#: Default magnetometer σ (µT): IIS2MDC noise 0.3 µT plus calibration residuals and local field errors.
EULER_MAG_NOISE = 1.0
#: Accelerometer gating: when |‖f‖ − g| exceeds ACCEL_GATE (m/s²) the accelerometer rows of R
#: are multiplied by ACCEL_GATE_FACTOR (its σ by √factor): the board is clearly accelerating.
ACCEL_GATE = 1.0
ACCEL_GATE_FACTOR = 100.0


# --------------------------------------------------------------------------------------
# Euler EKF: the lab's step functions (NumPy, textbook form)
# --------------------------------------------------------------------------------------
def euler_rates(euler, omega_b):
    """[φ̇, θ̇, ψ̇] (rad/s) from Euler angles [φ, θ, ψ] and body rate [p, q, r] (rad/s), ZYX:

        φ̇ = p + (q sin φ + r cos φ) tan θ,   θ̇ = q cos φ − r sin φ,   ψ̇ = (q sin φ + r cos φ) / cos θ

    Singular at cos θ = 0 (gimbal lock). Broadcasts over leading axes.
    """
    e = np.asarray(euler, dtype=float)
    w = np.asarray(omega_b, dtype=float)
    sf, cf = np.sin(e[..., 0]), np.cos(e[..., 0])
    ct, tt = np.cos(e[..., 1]), np.tan(e[..., 1])
    p, q, r = w[..., 0], w[..., 1], w[..., 2]
    u = q * sf + r * cf
    return np.stack(np.broadcast_arrays(p + u * tt, q * cf - r * sf, u / ct), axis=-1)


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
    x_new = x + euler_rates(x, omega_b) * dt
    x_new[2] = wrap_angle(x_new[2])
    return x_new, F @ np.asarray(P, dtype=float) @ F.T + np.asarray(Q, dtype=float)


def attitude_measurement(x, field_n=MAG_FIELD_LONDON):
    """h(x) = [R_bn(x)·(−g_n); R_bn(x)·m_n] (6,): specific force at rest (m/s²) and the field
    (µT, same unit as ``field_n``, NED) seen in the body frame; g_n = [0, 0, g].

    The first three are g·[sθ, −sφ cθ, −cφ cθ]; at rest and level, [0, 0, −g].
    """
    R_bn = euler_to_dcm(*np.asarray(x, dtype=float)[:3]).T
    return np.concatenate([R_bn @ np.array([0.0, 0.0, -G]), R_bn @ np.asarray(field_n, dtype=float)])


def attitude_jacobian(x, field_n=MAG_FIELD_LONDON):
    """H = ∂h/∂x (6×3) of :func:`attitude_measurement`, analytic.

    With a = cψ m_N + sψ m_E and b = −sψ m_N + cψ m_E (the horizontal field along and across the
    heading), h_m = [cθ a − sθ m_D,  sφ sθ a + cφ b + sφ cθ m_D,  cφ sθ a − sφ b + cφ cθ m_D].
    """
    phi, theta, psi = (float(v) for v in np.asarray(x, dtype=float)[:3])
    sf, cf, st, ct, sp, cp = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta), math.sin(psi), math.cos(psi)
    mN, mE, mD = (float(v) for v in field_n)
    a, b = cp * mN + sp * mE, -sp * mN + cp * mE
    m1 = sf * st * a + cf * b + sf * ct * mD
    m2 = cf * st * a - sf * b + cf * ct * mD
    return np.array([
        [0.0, G * ct, 0.0],
        [-G * cf * ct, G * sf * st, 0.0],
        [G * sf * ct, G * cf * st, 0.0],
        [0.0, -st * a - ct * mD, ct * b],
        [m2, sf * ct * a - sf * st * mD, sf * st * b - cf * a],
        [-m1, cf * ct * a - cf * st * mD, cf * st * b + sf * a],
    ])


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


def tilt_heading(acc, mag, field_n=MAG_FIELD_LONDON):
    """Initial [φ, θ, ψ] (rad) from one accelerometer (m/s²) and magnetometer (µT) sample.

    Tilt from the specific force, heading ψ = atan2(−m_y', m_x') + atan2(m_E, m_N) from the
    tilt-compensated field m' = Ry(θ) Rx(φ) m_b, rotated by the reference field's declination so
    that ψ is measured in the same NED frame as ``field_n``. ``mag`` None or NaN → ψ = 0.
    """
    roll, pitch = accel_tilt(acc)
    if mag is None or np.isnan(mag).any():
        return np.array([roll, pitch, 0.0])
    return np.array([roll, pitch, tilt_compensated_heading(mag, roll, pitch, declination(field_n))])


def learn_field(acc, mag, samples=50):
    """A reference field m_n = [H, 0, Z] (µT, magnetic NED: north is magnetic north) learned from
    the first ``samples`` magnetometer rows: each is tilt-compensated with its accelerometer tilt,
    and the horizontal magnitude H and vertical Z are averaged."""
    acc = np.asarray(acc, dtype=float)
    mag = np.asarray(mag, dtype=float)
    rows = np.flatnonzero(~np.isnan(mag).any(axis=1))[:samples]
    if rows.size == 0:
        raise ValueError("learn_field: the magnetometer has no sample (all rows NaN)")
    roll, pitch = accel_tilt(acc[rows])
    R_nb = euler_to_dcm(roll, pitch, np.zeros_like(roll))
    m_level = np.einsum("nij,nj->ni", R_nb, mag[rows])
    return np.array([np.hypot(m_level[:, 0], m_level[:, 1]).mean(), 0.0, m_level[:, 2].mean()])


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------
@dataclass
class AttitudeResult:
    """A filter's history over a recording, one row per sample.

    quat      (N, 4) w-x-y-z, body (sensor) → NED
    euler     (N, 3) [roll, pitch, yaw], rad
    P         (N, 3, 3) covariance of the attitude error, rad²: of [φ, θ, ψ] for ``euler-ekf``;
              of the small-angle rotation error (NED frame for mekf, see its docs) for ``mekf``
    y         (N, 6) innovations z − h(x⁻): accel (m/s²) in 0–2; for euler-ekf mag (µT) in 3–5,
              for mekf the heading innovation (rad) in 3 and NaN in 4–5; NaN where not used
    S         (N, 6, 6) their covariances (NaN where not used)
    nis       (N,) normalised innovation squared yᵀ S⁻¹ y over the rows used
    accel_gated (N,) True where the accelerometer rows were inflated (|‖f‖ − g| > gate)
    mag_used  (N,) True where a magnetometer update was made
    method    "euler-ekf" or "mekf"
    bias      (N, 3) gyro bias estimate, rad/s (mekf; zeros for euler-ekf)
    mag_gated (N,) True where a magnetometer sample was not used: a disturbed field or a heading
              outlier (mekf; all False for euler-ekf)
    """

    quat: np.ndarray
    euler: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray
    nis: np.ndarray
    accel_gated: np.ndarray
    mag_used: np.ndarray
    method: str
    bias: np.ndarray = field(default=None)

    mag_gated: np.ndarray = field(default=None)

    @property
    def dof(self) -> np.ndarray:
        """Innovation entries used per sample (the χ² degrees of freedom of ``nis``):
        3 or 6 for euler-ekf, 3 or 4 for mekf (its magnetometer gives one heading innovation)."""
        return np.sum(~np.isnan(self.y), axis=1)


class EulerAttitudeEKF:
    """The lab 04 filter: 3-state Euler-angle EKF, gyro predicts, accelerometer + magnetometer update.

    rate_hz      sample rate (Hz), dt = 1/rate_hz
    gyro_noise   σ_ω per sample (rad/s); Q = G Σ_ω Gᵀ dt²  (default 0.3 °/s, see EULER_GYRO_NOISE)
    accel_noise  σ of each accelerometer axis (m/s²), effective (includes linear acceleration)
    mag_noise    σ of each magnetometer axis (µT)
    field_n      reference field in NED (µT); sets the yaw reference (north of ``field_n``)
    accel_gate   |‖f‖ − g| threshold (m/s²) above which the accelerometer σ² is multiplied by
                 ``accel_gate_factor``; None disables gating
    x0, P0       initial state [φ, θ, ψ] (rad; default from the first samples, see
                 :func:`tilt_heading`) and covariance (rad²; default (5°)² tilt, (10°)² yaw)

    :meth:`step` runs one predict + update on one sample; :meth:`run` a whole recording in a
    scalar loop (≈ 10× faster than the NumPy step functions; same numbers, tested).
    """

    method = "euler-ekf"

    def __init__(self, rate_hz, gyro_noise=EULER_GYRO_NOISE, accel_noise=EULER_ACCEL_NOISE,
                 mag_noise=EULER_MAG_NOISE, field_n=MAG_FIELD_LONDON, accel_gate=ACCEL_GATE,
                 accel_gate_factor=ACCEL_GATE_FACTOR, x0=None, P0=None):
        if not rate_hz > 0:
            raise ValueError(f"EulerAttitudeEKF: rate_hz must be positive, got {rate_hz}")
        self.dt = 1.0 / float(rate_hz)
        self.gyro_noise = float(gyro_noise)
        self.accel_noise = float(accel_noise)
        self.mag_noise = float(mag_noise)
        self.field_n = np.asarray(field_n, dtype=float)
        if self.field_n.shape != (3,):
            raise ValueError(f"EulerAttitudeEKF: field_n must be a 3-vector in NED (µT), got shape {self.field_n.shape}")
        self.accel_gate = None if accel_gate is None else float(accel_gate)
        self.accel_gate_factor = float(accel_gate_factor)
        self.x = None if x0 is None else np.asarray(x0, dtype=float).copy()
        self.P = np.diag(np.radians([5.0, 5.0, 10.0]) ** 2) if P0 is None else np.asarray(P0, dtype=float).copy()

    def R(self, acc):
        """Measurement covariance diag (6,) for this specific force (gated if |‖f‖ − g| > gate)."""
        gated = self.accel_gate is not None and abs(float(np.linalg.norm(acc)) - G) > self.accel_gate
        ra = self.accel_noise ** 2 * (self.accel_gate_factor if gated else 1.0)
        return np.array([ra, ra, ra] + [self.mag_noise ** 2] * 3), gated

    def step(self, gyr, acc, mag=None):
        """One predict (gyro) + update (accel, and mag unless None/NaN) with the NumPy step
        functions. Returns (x, P, y, S) of the update."""
        acc = np.asarray(acc, dtype=float)
        mag = np.full(3, np.nan) if mag is None else np.asarray(mag, dtype=float)
        if self.x is None:
            self.x = tilt_heading(acc, mag, self.field_n)
        Q = euler_process_noise(self.x, self.gyro_noise, self.dt)
        self.x, self.P = euler_ekf_predict(self.x, self.P, gyr, self.dt, Q)
        R, _ = self.R(acc)
        self.x, self.P, y, S = euler_ekf_update(self.x, self.P, np.concatenate([acc, mag]), R, self.field_n)
        return self.x, self.P, y, S

    def run(self, gyr, acc, mag=None) -> AttitudeResult:
        """Filter a whole recording: gyr (N, 3) rad/s, acc (N, 3) m/s², mag (N, 3) µT or None;
        NaN magnetometer rows mean no new sample. Continues from the filter's current state."""
        gyr, acc, mag = _check_inputs(gyr, acc, mag)
        if self.x is None:
            first = _first_mag(mag)
            self.x = tilt_heading(acc[0], None if first is None else mag[first], self.field_n)
        return _euler_ekf_loop(self, gyr, acc, mag)


def _first_mag(mag):
    if mag is None:
        return None
    rows = np.flatnonzero(~np.isnan(mag).any(axis=1))
    return int(rows[0]) if rows.size else None


def _euler_ekf_loop(ekf: EulerAttitudeEKF, gyr, acc, mag) -> AttitudeResult:
    """The Euler EKF over N samples in plain-float arithmetic.

    Same equations as :func:`euler_ekf_predict` / :func:`euler_ekf_update`; the update is done as
    sequential scalar updates (one measurement row at a time, H fixed at x⁻), which with a
    diagonal R gives exactly the batch update's x and P, and Σ e_i²/s_i = yᵀ S⁻¹ y for the NIS.
    Innovations y = z − h(x⁻) and the priors are stored; S = H P⁻ Hᵀ + R is formed afterwards in
    one vectorised pass.
    """
    sin, cos, sqrt, pi = math.sin, math.cos, math.sqrt, math.pi
    dt = ekf.dt
    N = len(gyr)
    gq = ekf.gyro_noise ** 2 * dt * dt
    ra0 = ekf.accel_noise ** 2
    rm = ekf.mag_noise ** 2
    gate = ekf.accel_gate if ekf.accel_gate is not None else math.inf
    ra_gated = ra0 * ekf.accel_gate_factor
    mN, mE, mD = (float(v) for v in ekf.field_n)
    g = G
    W = gyr.tolist()
    A = acc.tolist()
    M = mag.tolist() if mag is not None else None
    phi, theta, psi = (float(v) for v in ekf.x)
    P = ekf.P
    p00, p01, p02, p11, p12, p22 = (float(P[0, 0]), float(P[0, 1]), float(P[0, 2]), float(P[1, 1]), float(P[1, 2]), float(P[2, 2]))

    xs = [None] * N
    Ps = [None] * N
    priors = [None] * N
    ys = [None] * N
    nis = [0.0] * N
    gated_out = [False] * N
    mag_out = [False] * N
    for k in range(N):
        p, q, r = W[k]
        # ---- predict: x⁻ = x + f dt, P⁻ = F P Fᵀ + G Σ Gᵀ dt² -----------------------------
        sf, cf, st, ct = sin(phi), cos(phi), sin(theta), cos(theta)
        if -1e-9 < ct < 1e-9:
            ct = 1e-9 if ct >= 0 else -1e-9
        tt, ic = st / ct, 1.0 / ct
        u, v = q * sf + r * cf, q * cf - r * sf
        # F = I + dt·A with A = [[v tθ, u/cθ², 0], [−u, 0, 0], [v/cθ, u sθ/cθ², 0]]
        f00 = 1.0 + dt * v * tt
        f01 = dt * u * ic * ic
        f10 = -dt * u
        f20 = dt * v * ic
        f21 = dt * u * st * ic * ic
        phi += (p + u * tt) * dt
        theta += v * dt
        psi += u * ic * dt
        if psi > pi or psi <= -pi:
            psi = pi - (pi - psi) % TWO_PI
        # M = F P (rows), then P⁻ = M Fᵀ (symmetric, upper triangle)
        a0, a1, a2 = f00 * p00 + f01 * p01, f00 * p01 + f01 * p11, f00 * p02 + f01 * p12
        b0, b1, b2 = f10 * p00 + p01, f10 * p01 + p11, f10 * p02 + p12
        c0, c1, c2 = f20 * p00 + f21 * p01 + p02, f20 * p01 + f21 * p11 + p12, f20 * p02 + f21 * p12 + p22
        # Q = σ² dt² G Gᵀ, G = [[1, sφ tθ, cφ tθ], [0, cφ, −sφ], [0, sφ/cθ, cφ/cθ]]
        g01, g02, g21, g22 = sf * tt, cf * tt, sf * ic, cf * ic
        p00 = a0 * f00 + a1 * f01 + gq * (1.0 + g01 * g01 + g02 * g02)
        p01 = a0 * f10 + a1 + gq * (g01 * cf - g02 * sf)
        p02 = a0 * f20 + a1 * f21 + a2 + gq * (g01 * g21 + g02 * g22)
        p11 = b0 * f10 + b1 + gq
        p12 = b0 * f20 + b1 * f21 + b2 + gq * (cf * g21 - sf * g22)
        p22 = c0 * f20 + c1 * f21 + c2 + gq * (g21 * g21 + g22 * g22)
        priors[k] = (phi, theta, psi, p00, p01, p02, p11, p12, p22)

        # ---- update: sequential scalar rows with H at x⁻ ---------------------------------
        fx, fy, fz = A[k]
        sf, cf, st, ct = sin(phi), cos(phi), sin(theta), cos(theta)
        ra = ra0
        if abs(sqrt(fx * fx + fy * fy + fz * fz) - g) > gate:
            ra = ra_gated
            gated_out[k] = True
        rows = [  # (innovation z − h(x⁻), H row, variance)
            (fx - g * st, 0.0, g * ct, 0.0, ra),
            (fy + g * sf * ct, -g * cf * ct, g * sf * st, 0.0, ra),
            (fz + g * cf * ct, g * sf * ct, g * cf * st, 0.0, ra),
        ]
        if M is not None:
            mx, my, mz = M[k]
            if mx == mx and my == my and mz == mz:  # not NaN
                sp, cp = sin(psi), cos(psi)
                ah, bh = cp * mN + sp * mE, -sp * mN + cp * mE
                m1 = sf * st * ah + cf * bh + sf * ct * mD
                m2 = cf * st * ah - sf * bh + cf * ct * mD
                rows.append((mx - ct * ah + st * mD, 0.0, -st * ah - ct * mD, ct * bh, rm))
                rows.append((my - m1, m2, sf * ct * ah - sf * st * mD, sf * st * bh - cf * ah, rm))
                rows.append((mz - m2, -m1, cf * ct * ah - cf * st * mD, cf * st * bh + sf * ah, rm))
                mag_out[k] = True
        d0 = d1 = d2 = 0.0
        s_nis = 0.0
        for y, h0, h1, h2, rv in rows:
            ph0 = p00 * h0 + p01 * h1 + p02 * h2
            ph1 = p01 * h0 + p11 * h1 + p12 * h2
            ph2 = p02 * h0 + p12 * h1 + p22 * h2
            s = h0 * ph0 + h1 * ph1 + h2 * ph2 + rv
            e = y - (h0 * d0 + h1 * d1 + h2 * d2)
            k0, k1, k2 = ph0 / s, ph1 / s, ph2 / s
            d0 += k0 * e
            d1 += k1 * e
            d2 += k2 * e
            p00 -= k0 * ph0
            p01 -= k0 * ph1
            p02 -= k0 * ph2
            p11 -= k1 * ph1
            p12 -= k1 * ph2
            p22 -= k2 * ph2
            s_nis += e * e / s
        phi += d0
        theta += d1
        psi += d2
        if psi > pi or psi <= -pi:
            psi = pi - (pi - psi) % TWO_PI
        ys[k] = [r_[0] for r_ in rows]
        nis[k] = s_nis
        xs[k] = (phi, theta, psi)
        Ps[k] = (p00, p01, p02, p11, p12, p22)

    ekf.x = np.array([phi, theta, psi])
    ekf.P = _sym3(np.array([Ps[-1]]))[0] if N else ekf.P
    euler = np.array(xs, dtype=float).reshape(N, 3)
    mag_used = np.array(mag_out, dtype=bool)
    gated = np.array(gated_out, dtype=bool)
    y = np.full((N, 6), np.nan)
    for k in range(N):
        y[k, :len(ys[k])] = ys[k]
    prior = np.array(priors, dtype=float).reshape(N, 9)
    r_acc = np.where(gated, ra_gated, ra0)
    S = _euler_innovation_cov(prior[:, :3], _sym3(prior[:, 3:]), r_acc, rm, ekf.field_n, mag_used)
    return AttitudeResult(quat=euler_to_quat(euler), euler=euler, P=_sym3(np.array(Ps, dtype=float).reshape(N, 6)),
                          y=y, S=S, nis=np.array(nis), accel_gated=gated, mag_used=mag_used, method="euler-ekf",
                          bias=np.zeros((N, 3)), mag_gated=np.zeros(N, dtype=bool))


def _sym3(p):
    """(N, 6) upper triangles [p00, p01, p02, p11, p12, p22] → (N, 3, 3) symmetric matrices."""
    i, j = np.triu_indices(3)
    out = np.empty((len(p), 3, 3))
    out[:, i, j] = p
    out[:, j, i] = p
    return out


def _euler_innovation_cov(x_prior, P_prior, r_acc, r_mag, field_n, mag_used):
    """S_k = H(x⁻_k) P⁻_k H(x⁻_k)ᵀ + R_k, vectorised; NaN in the magnetometer block where unused."""
    N = len(x_prior)
    if N == 0:
        return np.empty((0, 6, 6))
    H = _attitude_jacobians(x_prior, field_n)
    S = np.einsum("nij,njk,nlk->nil", H, P_prior, H)
    S[:, [0, 1, 2], [0, 1, 2]] += r_acc[:, None]
    S[:, [3, 4, 5], [3, 4, 5]] += r_mag
    S[~mag_used, 3:, :] = np.nan
    S[~mag_used, :, 3:] = np.nan
    return S


def _attitude_jacobians(x, field_n):
    """:func:`attitude_jacobian` for N states at once, (N, 6, 3)."""
    phi, theta, psi = x[:, 0], x[:, 1], x[:, 2]
    sf, cf, st, ct, sp, cp = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    mN, mE, mD = (float(v) for v in field_n)
    a, b = cp * mN + sp * mE, -sp * mN + cp * mE
    m1 = sf * st * a + cf * b + sf * ct * mD
    m2 = cf * st * a - sf * b + cf * ct * mD
    z = np.zeros_like(phi)
    return np.stack([
        np.stack([z, G * ct, z], -1),
        np.stack([-G * cf * ct, G * sf * st, z], -1),
        np.stack([G * sf * ct, G * cf * st, z], -1),
        np.stack([z, -st * a - ct * mD, ct * b], -1),
        np.stack([m2, sf * ct * a - sf * st * mD, sf * st * b - cf * a], -1),
        np.stack([-m1, cf * ct * a - cf * st * mD, cf * st * b + sf * a], -1),
    ], axis=1)


# --------------------------------------------------------------------------------------
# Multiplicative (error-state) quaternion EKF with gyro bias
# --------------------------------------------------------------------------------------
#: Default gyro white-noise density (rad/s/√Hz) of the process model: the ISM330DHCX's 5 mdps/√Hz
#: (DS13012) ×4, because under rotation the scale-factor and axis-misalignment errors (≈ 0.1–0.5 %
#: of the rate), which a bias-only model cannot represent, act as extra noise. 0.02 °/s/√Hz is
#: 0.2 °/s per sample at 104 Hz.
MEKF_GYRO_DENSITY = math.radians(0.02)
#: Default gyro bias random-walk density (rad/s/√s).
MEKF_BIAS_RW = 1e-5
#: Default accelerometer σ (m/s²), effective: sensor noise plus unmodelled linear acceleration.
MEKF_ACCEL_NOISE = 0.5
#: Default magnetometer σ (µT) per axis and sample: the IIS2MDC's 0.3 µT RMS noise plus the residual of
#: a hard/soft-iron calibration (≈ 0.5–1 µT); the same figure as the Euler EKF's. Heading σ per sample
#: = mag_noise / (horizontal field): 3° at London's 19.5 µT.
MEKF_MAG_NOISE = 1.0
#: Magnetic disturbance gates: a sample is rejected when |‖m‖ − ‖m_ref‖| > MAG_NORM_GATE·‖m_ref‖
#: or the dip angle (estimated with the current attitude) differs from the reference by > MAG_DIP_GATE.
MAG_NORM_GATE = 0.1
MAG_DIP_GATE = math.radians(10.0)
#: After a rejected magnetometer sample, the field must pass the gates for MAG_RECOVERY seconds
#: before it is used again (a disturbance fades in and out; its edges pass the gates). While the
#: field is trusted, the reference norm and dip follow it with the time constant MAG_REF_TAU (s).
#: These gates and times are VQF's defaults (Laidig & Seel 2023).
MAG_RECOVERY = 1.0
MAG_REF_TAU = 20.0
#: χ² gate (1 degree of freedom; 9 ≈ 3σ, 99.7 %) on the heading innovation, against the filter's own
#: S = H P Hᵀ + R: (1) a single sample of a trusted field whose y²/S exceeds it is skipped (an outlier
#: the norm and dip gates let through), for at most MAG_RECOVERY seconds in a row; (2) a rejected
#: field whose heading, averaged over MAG_RECOVERY, agrees with the filter's within this gate for
#: MAG_RECOVERY seconds is adopted as the new reference (a field that changed for good).
MAG_NIS_GATE = 9.0
#: Time constant (s) of the gyro-stabilised low-pass filter on the accelerometer (see MultiplicativeEKF).
ACCEL_TAU = 1.0


class MultiplicativeEKF:
    """Multiplicative (error-state) EKF: nominal quaternion q (body → NED) and gyro bias b, with a
    6-element error state δx = [δθ, δb] (rad, rad/s); δθ is a small rotation in the body frame,
    q_true = q ⊗ exp(δθ/2).

    predict   ω̂ = ω − b,  q ← q ⊗ exp(ω̂ dt / 2),
              F = [[exp(−[ω̂ dt]×), −I dt], [0, I]],  Q = diag(σ_g² dt² I, σ_bw² dt I)
    accel     y = f̄_b − Rᵀ(−g_n),  H = [[Rᵀ(−g_n)]×, 0]     (R = R_nb(q)); gated like the Euler EKF
    heading   ψ_m = atan2 of the horizontal part of R·m_b (the tilt-compensated field),
              y = wrap(ψ_ref − ψ_m),  H = [e_zᵀ R, 0],  σ_ψ = mag_noise / ‖m_h,ref‖
    reset     q ← q ⊗ exp(δθ/2) (normalised), b ← b + δb, δx ← 0

    f̄_b is the accelerometer low-passed in a gyro-stabilised frame (the idea of VQF, Laidig & Seel
    2023): a strapdown quaternion q_I integrates the bias-corrected gyro alone, f_I = R(q_I) f_b is
    low-passed with time constant ``accel_tau`` (rotation does not move gravity there, so only the
    linear acceleration — zero-mean over seconds for a board that stays in place — is averaged
    out), and f̄_b = R(q_I)ᵀ f̄_I. ``accel_tau=None`` uses the raw accelerometer.

    The magnetometer corrects heading only (a heading measurement whose H has no tilt part), so a
    disturbed field never tilts the estimate directly. Magnetic disturbances, in three layers:

    1. gates: a sample whose norm or dip angle (with the current attitude) differs from the
       reference by more than ``mag_norm_gate`` / ``mag_dip_gate`` marks the field as disturbed; it is
       trusted again once it has passed the gates for ``mag_recovery`` s;
    2. innovation gate: a trusted sample with y²/S > ``mag_nis_gate`` is skipped, for at most
       ``mag_recovery`` s in a row (a field with the right norm and dip that keeps disagreeing means the
       filter's heading, not the field, is wrong);
    3. bounded rejection: while disturbed, the heading innovations ȳ are averaged (time constant
       ``mag_recovery``, noise variance v̄ from σ_ψ²) and compared with the filter's own heading
       variance σ_h² = H P Hᵀ. When v̄ ≤ σ_h² and ȳ² ≤ ``mag_nis_gate``·(σ_h² + v̄) for ``mag_recovery``
       s, the field's heading agrees with the gyro's to within what the filter knows: it becomes the
       new reference (its averaged norm and dip) and is used again. σ_h² grows without a magnetometer
       (gyro noise, bias random walk), so any steady field is adopted in the end: at 100 Hz with the
       defaults, one whose heading agrees within seconds, one 10° off after about 3.5 minutes — about
       when the gyro alone is no better. (VQF instead uses a field again after 60 s of rejection; on
       BROAD's trial 06 that follows a field 3–4° off for the second half of the motion.)

    Knobs (defaults from the sensor noise; see the module constants):
    rate_hz        sample rate, Hz
    gyro_noise     per-sample gyro σ_g (rad/s); default MEKF_GYRO_DENSITY·√rate_hz
    gyro_bias_rw   bias random-walk density σ_bw (rad/s/√s)
    accel_noise    σ_a (m/s²), effective (includes linear acceleration)
    mag_noise      σ_m (µT)
    accel_gate, accel_gate_factor   as in :class:`EulerAttitudeEKF`
    field_n        reference field (NED, µT); sets north (its declination), its norm and dip.
                   None: learned from the first magnetometer samples (:func:`learn_field`)
    mag_norm_gate  relative norm gate (fraction of ‖m_ref‖), None = off
    mag_dip_gate   dip-angle gate (rad), None = off
    mag_recovery   seconds the field must pass the gates after a rejection before it is used again;
                   also the averaging time and duration of the innovation tests (2, 3 above)
    mag_nis_gate   χ² gate (1 dof) of the innovation tests 2 and 3; None = no innovation test, and a
                   disturbed field is rejected for as long as it fails the gates
    mag_ref_tau    time constant (s) with which the reference norm and dip follow a trusted field; None = fixed
    accel_tau      time constant (s) of the gyro-stabilised accelerometer low-pass; None = raw
    q0, bias0      initial quaternion (w-x-y-z) and gyro bias (rad/s); default from the first
                   samples (:func:`tilt_heading`) and zero
    P0             initial 6×6 error covariance; default diag((5°)², (5°)², (10°)², (0.5 °/s)²·3)
    """

    method = "mekf"

    def __init__(self, rate_hz, gyro_noise=None, gyro_bias_rw=MEKF_BIAS_RW, accel_noise=MEKF_ACCEL_NOISE,
                 mag_noise=MEKF_MAG_NOISE, accel_gate=ACCEL_GATE, accel_gate_factor=ACCEL_GATE_FACTOR, field_n=None,
                 mag_norm_gate=MAG_NORM_GATE, mag_dip_gate=MAG_DIP_GATE, mag_recovery=MAG_RECOVERY,
                 mag_nis_gate=MAG_NIS_GATE, mag_ref_tau=MAG_REF_TAU, accel_tau=ACCEL_TAU, q0=None, bias0=None,
                 P0=None):
        if not rate_hz > 0:
            raise ValueError(f"MultiplicativeEKF: rate_hz must be positive, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.gyro_noise = MEKF_GYRO_DENSITY * math.sqrt(self.rate_hz) if gyro_noise is None else float(gyro_noise)
        self.gyro_bias_rw = float(gyro_bias_rw)
        self.accel_noise = float(accel_noise)
        self.mag_noise = float(mag_noise)
        self.accel_gate = None if accel_gate is None else float(accel_gate)
        self.accel_gate_factor = float(accel_gate_factor)
        self.field_n = None if field_n is None else np.asarray(field_n, dtype=float)
        self.mag_norm_gate = None if mag_norm_gate is None else float(mag_norm_gate)
        self.mag_dip_gate = None if mag_dip_gate is None else float(mag_dip_gate)
        self.mag_recovery = float(mag_recovery)
        if not self.mag_recovery > 0:
            raise ValueError(f"MultiplicativeEKF: mag_recovery must be positive (s), got {mag_recovery}")
        self.mag_nis_gate = None if mag_nis_gate is None else float(mag_nis_gate)
        if self.mag_nis_gate is not None and not self.mag_nis_gate > 0:
            raise ValueError(f"MultiplicativeEKF: mag_nis_gate must be positive (a χ² value, 9 ≈ 3σ) or None, "
                             f"got {mag_nis_gate}")
        self.mag_ref_tau = None if mag_ref_tau is None else float(mag_ref_tau)
        self.accel_tau = float(accel_tau or 0.0)
        self.q = None if q0 is None else np.asarray(q0, dtype=float) / np.linalg.norm(q0)
        self.bias = np.zeros(3) if bias0 is None else np.asarray(bias0, dtype=float).copy()
        if P0 is None:
            P0 = np.diag(np.r_[np.radians([5.0, 5.0, 10.0]) ** 2, [math.radians(0.5) ** 2] * 3])
        self.P = np.asarray(P0, dtype=float).copy()
        self._carry = None  # the loop's gating and low-pass state, so that runs over pieces equal one run

    def run(self, gyr, acc, mag=None) -> AttitudeResult:
        """Filter a recording: gyr (N, 3) rad/s, acc (N, 3) m/s², mag (N, 3) µT or None (NaN rows =
        no new sample), one sensor frame. Continues from the current state: a recording fed in pieces
        gives the same result as in one run."""
        gyr, acc, mag = _check_inputs(gyr, acc, mag)
        if self.field_n is None:
            self.field_n = learn_field(acc, mag) if mag is not None else np.array(MAG_FIELD_LONDON)
        if self.q is None:
            first = _first_mag(mag)
            self.q = euler_to_quat(tilt_heading(acc[0], None if first is None else mag[first], self.field_n))
        return _mekf_loop(self, gyr, acc, mag)


def _mekf_loop(f: MultiplicativeEKF, gyr, acc, mag) -> AttitudeResult:
    """The MEKF over N samples: quaternion and measurement algebra on floats, covariance in NumPy."""
    sqrt, sin, cos, atan2, pi = math.sqrt, math.sin, math.cos, math.atan2, math.pi
    dt, g = f.dt, G
    N = len(gyr)
    qw, qx, qy, qz = (float(v) for v in f.q)
    bx, by, bz = (float(v) for v in f.bias)
    P = f.P.copy()
    Qd = np.diag([f.gyro_noise ** 2 * dt * dt] * 3 + [f.gyro_bias_rw ** 2 * dt] * 3)
    ra0 = f.accel_noise ** 2
    ra_gated = ra0 * f.accel_gate_factor
    gate = f.accel_gate if f.accel_gate is not None else math.inf
    mN, mE, mD = (float(v) for v in f.field_n)
    h_ref = math.hypot(mN, mE)
    psi_ref = atan2(mE, mN)
    r_psi = (f.mag_noise / h_ref) ** 2
    lpf = 1.0 - math.exp(-dt / f.accel_tau) if f.accel_tau > 0 else 1.0
    # State carried from one run() to the next (a live view feeds a recording in pieces):
    c = f._carry or {
        "k": 0,  # index of this run's first sample since the filter started
        "mag_gate": _MagGate(f, r_psi),  # the magnetometer's disturbance logic and its clocks
        "I": (1.0, 0.0, 0.0, 0.0),  # strapdown frame I: gyro-only attitude, body → I
        "f_I": tuple(float(v) for v in acc[0]),  # low-passed specific force in I
    }
    k_start, mag_gate = c["k"], c["mag_gate"]
    (iw, ix, iy, iz), (fbx, fby, fbz) = c["I"], c["f_I"]
    W = gyr.tolist()
    A = acc.tolist()
    M = mag.tolist() if mag is not None else None
    I6 = np.eye(6)
    F = np.eye(6)
    F[0:3, 3:6] = -dt * np.eye(3)
    Ha = np.zeros((3, 6))
    Hm = np.zeros(6)

    quats = [None] * N
    biases = [None] * N
    Ps = np.empty((N, 6, 6))
    y_out = np.full((N, 6), np.nan)
    S_out = np.full((N, 6, 6), np.nan)
    nis = np.zeros(N)
    gated_out = np.zeros(N, dtype=bool)
    mag_out = np.zeros(N, dtype=bool)
    mag_rej = np.zeros(N, dtype=bool)
    for k in range(N):
        # ---- predict ------------------------------------------------------------------
        wx, wy, wz = W[k]
        wx -= bx
        wy -= by
        wz -= bz
        ax_, ay_, az_ = wx * dt, wy * dt, wz * dt
        ang = sqrt(ax_ * ax_ + ay_ * ay_ + az_ * az_)
        if ang > 1e-12:
            s_ = sin(0.5 * ang) / ang
            dw, dx, dy, dz = cos(0.5 * ang), ax_ * s_, ay_ * s_, az_ * s_
        else:
            dw, dx, dy, dz = 1.0, 0.5 * ax_, 0.5 * ay_, 0.5 * az_
        qw, qx, qy, qz = (qw * dw - qx * dx - qy * dy - qz * dz, qw * dx + qx * dw + qy * dz - qz * dy,
                          qw * dy - qx * dz + qy * dw + qz * dx, qw * dz + qx * dy - qy * dx + qz * dw)
        iw, ix, iy, iz = (iw * dw - ix * dx - iy * dy - iz * dz, iw * dx + ix * dw + iy * dz - iz * dy,
                          iw * dy - ix * dz + iy * dw + iz * dx, iw * dz + ix * dy - iy * dx + iz * dw)
        # Φ = exp(−[ω̂ dt]×) = Rᵀ of the increment: rotation matrix of the conjugate of (dw, dx, dy, dz)
        F[0, 0] = 1 - 2 * (dy * dy + dz * dz)
        F[0, 1] = 2 * (dx * dy + dw * dz)
        F[0, 2] = 2 * (dx * dz - dw * dy)
        F[1, 0] = 2 * (dx * dy - dw * dz)
        F[1, 1] = 1 - 2 * (dx * dx + dz * dz)
        F[1, 2] = 2 * (dy * dz + dw * dx)
        F[2, 0] = 2 * (dx * dz + dw * dy)
        F[2, 1] = 2 * (dy * dz - dw * dx)
        F[2, 2] = 1 - 2 * (dx * dx + dy * dy)
        P = F @ P @ F.T + Qd

        # ---- accelerometer update ---------------------------------------------------------
        # R = R_nb(q); v_b = Rᵀ(−g_n) = −g·(third row of R)
        r20, r21, r22 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
        vx, vy, vz = -g * r20, -g * r21, -g * r22
        fx, fy, fz = A[k]
        if lpf < 1.0:
            # f_I = R_I f_b, low-passed in I (where rotation does not move it), back to the body frame
            n_ = 1.0 / sqrt(iw * iw + ix * ix + iy * iy + iz * iz)
            iw, ix, iy, iz = iw * n_, ix * n_, iy * n_, iz * n_
            c00, c01, c02 = 1 - 2 * (iy * iy + iz * iz), 2 * (ix * iy - iw * iz), 2 * (ix * iz + iw * iy)
            c10, c11, c12 = 2 * (ix * iy + iw * iz), 1 - 2 * (ix * ix + iz * iz), 2 * (iy * iz - iw * ix)
            c20, c21, c22 = 2 * (ix * iz - iw * iy), 2 * (iy * iz + iw * ix), 1 - 2 * (ix * ix + iy * iy)
            fbx += lpf * (c00 * fx + c01 * fy + c02 * fz - fbx)
            fby += lpf * (c10 * fx + c11 * fy + c12 * fz - fby)
            fbz += lpf * (c20 * fx + c21 * fy + c22 * fz - fbz)
            fx = c00 * fbx + c10 * fby + c20 * fbz
            fy = c01 * fbx + c11 * fby + c21 * fbz
            fz = c02 * fbx + c12 * fby + c22 * fbz
        ra = ra0
        if abs(sqrt(fx * fx + fy * fy + fz * fz) - g) > gate:
            ra = ra_gated
            gated_out[k] = True
        # H = [[v]×, 0]
        Ha[0, 1], Ha[0, 2], Ha[1, 0], Ha[1, 2], Ha[2, 0], Ha[2, 1] = -vz, vy, vz, -vx, -vy, vx
        y = np.array([fx - vx, fy - vy, fz - vz])
        PHt = P @ Ha.T
        S = Ha @ PHt
        S[0, 0] += ra
        S[1, 1] += ra
        S[2, 2] += ra
        K = np.linalg.solve(S, PHt.T).T
        dxs = K @ y
        IKH = I6 - K @ Ha
        P = IKH @ P @ IKH.T + ra * (K @ K.T)
        y_out[k, :3] = y
        S_out[k, :3, :3] = S
        nis[k] = y @ np.linalg.solve(S, y)
        qw, qx, qy, qz, bx, by, bz = _mekf_reset(qw, qx, qy, qz, bx, by, bz, dxs)

        # ---- magnetometer heading update ----------------------------------------------------
        if M is not None:
            mx, my, mz = M[k]
            if mx == mx:
                # m_n = R m_b
                r00, r01, r02 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
                r10, r11, r12 = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
                r20, r21, r22 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
                n_n = r00 * mx + r01 * my + r02 * mz
                n_e = r10 * mx + r11 * my + r12 * mz
                n_d = r20 * mx + r21 * my + r22 * mz
                hm = math.hypot(n_n, n_e)
                yp = psi_ref - atan2(n_e, n_n)
                if yp > pi or yp <= -pi:
                    yp = pi - (pi - yp) % TWO_PI
                Hm[0], Hm[1], Hm[2] = r20, r21, r22
                PH = P @ Hm
                var_h = float(Hm @ PH)
                if not mag_gate.use((k_start + k) * dt, sqrt(hm * hm + n_d * n_d), atan2(n_d, hm), yp, var_h):
                    mag_rej[k] = True
                else:
                    sp = var_h + r_psi
                    Kp = PH / sp
                    P = P - np.outer(Kp, PH)
                    P = 0.5 * (P + P.T)
                    y_out[k, 3] = yp
                    S_out[k, 3, 3] = sp
                    S_out[k, :3, 3] = S_out[k, 3, :3] = 0.0
                    nis[k] += yp * yp / sp
                    mag_out[k] = True
                    qw, qx, qy, qz, bx, by, bz = _mekf_reset(qw, qx, qy, qz, bx, by, bz, Kp * yp)
        quats[k] = (qw, qx, qy, qz)
        biases[k] = (bx, by, bz)
        Ps[k] = P

    f.q = np.array([qw, qx, qy, qz])
    f.bias = np.array([bx, by, bz])
    f.P = P
    f._carry = {"k": k_start + N, "mag_gate": mag_gate, "I": (iw, ix, iy, iz), "f_I": (fbx, fby, fbz)}
    quat = np.array(quats, dtype=float).reshape(N, 4)
    quat *= np.where(quat[:, :1] < 0, -1.0, 1.0)
    R = quat_to_dcm(quat)
    P_att_n = R @ Ps[:, :3, :3] @ np.swapaxes(R, 1, 2)  # attitude error covariance in NED
    return AttitudeResult(quat=quat, euler=quat_to_euler(quat), P=P_att_n, y=y_out, S=S_out, nis=nis,
                          accel_gated=gated_out, mag_used=mag_out, method="mekf",
                          bias=np.array(biases, dtype=float).reshape(N, 3), mag_gated=mag_rej)


class _MagGate:
    """The MEKF's magnetic-disturbance logic (see :class:`MultiplicativeEKF`, layers 1–3), one
    magnetometer sample at a time; its reference field and clocks carry from one run() to the next."""

    __slots__ = ("norm_ref", "dip_ref", "norm_gate", "dip_gate", "recovery", "nis_gate", "ref_rate", "r_psi",
                 "good_since", "t_prev", "nis_since", "mean", "adopt_since")

    def __init__(self, f: MultiplicativeEKF, r_psi):
        mN, mE, mD = (float(v) for v in f.field_n)
        self.norm_ref, self.dip_ref = math.sqrt(mN * mN + mE * mE + mD * mD), math.atan2(mD, math.hypot(mN, mE))
        self.norm_gate = f.mag_norm_gate if f.mag_norm_gate is not None else math.inf  # fraction of norm_ref
        self.dip_gate = f.mag_dip_gate if f.mag_dip_gate is not None else math.inf
        self.recovery = f.mag_recovery
        self.nis_gate = f.mag_nis_gate if f.mag_nis_gate is not None else math.inf
        self.ref_rate = 1.0 / f.mag_ref_tau if f.mag_ref_tau else 0.0
        self.r_psi = r_psi  # heading variance of one sample, rad²
        self.good_since = -math.inf  # time since which the field has passed the gates (trusted from the start)
        self.t_prev = None  # time of the previous magnetometer sample
        self.nis_since = None  # first of the trusted samples in a row that failed the innovation gate
        self.mean = None  # while disturbed: averaged [heading innovation, its noise variance, norm, dip]
        self.adopt_since = None  # since when the disturbed field's averaged heading agrees with the filter's

    def use(self, t, norm, dip, y, var_h):
        """True if the sample at time t (s) is to be used: field norm (µT) and dip (rad) seen with the
        current attitude, heading innovation y (rad) and the filter's heading variance var_h = H P Hᵀ (rad²)."""
        dt_m = t - self.t_prev if self.t_prev is not None else 0.0
        self.t_prev = t
        if abs(norm - self.norm_ref) > self.norm_gate * self.norm_ref or abs(dip - self.dip_ref) > self.dip_gate:
            self.good_since = math.inf
        elif self.good_since > t:
            self.good_since = t
        if t - self.good_since >= self.recovery:  # trusted
            self.mean = None
            if self.ref_rate:  # the reference follows a trusted field slowly
                a = min(1.0, dt_m * self.ref_rate)
                self.norm_ref += a * (norm - self.norm_ref)
                self.dip_ref += a * (dip - self.dip_ref)
            if y * y <= self.nis_gate * (var_h + self.r_psi):
                self.nis_since = None
                return True
            if self.nis_since is None:
                self.nis_since = t
            return t - self.nis_since >= self.recovery  # an outlier, unless it has lasted
        self.nis_since = None
        if self.nis_gate == math.inf:
            return False
        # disturbed: average its heading innovation, norm and dip; v = variance of the averaged noise
        if self.mean is None:
            self.mean, self.adopt_since = [y, self.r_psi, norm, dip], None
        else:
            a = 1.0 - math.exp(-dt_m / self.recovery)
            m = self.mean
            d = y - m[0]
            m[0] += a * (math.pi - (math.pi - d) % TWO_PI)  # wrapped
            m[1] = (1.0 - a) ** 2 * m[1] + a * a * self.r_psi
            m[2] += a * (norm - m[2])
            m[3] += a * (dip - m[3])
        y_mean, v_mean, norm_mean, dip_mean = self.mean
        if v_mean <= var_h and y_mean * y_mean <= self.nis_gate * (var_h + v_mean):
            if self.adopt_since is None:
                self.adopt_since = t
            if t - self.adopt_since >= self.recovery:  # agrees in heading: the field changed for good
                self.norm_ref, self.dip_ref = norm_mean, dip_mean
                self.good_since, self.mean = t - self.recovery, None
                return True
        else:
            self.adopt_since = None
        return False


def _mekf_reset(qw, qx, qy, qz, bx, by, bz, dxs):
    """Fold the error estimate into the nominal state: q ← q ⊗ exp(δθ/2) (normalised), b ← b + δb."""
    ex, ey, ez, dbx, dby, dbz = dxs.tolist()
    ex, ey, ez = 0.5 * ex, 0.5 * ey, 0.5 * ez
    qw, qx, qy, qz = (qw - qx * ex - qy * ey - qz * ez, qx + qw * ex + qy * ez - qz * ey,
                      qy + qw * ey - qx * ez + qz * ex, qz + qw * ez + qx * ey - qy * ex)
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    return qw * n, qx * n, qy * n, qz * n, bx + dbx, by + dby, bz + dbz


# --------------------------------------------------------------------------------------
# Input checks and the front door
# --------------------------------------------------------------------------------------
def _check_inputs(gyr, acc, mag):
    """Validate (N, 3) float arrays in SI units; returns them as float arrays (mag may be None)."""
    arrays = {}
    for name, arr, unit in (("gyr", gyr, "rad/s"), ("acc", acc, "m/s²"), ("mag", mag, "µT")):
        if arr is None:
            if name != "mag":
                raise ValueError(f"{name} is required ({unit}, shape (N, 3))")
            arrays[name] = None
            continue
        a = np.asarray(arr, dtype=float)
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must have shape (N, 3) in {unit}, got {a.shape}")
        arrays[name] = a
    gyr, acc, mag = arrays["gyr"], arrays["acc"], arrays["mag"]
    n = len(gyr)
    if n == 0:
        raise ValueError("gyr holds no samples")
    for name, a in (("acc", acc), ("mag", mag)):
        if a is not None and len(a) != n:
            raise ValueError(f"{name} has {len(a)} rows but gyr has {n}: the sensors must share one sample clock")
    for name, a in (("gyr", gyr), ("acc", acc)):
        bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
        if bad.size:
            raise ValueError(f"{name} row {bad[0]} is not finite ({a[bad[0]].tolist()}); only mag may have NaN rows "
                             f"(no new sample) — interpolate or drop gaps in {name}")
    acc_norm = float(np.median(np.linalg.norm(acc, axis=1)))
    if acc_norm < 3.0:
        raise ValueError(f"acc looks like it is in g, not m/s²: median ‖f‖ = {acc_norm:.3g} (expected ≈ {G}); multiply by {G}")
    if acc_norm > 50.0:
        raise ValueError(f"acc median ‖f‖ = {acc_norm:.3g} m/s² is far from g = {G}: are the units m/s² (not counts or mg)?")
    if np.abs(gyr).max() > 40.0:
        raise ValueError(f"gyr reaches {np.abs(gyr).max():.3g}: that is more than 2000 °/s in rad/s — is it in °/s? "
                         f"multiply by π/180")
    if mag is not None:
        if np.isnan(mag).all():
            mag = None
        else:
            partial = np.flatnonzero(np.isnan(mag).any(axis=1) & ~np.isnan(mag).all(axis=1))
            if partial.size:
                raise ValueError(f"mag row {partial[0]} is partly NaN ({mag[partial[0]].tolist()}): a row is either a whole "
                                 f"sample or all NaN (no new sample)")
            mag_norm = float(np.nanmedian(np.linalg.norm(mag, axis=1)))
            if not 5.0 < mag_norm < 200.0:
                hint = " (gauss? multiply by 100)" if 0.05 < mag_norm < 2 else " (tesla? multiply by 1e6)" if mag_norm < 1e-3 else ""
                raise ValueError(f"mag median ‖m‖ = {mag_norm:.3g} is not a geomagnetic field in µT (25–65 µT){hint}")
    return gyr, acc, mag


def estimate_attitude(gyr, acc, mag, rate_hz, method="euler-ekf", **tuning) -> AttitudeResult:
    """Attitude of a board from its gyro (rad/s), accelerometer (m/s², specific force) and
    magnetometer (µT; None, or NaN rows = no new sample), all (N, 3) in one right-handed sensor
    frame, sampled at ``rate_hz``.

    Returns :class:`AttitudeResult` with ``quat`` (N, 4; w-x-y-z, sensor → NED) and ``euler``.
    The world frame is NED whose north is that of the reference field: by default (``field_n``
    not given) the field is learned from the first magnetometer samples (:func:`learn_field`),
    so north is magnetic north. Without a magnetometer, yaw starts at 0 and follows the gyro.

    method "euler-ekf"  :class:`EulerAttitudeEKF` (tuning: gyro_noise, accel_noise, mag_noise,
                        field_n, accel_gate, accel_gate_factor, x0, P0)
           "mekf"       :class:`MultiplicativeEKF` (see its documented knobs)
    """
    gyr, acc, mag = _check_inputs(gyr, acc, mag)
    if not (isinstance(rate_hz, (int, float, np.floating, np.integer)) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number (Hz), got {rate_hz!r}")
    if "field_n" not in tuning and mag is not None:
        tuning["field_n"] = learn_field(acc, mag)
    if method == "euler-ekf":
        return EulerAttitudeEKF(rate_hz, **tuning).run(gyr, acc, mag)
    if method == "mekf":
        return MultiplicativeEKF(rate_hz, **tuning).run(gyr, acc, mag)
    raise ValueError(f"unknown method {method!r}; use 'euler-ekf' or 'mekf'")
