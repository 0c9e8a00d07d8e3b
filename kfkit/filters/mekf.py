"""Lab 04's multiplicative (error-state) quaternion EKF with gyro bias: :class:`MultiplicativeEKF`,
tuned by :class:`MekfSettings`, carrying a :class:`MekfState`, its update written as named steps
(predict, stabilised accelerometer, accelerometer update, heading update, reset); the magnetometer
gate is :class:`kfkit.filters.mag_gate.MagGate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..frames import (
    MAG_FIELD_LONDON,
    G,
    euler_to_quat,
    quat_multiply_f,
    quat_normalise_f,
    quat_to_dcm,
    quat_to_dcm_f,
    rotvec_to_quat_f,
    wrap_angle_f,
)
from .attitude_run import AttitudeRun, check_inputs, first_mag_row, learn_field, tilt_heading
from .linear import Step, configure, require_positive
from .mag_gate import MagGate


@dataclass(frozen=True)
class MekfSettings:
    """Tuning of the MEKF: every field with its meaning, unit and default.

    gyro_noise         per-sample gyro σ_g, rad/s; None: gyro_density·√rate_hz                          None
    gyro_density       gyro white-noise density, rad/s/√Hz: the ISM330DHCX's 5 mdps/√Hz (DS13012) ×4,
                       because under rotation the scale-factor and axis-misalignment errors (≈ 0.1–0.5 %
                       of the rate), which a bias-only model cannot represent, act as extra noise
                       (0.2 °/s per sample at 104 Hz)                                                 0.02 °/s/√Hz
    gyro_bias_rw       gyro bias random-walk density σ_bw, rad/s/√s                                      1e-5
    accel_noise        σ_a, m/s², effective: sensor noise plus unmodelled linear acceleration             0.5
    mag_noise          σ_m per axis and sample, µT: the IIS2MDC's 0.3 µT RMS noise plus the residual of a
                       hard/soft-iron calibration (≈ 0.5–1 µT); heading σ = mag_noise / ‖m_h‖
                       (3° at London's 19.5 µT)                                                           1.0
    accel_gate         |‖f‖ − g| (m/s²) above which the accelerometer σ² is multiplied by
                       ``accel_gate_factor``; None: no gating                                             1.0
    accel_gate_factor  that multiplier                                                                    100
    mag_norm_gate      a sample is disturbed when |‖m‖ − ‖m_ref‖| > mag_norm_gate·‖m_ref‖; None = off    0.1
    mag_dip_gate       … or when its dip angle (with the current attitude) is off by more, rad; None = off 10°
    mag_recovery       s the field must pass the gates after a rejection before it is used again (a
                       disturbance fades in and out; its edges pass the gates); also the averaging time
                       and duration of the innovation tests                                               1.0
    mag_nis_gate       χ² gate (1 dof; 9 ≈ 3σ) on the heading innovation against S = H P Hᵀ + R: a trusted
                       sample above it is skipped (for at most mag_recovery s in a row); a rejected field
                       whose averaged heading agrees within it for mag_recovery s is adopted as the new
                       reference. None: no innovation test                                                9.0
    mag_ref_tau        time constant (s) with which the reference norm and dip follow a trusted field;
                       None = fixed                                                                      20.0
    accel_tau          time constant (s) of the gyro-stabilised accelerometer low-pass; None = raw       1.0

    The gates and times are VQF's defaults (Laidig & Seel 2023).
    """

    gyro_noise: float | None = None
    gyro_density: float = math.radians(0.02)
    gyro_bias_rw: float = 1e-5
    accel_noise: float = 0.5
    mag_noise: float = 1.0
    accel_gate: float | None = 1.0
    accel_gate_factor: float = 100.0
    mag_norm_gate: float | None = 0.1
    mag_dip_gate: float | None = math.radians(10.0)
    mag_recovery: float = 1.0
    mag_nis_gate: float | None = 9.0
    mag_ref_tau: float | None = 20.0
    accel_tau: float | None = 1.0

    def __post_init__(self):
        require_positive(
            "MekfSettings",
            zero_ok=("gyro_noise", "gyro_bias_rw", "mag_ref_tau", "accel_tau"),
            none_ok=(
                "gyro_noise",
                "accel_gate",
                "mag_norm_gate",
                "mag_dip_gate",
                "mag_nis_gate",
                "mag_ref_tau",
                "accel_tau",
            ),
            gyro_noise=self.gyro_noise,
            gyro_density=self.gyro_density,
            gyro_bias_rw=self.gyro_bias_rw,
            accel_noise=self.accel_noise,
            mag_noise=self.mag_noise,
            accel_gate=self.accel_gate,
            accel_gate_factor=self.accel_gate_factor,
            mag_norm_gate=self.mag_norm_gate,
            mag_dip_gate=self.mag_dip_gate,
            mag_recovery=self.mag_recovery,
            mag_nis_gate=self.mag_nis_gate,
            mag_ref_tau=self.mag_ref_tau,
            accel_tau=self.accel_tau,
        )


@dataclass
class MekfCoefficients:
    """What the settings, the rate and the reference field give once (VQF's "coefficients").

    Qd        6×6 discrete process noise diag(σ_g² dt² I, σ_bw² dt I)
    ra, ra_gated  accelerometer variance (m²/s⁴), ungated and gated;  gate  |‖f‖ − g| threshold (m/s²)
    psi_ref   heading of the reference field, rad;  r_psi  heading variance of one sample, rad²
    lpf       low-pass step 1 − exp(−dt/accel_tau) (1: raw accelerometer)
    """

    Qd: np.ndarray
    ra: float
    ra_gated: float
    gate: float
    psi_ref: float
    r_psi: float
    lpf: float


@dataclass
class MekfState:
    """What the MEKF carries from one sample to the next, so that a recording fed in pieces gives the
    same result as one run.

    q          nominal quaternion (w, x, y, z), body → NED
    bias       gyro bias (x, y, z), rad/s
    P          6×6 covariance of the error state [δθ (body, rad), δb (rad/s)]
    k          samples filtered since the start
    strapdown  gyro-only attitude (w, x, y, z), body → I, of the accelerometer low-pass
    f_I        low-passed specific force in I, m/s²
    mag_gate   the magnetometer gate and its clocks
    """

    q: tuple
    bias: tuple
    P: np.ndarray
    k: int
    strapdown: tuple
    f_I: tuple
    mag_gate: MagGate


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
    disturbed field never tilts the estimate directly. Magnetic disturbances, in three layers
    (:class:`MagGate`):

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

    rate_hz    sample rate, Hz
    settings   :class:`MekfSettings`; keyword changes apply on top: ``MultiplicativeEKF(104, accel_tau=None)``
    field_n    reference field (NED, µT); sets north (its declination), its norm and dip.
               None: learned from the first magnetometer samples of the first run (:func:`learn_field`)
    q0, bias0  initial quaternion (w-x-y-z) and gyro bias (rad/s); default from the first
               samples (:func:`tilt_heading`) and zero
    P0         initial 6×6 error covariance; default diag((5°)², (5°)², (10°)², (0.5 °/s)²·3)
    """

    method = "mekf"

    def __init__(
        self, rate_hz, settings: MekfSettings | None = None, *, field_n=None, q0=None, bias0=None, P0=None, **changes
    ):
        require_positive("MultiplicativeEKF", rate_hz=rate_hz)
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.settings = configure(MekfSettings, settings, changes, "MultiplicativeEKF")
        self.field_n = None if field_n is None else np.asarray(field_n, dtype=float)
        self._q0 = None if q0 is None else tuple(float(v) for v in np.asarray(q0, dtype=float) / np.linalg.norm(q0))
        self._bias0 = (0.0, 0.0, 0.0) if bias0 is None else tuple(float(v) for v in bias0)
        if P0 is None:
            P0 = np.diag(np.r_[np.radians([5.0, 5.0, 10.0]) ** 2, [math.radians(0.5) ** 2] * 3])
        self._P0 = np.asarray(P0, dtype=float).copy()
        self.state: MekfState | None = None  # set by the first step or run
        self.coefficients: MekfCoefficients | None = None

    # ---- the start ---------------------------------------------------------------------------
    def _start(self, acc, mag):
        """State and coefficients from the first samples acc (N, 3), mag (N, 3) or None."""
        st, dt = self.settings, self.dt
        if self.field_n is None:
            self.field_n = learn_field(acc, mag) if mag is not None else np.array(MAG_FIELD_LONDON)
        mN, mE, mD = (float(v) for v in self.field_n)
        r_psi = (st.mag_noise / math.hypot(mN, mE)) ** 2
        gyro_noise = st.gyro_density * math.sqrt(self.rate_hz) if st.gyro_noise is None else st.gyro_noise
        ra = st.accel_noise**2
        self.coefficients = MekfCoefficients(
            Qd=np.diag([gyro_noise**2 * dt * dt] * 3 + [st.gyro_bias_rw**2 * dt] * 3),
            ra=ra,
            ra_gated=ra * st.accel_gate_factor,
            gate=st.accel_gate if st.accel_gate is not None else math.inf,
            psi_ref=math.atan2(mE, mN),
            r_psi=r_psi,
            lpf=1.0 - math.exp(-dt / st.accel_tau) if st.accel_tau else 1.0,
        )
        q = self._q0
        if q is None:
            first = first_mag_row(mag)
            q = tuple(
                float(v)
                for v in euler_to_quat(tilt_heading(acc[0], None if first is None else mag[first], self.field_n))
            )
        gate = MagGate(
            self.field_n, r_psi, st.mag_norm_gate, st.mag_dip_gate, st.mag_recovery, st.mag_nis_gate, st.mag_ref_tau
        )
        self.state = MekfState(
            q=q,
            bias=self._bias0,
            P=self._P0.copy(),
            k=0,
            strapdown=(1.0, 0.0, 0.0, 0.0),
            f_I=tuple(float(v) for v in acc[0]),
            mag_gate=gate,
        )
        self._F = np.eye(6)  # work arrays of the steps, filled in place
        self._F[0:3, 3:6] = -dt * np.eye(3)
        self._Ha, self._Hm, self._I6 = np.zeros((3, 6)), np.zeros(6), np.eye(6)

    # ---- one sample, as named steps ------------------------------------------------------------
    def step(self, gyr, acc, mag=None) -> Step:
        """One sample: gyr (3,) rad/s, acc (3,) m/s², mag (3,) µT or None/NaN (no new sample) →
        Step(x = [q (w ≥ 0), b] (7,), P (6×6, body-frame error), y (6,), S (6×6)); y[3] is the heading
        innovation (rad), y[4:6] NaN; NaN where no update was made."""
        acc = np.asarray(acc, dtype=float)
        mag = None if mag is None else np.asarray(mag, dtype=float)
        if self.state is None:
            self._start(acc[None], None if mag is None or np.isnan(mag).any() else mag[None])
        y, S = np.full(6, np.nan), np.full((6, 6), np.nan)
        self._sample(*(float(v) for v in gyr), *acc.tolist(), None if mag is None else mag.tolist(), y, S)
        q = np.array(self.state.q)
        return Step(np.r_[q if q[0] >= 0 else -q, self.state.bias], self.state.P, y, S)

    def _sample(self, wx, wy, wz, fx, fy, fz, m, y, S):
        """predict → stabilised accelerometer → accelerometer update → heading update; writes the
        innovations and their covariances into y (6,) and S (6×6) and returns (nis, gated, used, rejected)."""
        self._predict(wx, wy, wz)
        y_a, S_a, gated = self._accel_update(*self._stabilised_accel(fx, fy, fz))
        y[:3], S[:3, :3] = y_a, S_a
        nis = y_a @ np.linalg.solve(S_a, y_a)
        used = rejected = False
        if m is not None and m[0] == m[0]:  # a new magnetometer sample
            heading = self._heading_update(*m)
            if heading is None:
                rejected = True
            else:
                y[3], S[3, 3] = heading
                S[:3, 3] = S[3, :3] = 0.0
                nis += y[3] * y[3] / S[3, 3]
                used = True
        self.state.k += 1
        return nis, gated, used, rejected

    def _predict(self, wx, wy, wz):
        """ω̂ = ω − b;  q ← q ⊗ exp(ω̂ dt/2) (and the strapdown q_I with it);  P ← F P Fᵀ + Q, F's attitude
        block Φ = exp(−[ω̂ dt]×) = Rᵀ of the increment."""
        s, dt = self.state, self.dt
        bx, by, bz = s.bias
        wx -= bx
        wy -= by
        wz -= bz
        dq = rotvec_to_quat_f(wx * dt, wy * dt, wz * dt)
        s.q = quat_multiply_f(s.q, dq)
        s.strapdown = quat_multiply_f(s.strapdown, dq)
        F = self._F  # the rotation matrix of dq's conjugate: R(dq)ᵀ
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_dcm_f(dq)
        F[0, 0], F[0, 1], F[0, 2] = r00, r10, r20
        F[1, 0], F[1, 1], F[1, 2] = r01, r11, r21
        F[2, 0], F[2, 1], F[2, 2] = r02, r12, r22
        s.P = F @ s.P @ F.T + self.coefficients.Qd

    def _stabilised_accel(self, fx, fy, fz):
        """f̄_b: f_I = R(q_I) f_b low-passed in I (where rotation does not move gravity), back to the body
        frame; the raw f_b when accel_tau is None."""
        lpf, s = self.coefficients.lpf, self.state
        if lpf >= 1.0:
            return fx, fy, fz
        s.strapdown = quat_normalise_f(s.strapdown)
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = quat_to_dcm_f(s.strapdown)
        fbx, fby, fbz = s.f_I
        fbx += lpf * (c00 * fx + c01 * fy + c02 * fz - fbx)
        fby += lpf * (c10 * fx + c11 * fy + c12 * fz - fby)
        fbz += lpf * (c20 * fx + c21 * fy + c22 * fz - fbz)
        s.f_I = (fbx, fby, fbz)
        return (c00 * fbx + c10 * fby + c20 * fbz, c01 * fbx + c11 * fby + c21 * fbz, c02 * fbx + c12 * fby + c22 * fbz)

    def _accel_update(self, fx, fy, fz):
        """y = f̄_b − v_b with v_b = Rᵀ(−g_n) = −g·(third row of R), H = [[v_b]×, 0], R = σ_a² I (gated:
        × accel_gate_factor); Joseph-form update, then the reset. Returns (y, S, gated)."""
        s, c = self.state, self.coefficients
        r20, r21, r22 = quat_to_dcm_f(s.q)[6:]
        vx, vy, vz = -G * r20, -G * r21, -G * r22
        gated = abs(math.sqrt(fx * fx + fy * fy + fz * fz) - G) > c.gate
        ra = c.ra_gated if gated else c.ra
        Ha = self._Ha
        Ha[0, 1], Ha[0, 2], Ha[1, 0], Ha[1, 2], Ha[2, 0], Ha[2, 1] = -vz, vy, vz, -vx, -vy, vx
        y = np.array([fx - vx, fy - vy, fz - vz])
        P = s.P
        PHt = P @ Ha.T
        S = Ha @ PHt
        S[0, 0] += ra
        S[1, 1] += ra
        S[2, 2] += ra
        K = np.linalg.solve(S, PHt.T).T
        IKH = self._I6 - K @ Ha
        s.P = IKH @ P @ IKH.T + ra * (K @ K.T)
        self._reset(K @ y)
        return y, S, gated

    def _heading_update(self, mx, my, mz):
        """ψ_m of the tilt-compensated field R·m_b, y = wrap(ψ_ref − ψ_m), H = [third row of R, 0]; if the
        gate passes the sample, the scalar update and the reset. Returns (y, S), or None if gated out."""
        s, c = self.state, self.coefficients
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_dcm_f(s.q)
        n_n = r00 * mx + r01 * my + r02 * mz
        n_e = r10 * mx + r11 * my + r12 * mz
        n_d = r20 * mx + r21 * my + r22 * mz
        hm = math.hypot(n_n, n_e)
        y = wrap_angle_f(c.psi_ref - math.atan2(n_e, n_n))
        Hm = self._Hm
        Hm[0], Hm[1], Hm[2] = r20, r21, r22
        PH = s.P @ Hm
        var_h = float(Hm @ PH)
        if not s.mag_gate.use(s.k * self.dt, math.sqrt(hm * hm + n_d * n_d), math.atan2(n_d, hm), y, var_h):
            return None
        S = var_h + c.r_psi
        K = PH / S
        P = s.P - np.outer(K, PH)
        s.P = 0.5 * (P + P.T)
        self._reset(K * y)
        return y, S

    def _reset(self, dx):
        """Fold the error estimate δx = [δθ, δb] into the nominal state: q ← q ⊗ exp(δθ/2) (normalised),
        b ← b + δb."""
        s = self.state
        ex, ey, ez, dbx, dby, dbz = dx.tolist()
        ex, ey, ez = 0.5 * ex, 0.5 * ey, 0.5 * ez
        bx, by, bz = s.bias
        s.q, s.bias = quat_normalise_f(quat_multiply_f(s.q, (1.0, ex, ey, ez))), (bx + dbx, by + dby, bz + dbz)

    # ---- a recording ---------------------------------------------------------------------------
    def run(self, gyr, acc, mag=None) -> AttitudeRun:
        """The named steps over a recording: gyr (N, 3) rad/s, acc (N, 3) m/s², mag (N, 3) µT or None
        (NaN rows = no new sample), one sensor frame. Continues from the current state: a recording fed
        in pieces gives the same result as one run."""
        gyr, acc, mag = check_inputs(gyr, acc, mag)
        if self.state is None:
            self._start(acc, mag)
        N = len(gyr)
        y, S = np.full((N, 6), np.nan), np.full((N, 6, 6), np.nan)
        x, Ps = np.empty((N, 7)), np.empty((N, 6, 6))
        nis, gated, used, rejected = (
            np.zeros(N),
            np.zeros(N, dtype=bool),
            np.zeros(N, dtype=bool),
            np.zeros(N, dtype=bool),
        )
        M = mag.tolist() if mag is not None else [None] * N
        sample, s = self._sample, self.state
        for k, (w, f, m) in enumerate(zip(gyr.tolist(), acc.tolist(), M)):
            nis[k], gated[k], used[k], rejected[k] = sample(*w, *f, m, y[k], S[k])
            x[k, :4], x[k, 4:] = s.q, s.bias
            Ps[k] = s.P
        x[:, :4] *= np.where(x[:, :1] < 0, -1.0, 1.0)
        R = quat_to_dcm(x[:, :4])
        P_att_n = R @ Ps[:, :3, :3] @ np.swapaxes(R, 1, 2)  # attitude error covariance in NED
        return AttitudeRun(
            x, P_att_n, y, S, nis=nis, accel_gated=gated, mag_used=used, mag_gated=rejected, method=self.method
        )
