"""Lab 05: one tilt angle and its gyro bias, x = [θ; b], for one axis of an MPU6050.

    predict   x⁻ = A x + B ω,   A = [[1, −Δt], [0, 1]],  B = [Δt; 0]     (θ⁻ = θ + (ω − b)·Δt)
              P⁻ = A P Aᵀ + Q                                           (rad², rad²/s, (rad/s)²)
    update    z = accelerometer angle (rad),  H = [1, 0],  R = r (rad²)
              y = z − θ⁻,  S = P⁻₀₀ + r,  K = P⁻ Hᵀ / S,  x = x⁻ + K y,  P = (I − K H) P⁻

The textbook forms the lab teaches are :func:`tilt_kf_predict`, :func:`tilt_kf_update` (any 2×2 Q, as Van Loan gives
it: :func:`kfkit.discrete.angle_bias_process_noise`) and :func:`tilt_kf`, their loop. :class:`TiltBiasKF` is the
same filter with Q = diag(q_θ, q_b) unrolled on floats, after the kit's filter contract, with a
:class:`TiltBiasKFSettings`.

The accelerometer angle is only a measurement of tilt while the board does not accelerate, which
the host (or the board) judges from the specific force's norm: ``static_ok = |‖f‖ − g| < ε``.
When it is false the update is skipped (``accel_gating="skip"``) or made with R × ``accel_inflation``
(``accel_gating="inflate"``); ``accel_gating="none"`` always updates.
``firmware/tilt_kf/tilt_kf.c`` is the same filter in C (float32; its ``gate`` and ``inflation`` are
``accel_gating`` and ``accel_inflation``); ``tests/test_tilt_c.py`` holds them together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..frames import G, accel_tilt, mount_matrix
from ..sensors import board as get_board
from .contract import FilterRun, State, Step, check_settings, configure, sample_period, shaped

GATINGS = ("none", "skip", "inflate")
DEFAULT_EPS = 0.05 * G  # m/s², static gate |‖f‖ − g| < ε


@dataclass(frozen=True)
class TiltBiasKFSettings:
    """Tuning of one :class:`TiltBiasKF` axis. The defaults are the C filter's (``tiltKfDefaultSettings``), what
    ``firmware/mpu6050_tilt_kf`` runs for ``kfkit demo tilt``: an MPU6050 at 100 Hz, tuned for motion.

    q_angle          q_θ, angle random walk per step beyond the gyro, rad²: the gyro's white noise N²·Δt     8e-11
    q_bias           q_b, gyro-bias random walk per step, (rad/s)²: the rate random walk K²·Δt            6e-11
    r                variance of the accelerometer angle at rest, rad² ((4 mg noise / 1 g)²)              1.6e-5
    accel_gating     what a sample whose ``static_ok`` is false does: "skip" its update, "inflate"
                     its R, or "none" (update as any other)                                          "skip"
    accel_inflation  the R multiplier of ``accel_gating="inflate"``                                  100

    Why q_θ and q_b are the sensor's own (lab 02's N and K of the bundled MPU6050 through Van Loan, x and y averaged:
    :func:`kfkit.labs.lab05.shipped_process_noise`), not lab 05's tuning on the holds (q_θ = 2e-6): the demo is used
    while the board moves, and over a whole motion record the hold-tuned filter follows every push of the hand that
    slips through the gate. Tuned on the motion instead, q_θ finds nothing to add beyond the gyro's noise: roll and
    pitch turned without yaw are what the per-axis model describes (lab 05, section 9; ``tests/test_tilt.py`` measures
    both tunings on a whole motion record).
    """

    q_angle: float = 8e-11
    q_bias: float = 6e-11
    r: float = 1.6e-5
    accel_gating: str = "skip"
    accel_inflation: float = 100.0

    def __post_init__(self):
        check_settings(
            self,
            positive=("q_angle", "r", "accel_inflation"),
            non_negative=("q_bias",),
            choices={"accel_gating": GATINGS},
        )


def tilt_kf_predict(x, P, omega, dt, Q):
    """Prediction of x = [θ (rad), b (rad/s)] over ``dt`` (s) with the gyro rate ``omega`` (rad/s):
    x⁻ = A x + B ω,  P⁻ = A P Aᵀ + Q,  A = [[1, −Δt], [0, 1]],  B = [Δt, 0];  Q (2×2). Returns (x⁻, P⁻)."""
    A = np.array([[1.0, -dt], [0.0, 1.0]])
    return A @ np.asarray(x, dtype=float) + np.array([dt, 0.0]) * omega, A @ np.asarray(P, dtype=float) @ A.T + Q


def tilt_kf_update(x, P, z, r):
    """Update with an accelerometer angle ``z`` (rad) of variance ``r`` (rad²), H = [1, 0]:
    y = z − θ⁻,  S = P⁻₀₀ + r,  K = P⁻ Hᵀ / S,  x = x⁻ + K y,  P = (I − K H) P⁻. Returns (x, P, y, S)."""
    x, P = np.asarray(x, dtype=float), np.asarray(P, dtype=float)
    y = z - x[0]
    S = P[0, 0] + r
    K = P[:, 0] / S
    return x + K * y, P - np.outer(K, P[0]), y, S


def tilt_kf(
    gyro_rate,
    accel_angle,
    static_ok,
    dt,
    Q,
    r,
    gate="skip",
    x0=None,
    P0=None,
    inflation=TiltBiasKFSettings.accel_inflation,
):
    """The textbook loop over :func:`tilt_kf_predict` and :func:`tilt_kf_update` with any 2×2 Q: every sample
    predicted, then updated as ``gate`` says where ``static_ok`` is false ("none" updates, "skip" does not,
    "inflate" uses r × ``inflation``). x0 None: [first accelerometer angle, 0]; P0 None: diag(r, (0.1 rad/s)²).
    Returns the states (N, 2) and covariances (N, 2, 2) after each sample. With a diagonal Q it is
    :class:`TiltBiasKF`'s run (``tests/test_tilt.py``)."""
    if gate not in GATINGS:
        raise ValueError(f"tilt_kf: gate must be one of {', '.join(GATINGS)}, got {gate!r}")
    x = np.array([accel_angle[0], 0.0] if x0 is None else x0, dtype=float)
    P = np.diag([r, 0.1**2]) if P0 is None else np.asarray(P0, dtype=float)
    xs, Ps = np.empty((len(accel_angle), 2)), np.empty((len(accel_angle), 2, 2))
    for k, (w, z, ok) in enumerate(zip(gyro_rate, accel_angle, static_ok)):
        x, P = tilt_kf_predict(x, P, w, dt, Q)
        if ok or gate == "none":
            x, P, _, _ = tilt_kf_update(x, P, z, r)
        elif gate == "inflate":
            x, P, _, _ = tilt_kf_update(x, P, z, inflation * r)
        xs[k], Ps[k] = x, P
    return xs, Ps


