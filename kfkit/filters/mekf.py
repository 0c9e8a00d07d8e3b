"""Lab 04's multiplicative (error-state) quaternion EKF with gyro bias: :class:`MultiplicativeEKF`, tuned by
:class:`MultiplicativeEKFSettings`, carrying a :class:`MultiplicativeEKFState`, its update written as named steps
(predict, rest detection, zero-rate update, stabilised accelerometer, accelerometer update, heading update, reset);
the magnetometer gate is :class:`kfkit.filters.mag_gate.MagGate`.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..frames import (
    MAG_FIELD_LONDON,
    G,
    euler_to_quat,
    quat_multiply_f,
    quat_normalise_f,
    quat_to_dcm_f,
    rotvec_to_quat_f,
    wrap_angle_f,
)
from .attitude_run import AttitudeRun, check_inputs, first_mag_row, learn_field, tilt_heading
from .contract import Step, check_settings, configure, sample_period, shaped
from .error_covariance import (
    BIAS,
    NOTHING_KEPT,
    TILT,
    TILT_AND_BIAS,
    diagonal_S,
    propagate,
    scalar_update,
    times_attitude_row,
)
from .mag_gate import MagGate


@dataclass(frozen=True)
class MultiplicativeEKFSettings:
    """Tuning of the MEKF: every field with its meaning, unit and default.

    gyro_noise       σ of a gyro sample, rad/s; None: gyro_density·√rate                               None
    gyro_density     gyro white-noise density, rad/s/√Hz: the ISM330DHCX's 5 mdps/√Hz (DS13012) ×4,
                     because under rotation the scale-factor and axis-misalignment errors (0.1–0.5 % of
                     the rate), which a bias-only model cannot represent, act as extra noise       0.02 °/s/√Hz
    gyro_bias_rw     gyro-bias random-walk density (σ), rad/s/√s                                         1e-5
    accel_noise      σ of an accelerometer sample, m/s²; None: accel_density·√rate                     None
    accel_density    accelerometer noise density, m/s²/√Hz, effective: what is left of the linear
                     acceleration after the low-pass, and the sensor's own 0.07 mg/√Hz. As a density
                     the tilt correction's time constant, accel_density / (g·gyro_density), is the
                     same at every sample rate                                                         0.002
    accel_tau        time constant of the accelerometer low-pass (in a gyro-stabilised frame), s;
                     None: the raw samples                                                               1.0
    accel_dynamic    linear acceleration (RMS of what the low-pass removes) at which the
                     accelerometer's variance doubles, m/s²: σ_a² (1 + a_lin²/accel_dynamic²);
                     None: a fixed variance                                                              1.0
    mag_noise        σ of a magnetometer sample per axis, µT; None: mag_density / √Δt_m, Δt_m the
                     time since the previous magnetometer sample                                        None
    mag_density      magnetometer noise density, µT/√Hz, effective: the IIS2MDC's 0.03 µT/√Hz plus what
                     a hard/soft-iron calibration and the room leave; the heading's σ is σ_m / ‖m_h‖       0.1
    rest_gyro        rest detection's threshold on the gyro, rad/s: the largest deviation of a sample
                     from its low-pass, and of the low-pass from zero on each axis; None: no rest
                     detection (the bias is learned from the accelerometer and magnetometer always)    2 °/s
    rest_accel       rest detection's threshold on the accelerometer, m/s²: the largest deviation of a
                     sample from its low-pass                                                            0.5
    rest_time        time both must stay within their thresholds before the IMU counts as at rest, s:
                     then the gyro reads its bias (zero-rate update); once measured at rest, the bias
                     is frozen in motion                                                                 1.5
    rest_tau         time constant of the rest detector's low-passes, s                                  0.5
    rest_margin      age of the gyro sample a zero-rate update uses, s: a motion that starts slowly
                     passes the rest tests for its first few tenths of a second, so only a sample
                     followed by rest_margin s more of rest is taken to read the bias alone               0.5
    mag_norm_gate    threshold on the field norm, a fraction of the reference's: a sample is disturbed
                     when |‖m‖ − ‖m_ref‖| > mag_norm_gate·‖m_ref‖; None: no norm gate                   0.1
    mag_dip_gate     threshold on the dip angle (seen with the current attitude), rad; None: no dip gate  10°
    mag_recovery     time a field must pass the gates after a rejection before it is used again, s (a
                     disturbance fades in and out; its edges pass the gates); also the averaging time
                     and duration of the innovation tests                                                1.0
    mag_nis_gate     threshold on the heading innovation's NIS, χ² (1 dof; 9 = 3σ) against S = H P Hᵀ + R:
                     a trusted sample above it is skipped (for at most mag_recovery s in a row); a
                     rejected field whose averaged heading agrees within it for mag_recovery s is
                     adopted as the new reference. None: no innovation test                              9.0
    mag_ref_tau      time constant of the gates' reference field, s, with which its norm and dip follow a
                     trusted field; None: fixed, those of the field at the start (a field that changes
                     for good is adopted by the innovation test; one the reference followed would not be
                     rejected: on BROAD's A session the field a few decimetres above the rest spot is 7 %
                     stronger)                                                                          None

    The rest detector's thresholds and times, the accelerometer's stabilised low-pass and the magnetometer
    gates are VQF's (Laidig & Seel 2023), whose defaults they keep.
    """

    gyro_noise: float | None = None
    gyro_density: float = math.radians(0.02)
    gyro_bias_rw: float = 1e-5
    accel_noise: float | None = None
    accel_density: float = 0.002
    accel_tau: float | None = 1.0
    accel_dynamic: float | None = 1.0
    mag_noise: float | None = None
    mag_density: float = 0.1
    rest_gyro: float | None = math.radians(2.0)
    rest_accel: float = 0.5
    rest_time: float = 1.5
    rest_tau: float = 0.5
    rest_margin: float = 0.5
    mag_norm_gate: float | None = 0.1
    mag_dip_gate: float | None = math.radians(10.0)
    mag_recovery: float = 1.0
    mag_nis_gate: float | None = 9.0
    mag_ref_tau: float | None = None

    def __post_init__(self):
        check_settings(
            self,
            positive=(
                "gyro_density",
                "accel_noise",
                "accel_density",
                "accel_tau",
                "accel_dynamic",
                "mag_noise",
                "mag_density",
                "rest_gyro",
                "rest_accel",
                "rest_tau",
                "mag_norm_gate",
                "mag_dip_gate",
                "mag_recovery",
                "mag_nis_gate",
                "mag_ref_tau",
            ),
            non_negative=("gyro_noise", "gyro_bias_rw", "rest_time", "rest_margin"),
            optional=(
                "gyro_noise",
                "accel_noise",
                "accel_tau",
                "accel_dynamic",
                "mag_noise",
                "rest_gyro",
                "mag_norm_gate",
                "mag_dip_gate",
                "mag_nis_gate",
                "mag_ref_tau",
            ),
        )


@dataclass
class MultiplicativeEKFCoefficients:
    """What the settings, the rate and the reference field give once, at the start (VQF's "coefficients").

    field_n    the reference field in NED, µT (the constructor's, or learned from the first samples)
    q_angle    process noise of the attitude per step, σ_g² dt², rad²  (Q = diag(q_angle I, q_bias I))
    q_bias     process noise of the bias per step, σ_bw² dt, (rad/s)²
    r_gyro     variance of one gyro sample, (rad/s)²: the zero-rate update's R
    r_accel    variance of one accelerometer sample at rest, m²/s⁴
    inv_dyn2   1 / accel_dynamic², s⁴/m² (0: a fixed variance)
    psi_ref    heading of the reference field, rad
    r_psi      heading variance of one magnetometer sample, rad², or None: r_psi_dt (rad²·s) divided by the time
               since the previous one
    lpf        one-pole low-pass step 1 − exp(−dt/accel_tau) of the accelerometer (1: raw)
    rest_lpf   the same for the rest detector's low-passes
    rest_delay the zero-rate update's samples in hand, rest_margin / dt + 1 (the oldest is the one it uses)
    """

    field_n: np.ndarray
    q_angle: float
    q_bias: float
    r_gyro: float
    r_accel: float
    inv_dyn2: float
    psi_ref: float
    r_psi: float | None
    r_psi_dt: float | None
    lpf: float
    rest_lpf: float
    rest_delay: int


@dataclass
class MultiplicativeEKFState:
    """What the MEKF carries from one sample to the next, so that a recording fed in pieces gives one run's result.

    q          nominal quaternion (w, x, y, z), body → NED (None: from the first samples)
    bias       gyro bias (x, y, z), rad/s
    cov        covariance of the error state [δθ (NED, rad), δb (body, rad/s)], its 36 floats row by row
               (:mod:`~kfkit.filters.error_covariance`); ``P`` is the same as a 6×6 array
    k          samples filtered since the start
    strapdown  gyro-only attitude (w, x, y, z), body → I, of the accelerometer low-pass
    f_I        low-passed specific force in I, m/s²
    a_lin2     low-passed ‖f_I − f̄_I‖², the linear acceleration the low-pass removes, m²/s⁴
    rest_lp    the rest detector's low-passed gyro (rad/s) and specific force (m/s²), 6 values
    rest_t     how long the rest detector's tests have passed, s
    rest_samples the gyro samples of the last rest_margin s, oldest first (the zero-rate update's)
    rested     whether the IMU has been at rest (its bias measured) since the start
    t_mag      time of the previous magnetometer sample, s (None before the first)
    mag_gate   the magnetometer gate and its clocks (None before the first sample)
    """

    q: tuple | None
    bias: tuple
    cov: tuple
    k: int = 0
    strapdown: tuple = (1.0, 0.0, 0.0, 0.0)
    f_I: tuple | None = None
    a_lin2: float = 0.0
    rest_lp: tuple | None = None
    rest_t: float = 0.0
    rest_samples: deque = field(default_factory=deque)
    rested: bool = False
    t_mag: float | None = None
    mag_gate: MagGate | None = None

    @property
    def P(self):
        """The 6×6 error covariance (a new array)."""
        return np.array(self.cov).reshape(6, 6)


#: one sample's row in :meth:`MultiplicativeEKF.run`'s table: x, x⁻, P, P⁻, y, S and the four flags, as float64
_RUN_COLUMNS = (7, 7, 36, 36, 6, 6, 4)
_RUN_ROW = struct.Struct(f"{sum(_RUN_COLUMNS)}d")


class MultiplicativeEKF:
    """Multiplicative (error-state) EKF: nominal quaternion q (body → NED) and gyro bias b, with a
    6-element error state δx = [δθ, δb] (rad, rad/s); δθ is a small rotation in the NED frame,
    q_true = exp(δθ) ⊗ q, so that δθ_N, δθ_E are the tilt error and δθ_D the heading error (BROAD's
    inclination and heading). A :class:`~kfkit.filters.contract.TunedFilter`: x = [q, b] (7,), P 6×6.

    predict   ω̂ = ω − b held over the step the sample ends, q ← q ⊗ exp(ω̂ dt) (the exact
              exponential of the rotation vector), F = [[I, −R dt], [0, I]] (R = R_nb(q): a bias
              error turns the body, so the NED error, by −R δb dt), Q = diag(σ_g² dt² I, σ_bw² dt I)
    rest      the gyro and the accelerometer steady for rest_time s: the IMU is still and the gyro
              reads its bias, y = ω(t − rest_margin) − b, H = [0 I], R = σ_g² I (a zero-rate update on a
              sample known to be followed by rest)
    accel     f_n = g·R f̄ / ‖f̄‖, the low-passed specific force turned into NED, is [0, 0, −g] for the
              true attitude, and a tilt error δθ moves it to g·[δθ_E, −δθ_N, ·]:
              y = [f_n,N, f_n,E],  rows of H  g·e_E and −g·e_N (blocks: δθ_N, δθ_E, δθ_D, δb);
              R = σ_a² (1 + a_lin²/accel_dynamic²)
    heading   ψ_m = atan2(m_E, m_N) of the tilt-compensated field m = R m_b, y = wrap(ψ_ref − ψ_m),
              H = [−tan I cos D_m, −tan I sin D_m, 1, 0, 0, 0] (I the dip, D_m the heading of m): besides
              the heading, a tilt error about the field's horizontal direction turns the tilt-compensated
              field, and tan I of it shows as heading. The gain is kept off the tilt (a Schmidt "consider"
              update), so that a disturbed field never tilts the estimate; S = H P Hᵀ + R counts the tilt's
              uncertainty, which H = [0, 0, 1, 0, 0, 0] (the heading alone) would leave out
    reset     q ← exp(δθ) ⊗ q (normalised), b ← b + δb, δx ← 0

    Once the IMU has been at rest, its bias is learned at rest only (zero-rate updates and the
    accelerometer) and frozen in motion: the updates there are "consider" updates for it (K has no bias
    rows, P stays right), because a moving gyro's scale-factor and misalignment errors would be taken
    for bias. Before the first rest (or with ``rest_gyro=None``) every update corrects the bias.

    f̄ is the accelerometer low-passed in a gyro-stabilised frame (VQF, Laidig & Seel 2023): a strapdown
    quaternion q_I integrates the bias-corrected gyro alone, f_I = R(q_I) f_b is low-passed with time
    constant ``accel_tau`` (rotation does not move gravity there, so only the linear acceleration —
    zero-mean over seconds for a board that stays in place — is averaged out), and f̄ = R(q_I)ᵀ f̄_I.
    What the low-pass removes, a_lin² = low-passed ‖f_I − f̄_I‖², measures how hard the board is being
    pushed; the accelerometer's variance grows with it.

    Magnetic disturbances, in three layers (:class:`MagGate`):

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
       (gyro noise, bias random walk), so any steady field is adopted in the end. (VQF instead uses a
       field again after 60 s of rejection.)

    dt         sample period, s (or ``rate_hz``, Hz)
    settings   :class:`MultiplicativeEKFSettings`; keyword changes apply on top:
               ``MultiplicativeEKF(rate_hz=104, accel_tau=None)``
    field_n    reference field (NED, µT); sets north (its declination), its norm and dip.
               None: learned from the first magnetometer samples of each run from the start (:func:`learn_field`)
    x0         the start [q (w-x-y-z, body → NED), b (rad/s)] (7,); None: q from the first samples
               (:func:`tilt_heading`), b = 0
    P0         the start's 6×6 error covariance; default diag((5°)², (5°)², (10°)², (0.5 °/s)²·3)
    """

    method = "mekf"
    #: the bias is a "consider" state in motion once measured at rest; False: every update corrects it
    freeze_bias_in_motion = True
    #: the magnetometer gate's class (a variant can swap it)
    mag_gate_class = MagGate

    def __init__(
        self,
        dt=None,
        settings: MultiplicativeEKFSettings | None = None,
        *,
        rate_hz=None,
        field_n=None,
        x0=None,
        P0=None,
        **changes,
    ):
        owner = type(self).__name__
        self.dt = sample_period(owner, dt, rate_hz)
        self.rate_hz = 1.0 / self.dt
        self.settings = configure(MultiplicativeEKFSettings, settings, changes, owner)
        self.field_n = None if field_n is None else shaped(owner, "field_n", field_n, (3,))
        self._x0 = None
        self._P0 = np.diag(np.r_[np.radians([5.0, 5.0, 10.0]) ** 2, [math.radians(0.5) ** 2] * 3])
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start; a given x0 [q, b] (7,) or P0 (6×6) replaces the start's (q is normalised)."""
        owner = type(self).__name__
        if x0 is not None:
            x0 = shaped(owner, "x0", x0, (7,))
            x0[:4] /= np.linalg.norm(x0[:4])
            self._x0 = x0
        if P0 is not None:
            self._P0 = shaped(owner, "P0", P0, (6, 6))
        q, b = (
            (None, (0.0, 0.0, 0.0))
            if self._x0 is None
            else (tuple(self._x0[:4].tolist()), tuple(self._x0[4:].tolist()))
        )
        self.state = MultiplicativeEKFState(q=q, bias=b, cov=tuple(self._P0.ravel().tolist()))
        self.coefficients: MultiplicativeEKFCoefficients | None = None  # from the first samples

    # ---- the start ---------------------------------------------------------------------------
    def _begin(self, gyr, acc, mag):
        """Coefficients and the rest of the state from the first samples gyr, acc (N, 3), mag (N, 3) or None."""
        st, dt, rate, s = self.settings, self.dt, self.rate_hz, self.state
        field_n = self.field_n
        if field_n is None:
            field_n = learn_field(acc, mag) if mag is not None else np.array(MAG_FIELD_LONDON)
        mN, mE, _ = (float(v) for v in field_n)
        b_h2 = mN * mN + mE * mE
        sg = st.gyro_density * math.sqrt(rate) if st.gyro_noise is None else st.gyro_noise
        sa = st.accel_density * math.sqrt(rate) if st.accel_noise is None else st.accel_noise
        self.coefficients = MultiplicativeEKFCoefficients(
            field_n=field_n,
            q_angle=sg * sg * dt * dt,
            q_bias=st.gyro_bias_rw**2 * dt,
            r_gyro=sg * sg,
            r_accel=sa * sa,
            inv_dyn2=1.0 / st.accel_dynamic**2 if st.accel_dynamic else 0.0,
            psi_ref=math.atan2(mE, mN),
            r_psi=None if st.mag_noise is None else st.mag_noise**2 / b_h2,
            r_psi_dt=st.mag_density**2 / b_h2 if st.mag_noise is None else None,
            lpf=1.0 - math.exp(-dt / st.accel_tau) if st.accel_tau else 1.0,
            rest_lpf=1.0 - math.exp(-dt / st.rest_tau),
            rest_delay=round(st.rest_margin / dt) + 1,
        )
        if s.q is None:
            first = first_mag_row(mag)
            s.q = tuple(euler_to_quat(tilt_heading(acc[0], None if first is None else mag[first], field_n)).tolist())
        s.f_I = tuple(acc[0].tolist())
        s.rest_lp = tuple(gyr[0].tolist()) + tuple(acc[0].tolist())
        s.mag_gate = self.mag_gate_class(field_n, st)

    # ---- one sample, as named steps ------------------------------------------------------------
    def step(self, gyr, acc, mag=None) -> Step:
        """One sample: gyr (3,) rad/s, acc (3,) m/s², mag (3,) µT or None/NaN (no new sample) →
        Step(x = [q (w ≥ 0), b] (7,), P (6×6: δθ in NED, δb), y (6,), S (6×6, diagonal), x⁻, P⁻) with
        y = [accelerometer north, east (m/s²), heading (rad), zero rate x, y, z (rad/s)], NaN where no
        update was made (the updates are scalar, one after another)."""
        gyr, acc = np.asarray(gyr, dtype=float), np.asarray(acc, dtype=float)
        mag = None if mag is None or np.isnan(mag).any() else np.asarray(mag, dtype=float)
        if self.coefficients is None:
            self._begin(gyr[None], acc[None], None if mag is None else mag[None])
        y, s = [math.nan] * 6, [math.nan] * 6
        x_prior, P_prior, _ = self._sample(gyr.tolist(), acc.tolist(), None if mag is None else mag.tolist(), y, s)
        st = self.state
        return Step(
            _positive(st.q + st.bias),
            st.P,
            np.array(y),
            diagonal_S(np.array([s]))[0],
            _positive(x_prior),
            np.array(P_prior).reshape(6, 6),
        )

    def _sample(self, w, f, m, y, s):
        """predict → rest detection (zero-rate update) → stabilised accelerometer → accelerometer update →
        heading update → reset. The updates are scalar, one after another, each adding to the error estimate δx
        (its innovation corrected for the δx before it); the reset folds δx into q and b once. Writes the
        innovations and their variances into y and s (lists of 6); returns the prior (x⁻ = q⁻ + b, a 7-tuple; P⁻)
        and the flags (at rest, accelerometer variance raised, magnetometer used, magnetometer rejected)."""
        self._predict(w)
        x_prior, P_prior = self.state.q + self.state.bias, self.state.cov  # the prediction leaves b as it is
        dx = [0.0] * 6
        rest = self._at_rest(w, f)
        if rest:
            self.state.rested = True
            self._zero_rate_update(self.state.rest_samples[0], dx, y, s)
        frozen = BIAS if self.freeze_bias_in_motion and self.state.rested and not rest else NOTHING_KEPT
        pushed = self._accel_update(self._stabilised_accel(f), dx, frozen, y, s)
        used = rejected = False
        if m is not None and m[0] == m[0]:  # a new magnetometer sample
            used = self._heading_update(m, dx, frozen, y, s)
            rejected = not used
        self._reset(dx)
        self.state.k += 1
        return x_prior, P_prior, (rest, pushed, used, rejected)

    def _predict(self, w):
        """ω̂ = ω − b;  q ← q ⊗ exp(ω̂ dt) (and the strapdown q_I with it);  P ← F P Fᵀ + Q with
        F = [[I, −R dt], [0, I]]."""
        s, dt = self.state, self.dt
        turn = self._turn(w)
        s.q = quat_multiply_f(s.q, turn)
        s.strapdown = quat_multiply_f(s.strapdown, turn)
        self._R = R = quat_to_dcm_f(s.q)  # the accelerometer and heading updates' too
        c = self.coefficients
        s.cov = propagate(s.cov, R, dt, c.q_angle, c.q_bias)

    def _turn(self, w):
        """The body's turn over the step: exp(ω̂ dt), ω̂ = ω − b, the sample held over the step it ends."""
        bx, by, bz = self.state.bias
        return rotvec_to_quat_f((w[0] - bx) * self.dt, (w[1] - by) * self.dt, (w[2] - bz) * self.dt)

    def _at_rest(self, w, f):
        """VQF's rest detector: gyro and accelerometer low-passed (time constant rest_tau); at rest once, for
        rest_time s, each sample has stayed within rest_gyro / rest_accel of its low-pass and the gyro's
        low-pass within rest_gyro of zero on every axis. Keeps the samples of the last rest_margin s (since the
        tests last failed) in ``state.rest_samples``; the oldest is the zero-rate update's."""
        th = self.settings.rest_gyro
        if th is None:
            return False
        s, a = self.state, self.coefficients.rest_lpf
        wx, wy, wz, fx, fy, fz = s.rest_lp
        wx += a * (w[0] - wx)
        wy += a * (w[1] - wy)
        wz += a * (w[2] - wz)
        fx += a * (f[0] - fx)
        fy += a * (f[1] - fy)
        fz += a * (f[2] - fz)
        s.rest_lp = (wx, wy, wz, fx, fy, fz)
        gyro_dev = (w[0] - wx) ** 2 + (w[1] - wy) ** 2 + (w[2] - wz) ** 2
        accel_dev = (f[0] - fx) ** 2 + (f[1] - fy) ** 2 + (f[2] - fz) ** 2
        if gyro_dev > th * th or accel_dev > self.settings.rest_accel**2 or max(abs(wx), abs(wy), abs(wz)) > th:
            s.rest_t = 0.0
            s.rest_samples.clear()  # none of them is followed by rest
            return False
        s.rest_t += self.dt
        s.rest_samples.append(w)
        if len(s.rest_samples) > self.coefficients.rest_delay:
            s.rest_samples.popleft()
        return s.rest_t >= self.settings.rest_time

    def _zero_rate_update(self, w, dx, y, s_out):
        """At rest the gyro reads its bias: y_i = ω_i − b_i, H = e_(3+i), R = σ_g²; three scalar updates. ω is the
        sample of rest_margin s ago (the bias barely changes in that time)."""
        s, r = self.state, self.coefficients.r_gyro
        for i in range(3):
            y[3 + i] = w[i] - s.bias[i]
            j = 3 + i  # P Hᵀ is P's column j, its row j
            s.cov, s_out[j] = scalar_update(s.cov, dx, s.cov[6 * j : 6 * j + 6], s.cov[7 * j], y[j] - dx[j], r)

    def _stabilised_accel(self, f):
        """f̄_b: f_I = R(q_I) f_b low-passed in I (where rotation does not move gravity), back to the body
        frame; a_lin² follows ‖f_I − f̄_I‖². The raw f_b when accel_tau is None. Returns (f̄_b, a_lin²)."""
        lpf, s = self.coefficients.lpf, self.state
        if lpf >= 1.0:
            return f, 0.0
        fx, fy, fz = f
        s.strapdown = quat_normalise_f(s.strapdown)
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = quat_to_dcm_f(s.strapdown)
        fix, fiy, fiz = c00 * fx + c01 * fy + c02 * fz, c10 * fx + c11 * fy + c12 * fz, c20 * fx + c21 * fy + c22 * fz
        ix, iy, iz = s.f_I
        ix += lpf * (fix - ix)
        iy += lpf * (fiy - iy)
        iz += lpf * (fiz - iz)
        s.f_I = (ix, iy, iz)
        s.a_lin2 += lpf * ((fix - ix) ** 2 + (fiy - iy) ** 2 + (fiz - iz) ** 2 - s.a_lin2)
        return (
            c00 * ix + c10 * iy + c20 * iz,
            c01 * ix + c11 * iy + c21 * iz,
            c02 * ix + c12 * iy + c22 * iz,
        ), s.a_lin2

    def _accel_update(self, f_lin, dx, frozen, y, s_out):
        """f_n = g·R f̄ / ‖f̄‖; y = [f_n,N, f_n,E] (zero for a level estimate), H rows g·e_E and −g·e_N of the
        attitude error, R = σ_a² (1 + a_lin²/accel_dynamic²); two scalar updates. Returns whether linear
        acceleration at least doubled R."""
        s, c = self.state, self.coefficients
        (fx, fy, fz), a_lin2 = f_lin
        scale = G / math.sqrt(fx * fx + fy * fy + fz * fz)
        r00, r01, r02, r10, r11, r12, _, _, _ = self._R  # of the predicted q
        y[0] = scale * (r00 * fx + r01 * fy + r02 * fz)
        y[1] = scale * (r10 * fx + r11 * fy + r12 * fz)
        pushed = a_lin2 * c.inv_dyn2
        r = c.r_accel * (1.0 + pushed) / (G * G)
        # H = g·e_E (north) and −g·e_N (east): each is y/(±g) = δθ_E or −δθ_N with variance R/g², an update of
        # one component (P Hᵀ is P's column 1, then 0); S = g² × that measurement's
        s.cov, S_north = scalar_update(s.cov, dx, s.cov[6:12], s.cov[7], y[0] / G - dx[1], r, frozen)
        s.cov, S_east = scalar_update(s.cov, dx, s.cov[0:6], s.cov[0], -y[1] / G - dx[0], r, frozen)
        s_out[0], s_out[1] = G * G * S_north, G * G * S_east
        return pushed > 1.0

    def _heading_update(self, m, dx, frozen, y, s_out):
        """ψ_m of the tilt-compensated field m = R·m_b, y = wrap(ψ_ref − ψ_m) − H δx, H = [−tan I cos D_m,
        −tan I sin D_m, 1, 0, 0, 0]; if the gate passes the sample, the update with the gain kept off the tilt.
        Returns whether the sample was used."""
        s, c = self.state, self.coefficients
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = self._R
        mx, my, mz = m
        m_n, m_e, m_d = r00 * mx + r01 * my + r02 * mz, r10 * mx + r11 * my + r12 * mz, r20 * mx + r21 * my + r22 * mz
        m_h = math.hypot(m_n, m_e)  # horizontal part, µT
        t = s.k * self.dt
        r = c.r_psi if c.r_psi is not None else c.r_psi_dt / (t - s.t_mag if s.t_mag is not None else self.dt)
        s.t_mag = t
        (h0, h1, h2), kept_off = self._heading_row(m_n, m_e, m_d, frozen)
        innov = wrap_angle_f(c.psi_ref - math.atan2(m_e, m_n)) - (h0 * dx[0] + h1 * dx[1] + h2 * dx[2])
        a = times_attitude_row(s.cov, h0, h1, h2)  # P Hᵀ
        var_h = h0 * a[0] + h1 * a[1] + h2 * a[2]  # H P Hᵀ
        if not s.mag_gate.use(t, math.hypot(m_h, m_d), math.atan2(m_d, m_h), innov, var_h, r):
            return False
        y[2] = innov
        s.cov, s_out[2] = scalar_update(s.cov, dx, a, var_h, innov, r, kept_off)
        return True

    def _heading_row(self, m_n, m_e, m_d, frozen):
        """The heading's H (its attitude part, 3 values) for the tilt-compensated field m = [m_n, m_e, m_d] (µT),
        and what the update leaves alone: the tilt, and the bias when ``frozen``."""
        h2 = m_n * m_n + m_e * m_e
        return (-m_d * m_n / h2, -m_d * m_e / h2, 1.0), TILT_AND_BIAS if frozen.bias else TILT

    def _reset(self, dx):
        """Fold the error estimate δx = [δθ, δb] into the nominal state: q ← exp(δθ) ⊗ q (normalised),
        b ← b + δb."""
        s = self.state
        ex, ey, ez, dbx, dby, dbz = dx
        s.q = quat_normalise_f(quat_multiply_f((1.0, 0.5 * ex, 0.5 * ey, 0.5 * ez), s.q))
        bx, by, bz = s.bias
        s.bias = (bx + dbx, by + dby, bz + dbz)

    # ---- a recording ---------------------------------------------------------------------------
    def run(self, gyr, acc, mag=None, *, resume=False) -> AttitudeRun:
        """The named steps over a recording: gyr (N, 3) rad/s, acc (N, 3) m/s², mag (N, 3) µT or None
        (NaN rows = no new sample), one sensor frame. From the start (x0 None: from the first samples), or from
        the current state with ``resume=True`` (a recording fed in pieces gives what one run gives)."""
        gyr, acc, mag = check_inputs(gyr, acc, mag)
        if not resume:
            self.reset()
        if self.coefficients is None:
            self._begin(gyr, acc, mag)
        N = len(gyr)
        # each sample's numbers go into one row of a table of floats at once, while they are fresh in the cache (lists
        # of tuples turned into arrays at the end cost a fifth of the run)
        row = _RUN_ROW
        table = bytearray(row.size * N)
        M = mag.tolist() if mag is not None else [None] * N
        sample, s, pack = self._sample, self.state, row.pack_into
        nan6 = [math.nan] * 6
        for k, (w, f, m) in enumerate(zip(gyr.tolist(), acc.tolist(), M)):
            yk, sk = nan6.copy(), nan6.copy()
            x_prior, P_prior, flag = sample(w, f, m, yk, sk)
            pack(table, k * row.size, *s.q, *s.bias, *x_prior, *s.cov, *P_prior, *yk, *sk, *flag)
        columns = np.frombuffer(table).reshape(N, -1)
        x, x_prior, P, P_prior, y, S, flags = np.split(columns, np.cumsum(_RUN_COLUMNS)[:-1], axis=1)
        x, x_prior, y, S, flags = _positive(x), _positive(x_prior), y.copy(), S.copy(), flags > 0.0
        return AttitudeRun(
            x,
            P.reshape(N, 6, 6).copy(),
            y,
            diagonal_S(S),
            x_prior,
            P_prior.reshape(N, 6, 6).copy(),
            nis=np.nansum(y * y / S, axis=1),
            accel_gated=flags[:, 1],
            mag_used=flags[:, 2],
            mag_gated=flags[:, 3],
            at_rest=flags[:, 0],
            method=self.method,
        )


def _positive(x):
    """[q, b] with the quaternion's w ≥ 0 (q and −q are the same rotation), (7,) or (N, 7), as a new array."""
    x = np.array(x, dtype=float)
    q = x[..., :4]
    q *= np.where(q[..., :1] < 0, -1.0, 1.0)
    return x