def accel_static_ok(f_b, eps=DEFAULT_EPS):
    """True where |‖f_b‖ − g| < eps (m/s²): the board is probably not accelerating.

    ``f_b`` is specific force (m/s²), (3,) or (N, 3). A necessary, not a sufficient test: a
    board accelerated sideways while tilted can keep ‖f‖ = g for a moment.
    """
    f = np.asarray(f_b, dtype=float)
    if f.ndim == 0 or f.shape[-1] != 3:
        raise ValueError(
            f"accel_static_ok expects specific force with 3 components on the last axis, got shape {f.shape}"
        )
    if not eps > 0:
        raise ValueError(f"accel_static_ok: eps must be a positive tolerance in m/s², got {eps}")
    ok = np.abs(np.linalg.norm(f, axis=-1) - G) < eps
    return bool(ok) if ok.ndim == 0 else ok


@dataclass
class TiltRun(FilterRun):
    """:class:`FilterRun` of a :class:`TiltBiasKF`: x, x_prior (N, 2) = [θ, b], P, P_prior (N, 2, 2), y (N,), S (N,).

    ``y`` and ``S`` are NaN where the update was skipped; ``gated`` marks the samples where
    ``static_ok`` was false (skipped or inflated).
    """

    gated: np.ndarray | None = None

    @property
    def angle(self) -> np.ndarray:
        """Estimated angle θ (rad), (N,)."""
        return self.x[:, 0]

    @property
    def bias(self) -> np.ndarray:
        """Estimated gyro bias b (rad/s), (N,)."""
        return self.x[:, 1]


class TiltBiasKF:
    """Two-state [angle, gyro bias] Kalman filter for one tilt axis, a :class:`~kfkit.filters.contract.TunedFilter`.

    dt         sample period, s (or ``rate_hz``, Hz)
    settings   :class:`TiltBiasKFSettings`; keyword changes apply on top: ``TiltBiasKF(0.01, r=1e-4)``
    x0, P0     initial [θ (rad), b (rad/s)] and its 2×2 covariance, one step before the first sample; x0 None:
               [the first accelerometer angle (0 if there is none), 0]; P0 None: diag(r, (0.1 rad/s)²)
    """

    def __init__(
        self, dt=None, settings: TiltBiasKFSettings | None = None, *, rate_hz=None, x0=None, P0=None, **changes
    ):
        self.dt = sample_period("TiltBiasKF", dt, rate_hz)
        self.settings = configure(TiltBiasKFSettings, settings, changes, "TiltBiasKF")
        self._x0, self._P0 = None, np.diag([self.settings.r, 0.1**2])
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start; a given x0 [θ, b] or P0 (2×2) replaces the start's."""
        if x0 is not None:
            self._x0 = shaped("TiltBiasKF", "x0", x0, (2,))
        if P0 is not None:
            P0 = shaped("TiltBiasKF", "P0", P0, (2, 2))
            self._P0 = 0.5 * (P0 + P0.T)
        self.state = State(None if self._x0 is None else self._x0.copy(), self._P0.copy())

    def step(self, gyro_rate, accel_angle, static_ok=True) -> Step:
        """One predict with the gyro rate (rad/s), one (gated) update with the accel angle (rad).

        A NaN ``accel_angle`` skips the update. Returns Step(x = [θ, b], P (2×2), y, S, x⁻, P⁻); y and S
        are NaN if skipped.
        """
        s = self.state
        x = (accel_angle if accel_angle == accel_angle else 0.0, 0.0) if s.x is None else s.x.tolist()
        row = _tilt_sample(
            *x, s.P[0, 0], s.P[0, 1], s.P[1, 1], gyro_rate, accel_angle, static_ok, *self._coefficients()
        )
        x_prior, P_prior, x, P, y, S = (a[0] for a in _unpack(np.array([row])))
        s.x, s.P = x, P
        return Step(x, P, float(y), float(S), x_prior, P_prior)

    def _coefficients(self):
        """(dt, q_θ, q_b, r, R of a sample that is not static: None = skipped) as floats."""
        st = self.settings
        moving = {"none": st.r, "skip": None, "inflate": st.r * st.accel_inflation}[st.accel_gating]
        return self.dt, float(st.q_angle), float(st.q_bias), float(st.r), moving

    def run(self, gyro_rate, accel_angle, static_ok=None, *, resume=False) -> TiltRun:
        """:meth:`step` over a recording → :class:`TiltRun`: from the start (x0 None: the first accelerometer angle
        that is not NaN), or from the current state with ``resume=True``.

        gyro_rate, accel_angle (N,) rad/s and rad; static_ok (N,) bool (default all True).
        """
        w = np.asarray(gyro_rate, dtype=float)
        z = np.asarray(accel_angle, dtype=float)
        ok = np.ones(len(z), dtype=bool) if static_ok is None else np.asarray(static_ok, dtype=bool)
        if w.ndim != 1 or w.shape != z.shape or ok.shape != z.shape:
            raise ValueError(
                f"TiltBiasKF.run: gyro_rate, accel_angle and static_ok must be 1-D of equal length, "
                f"got shapes {w.shape}, {z.shape}, {ok.shape}"
            )
        if not len(z):
            raise ValueError("TiltBiasKF.run: no samples")
        if not np.isfinite(w).all():
            k = int(np.flatnonzero(~np.isfinite(w))[0])
            raise ValueError(
                f"TiltBiasKF.run: gyro_rate[{k}] is {w[k]}: the prediction needs a finite rate at every sample"
            )
        if not resume:
            self.reset()
        s, c = self.state, self._coefficients()
        if s.x is None:
            first = z[~np.isnan(z)]
            s.x = np.array([float(first[0]) if len(first) else 0.0, 0.0])
        angle, bias = s.x.tolist()
        P00, P01, P11 = float(s.P[0, 0]), float(s.P[0, 1]), float(s.P[1, 1])
        rows = []
        for wk, zk, okk in zip(w.tolist(), z.tolist(), ok.tolist()):  # plain floats: fast enough for tuning loops
            row = _tilt_sample(angle, bias, P00, P01, P11, wk, zk, okk, *c)
            angle, bias, P00, P01, P11 = row[5:10]
            rows.append(row)
        x_prior, P_prior, x, P, y, S = _unpack(np.array(rows))
        self.state = State(x[-1].copy(), P[-1].copy())
        return TiltRun(x, P, y, S, x_prior, P_prior, gated=~ok)


def _tilt_sample(angle, bias, P00, P01, P11, gyro_rate, accel_angle, static_ok, dt, q_angle, q_bias, r, r_moving):
    """One predict + gated update on floats (P symmetric: P00, P01, P11) →
    (θ⁻, b⁻, P⁻00, P⁻01, P⁻11, θ, b, P00, P01, P11, y, S); y, S NaN where the update is skipped."""
    # predict: θ⁻ = θ + (ω − b)Δt; P⁻ = A P Aᵀ + Q written out
    angle, bias = angle + (gyro_rate - bias) * dt, bias
    P00 += dt * (dt * P11 - 2.0 * P01) + q_angle
    P01 -= dt * P11
    P11 += q_bias
    prior = (angle, bias, P00, P01, P11)
    r = r if static_ok else r_moving
    if accel_angle != accel_angle or r is None:  # NaN, or gated out
        return (*prior, *prior, math.nan, math.nan)
    y = accel_angle - angle
    S = P00 + r
    k0, k1 = P00 / S, P01 / S
    angle += k0 * y
    bias += k1 * y
    # P = (I − K H) P⁻; the bias row uses the prior P01, so update P11 first
    P11 -= k1 * P01
    P01 -= k0 * P01
    P00 -= k0 * P00
    return (*prior, angle, bias, P00, P01, P11, y, S)


def _unpack(rows):
    """(N, 12) rows of :func:`_tilt_sample` → x⁻ (N, 2), P⁻ (N, 2, 2), x, P, y (N,), S (N,)."""

    def cov(c):
        return rows[:, [c, c + 1, c + 1, c + 2]].reshape(-1, 2, 2)

    return rows[:, 0:2].copy(), cov(2), rows[:, 5:7].copy(), cov(7), rows[:, 10].copy(), rows[:, 11].copy()


class TiltAttitude:
    """Roll and pitch from a board's raw counts, sample by sample, as ``firmware/mpu6050_tilt_kf`` does.

    The first ``bias_seconds`` of samples (the board must be still) give the gyro bias both
    filters start from; then for every sample: counts → body frame (SI) with the board's
    sensitivities and mounting, six-face correction f = (f_raw − accel_bias) / accel_scale (body frame),
    accelerometer roll and pitch, the static gate |‖f‖ − g| < eps, one :class:`TiltBiasKF` per axis
    (``settings``, a :class:`TiltBiasKFSettings`) fed with the body rates p (roll) and q (pitch). Each axis is
    treated on its own, which holds for turns about one axis at a time (θ̇ = q only while φ = 0). Roll is not
    updated while
    √(f_y² + f_z²) < roll_min·g: near pitch ±90° the accelerometer roll is the angle of noise.
    """

    def __init__(
        self,
        board="mpu6050",
        rate_hz=None,
        settings: TiltBiasKFSettings | None = None,
        eps=DEFAULT_EPS,
        roll_min=0.5,
        bias_seconds=2.0,
        accel_bias=(0.0, 0.0, 0.0),
        accel_scale=(1.0, 1.0, 1.0),
    ):
        self.board = get_board(board) if isinstance(board, str) else board
        self.rate_hz = float(rate_hz or self.board.rate_hz)
        self.kfs = [TiltBiasKF(rate_hz=self.rate_hz, settings=settings) for _ in range(2)]
        self.eps, self.roll_min = eps, roll_min
        self.accel_bias, self.accel_scale = np.asarray(accel_bias, float), np.asarray(accel_scale, float)
        self._acc = mount_matrix(self.board.mount["acc"]) * self.board.accel.sensitivity
        self._gyr = mount_matrix(self.board.mount["gyr"]) * self.board.gyro.sensitivity
        self._bias_n = max(1, int(round(bias_seconds * self.rate_hz)))
        self._rates = []
        self.gyro_bias = None  # body frame [p, q, r] bias from the still start, rad/s

    def step(self, acc_counts, gyr_counts):
        """One sample of counts (sensor frame). Returns (roll, pitch) in rad, or None while measuring the
        bias; each axis's full :class:`Step` is its filter's (``kfs[0]`` roll, ``kfs[1]`` pitch)."""
        f = (self._acc @ np.asarray(acc_counts, float) - self.accel_bias) / self.accel_scale
        w = self._gyr @ np.asarray(gyr_counts, float)
        if self.gyro_bias is None:
            self._rates.append(w)
            if len(self._rates) < self._bias_n:
                return None
            self.gyro_bias = np.mean(self._rates, axis=0)
            roll, pitch = accel_tilt(f)
            for kf, angle, b in zip(self.kfs, (roll, pitch), self.gyro_bias[:2]):
                kf.reset((angle, b))
            return float(roll), float(pitch)
        ok = accel_static_ok(f, self.eps)
        roll_ok = ok and np.hypot(f[1], f[2]) >= self.roll_min * G
        (roll, pitch), (p, q) = accel_tilt(f), w[:2].tolist()
        return float(self.kfs[0].step(p, roll, roll_ok).x[0]), float(self.kfs[1].step(q, pitch, ok).x[0])


def protocol_angles(rec):
    """The tilt protocol's known angles (rad) from a recording's phase labels: (roll, pitch), each (N,).

    In a "<axis>_0" or "<axis>_90" hold that axis is 0 or π/2 and the other axis is 0, except roll
    during "pitch_90", which is undefined (NaN): with the nose straight up, roll and yaw turn about
    the same vertical axis (gimbal lock) and gravity says nothing about either. NaN outside holds.
    """
    roll, pitch = np.full(len(rec), np.nan), np.full(len(rec), np.nan)
    known = {"roll_0": (0.0, 0.0), "roll_90": (np.pi / 2, 0.0), "pitch_0": (0.0, 0.0), "pitch_90": (np.nan, np.pi / 2)}
    labels = {p["label"] for p in rec.phases} & set(known)
    if not labels:
        raise KeyError(
            f"recording {rec.path or ''} has no tilt-protocol phases ({', '.join(known)}): "
            f"record it with the guided tilt protocol (kfkit capture --protocol tilt)"
        )
    for label in labels:
        mask = rec.phase(label)
        roll[mask], pitch[mask] = known[label]
    return roll, pitch
