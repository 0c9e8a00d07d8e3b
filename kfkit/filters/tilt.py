"""Lab 05: one tilt angle and its gyro bias, x = [θ; b], for one axis of an MPU6050.

    predict   x⁻ = A x + B ω,   A = [[1, −Δt], [0, 1]],  B = [Δt; 0]     (θ⁻ = θ + (ω − b)·Δt)
              P⁻ = A P Aᵀ + Q,  Q = diag(q_θ, q_b)                        (rad², (rad/s)²)
    update    z = accelerometer angle (rad),  H = [1, 0],  R = r (rad²)
              y = z − θ⁻,  S = P⁻₀₀ + r,  K = P⁻ Hᵀ / S,  x = x⁻ + K y,  P = (I − K H) P⁻

The accelerometer angle is only a measurement of tilt while the board does not accelerate, which
the host (or the board) judges from the specific force's norm: ``static_ok = |‖f‖ − g| < ε``.
When it is false the gate either skips the update (``gate="skip"``) or inflates R by
``inflation`` (``gate="inflate"``); ``gate="none"`` always updates. The tuning is a :class:`TiltSettings`. ``firmware/tilt_kf/tilt_kf.c``
is the same filter in C (float32); ``tests/test_tilt_c.py`` holds them together.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frames import G, accel_tilt, mount_matrix
from ..sensors import board as get_board
from .linear import FilterRun, Step, configure, require_positive

GATES = ("none", "skip", "inflate")
DEFAULT_EPS = 0.05 * G  # m/s², static gate |‖f‖ − g| < ε


@dataclass(frozen=True)
class TiltSettings:
    """Tuning of one :class:`TiltBiasKF` axis. The defaults are lab 05's for an MPU6050 at 100 Hz and
    the C filter's (``tiltKfDefaultSettings``).

    q_angle    q_θ, angle random walk per step beyond the gyro, rad² (≈ (σ_ω·Δt)² to start)    2e-6
    q_bias     q_b, bias random walk per step, (rad/s)² (10⁻⁴ q_θ: the fit is flat in q_b
               once the bias has converged)                                                    2e-10
    r          variance of the accelerometer angle, rad² ((4 mg noise / 1 g)²)                 1.6e-5
    gate       what to do when ``static_ok`` is false: "skip", "inflate" or "none"            "skip"
    inflation  R multiplier for ``gate="inflate"``                                             100
    """

    q_angle: float = 2e-6
    q_bias: float = 2e-10
    r: float = 1.6e-5
    gate: str = "skip"
    inflation: float = 100.0

    def __post_init__(self):
        require_positive("TiltSettings", zero_ok=("q_bias",), q_angle=self.q_angle, q_bias=self.q_bias, r=self.r,
                         inflation=self.inflation)
        if self.gate not in GATES:
            raise ValueError(f"TiltSettings: gate must be one of {', '.join(GATES)}, got {self.gate!r}")


def accel_static_ok(f_b, eps=DEFAULT_EPS):
    """True where |‖f_b‖ − g| < eps (m/s²): the board is probably not accelerating.

    ``f_b`` is specific force (m/s²), (3,) or (N, 3). A necessary, not a sufficient test: a
    board accelerated sideways while tilted can keep ‖f‖ = g for a moment.
    """
    f = np.asarray(f_b, dtype=float)
    if f.ndim == 0 or f.shape[-1] != 3:
        raise ValueError(f"accel_static_ok expects specific force with 3 components on the last axis, got shape {f.shape}")
    if not eps > 0:
        raise ValueError(f"accel_static_ok: eps must be a positive tolerance in m/s², got {eps}")
    ok = np.abs(np.linalg.norm(f, axis=-1) - G) < eps
    return bool(ok) if ok.ndim == 0 else ok


@dataclass
class TiltRun(FilterRun):
    """:class:`FilterRun` of a :class:`TiltBiasKF`: x (N, 2) = [θ, b], P (N, 2, 2), y (N,), S (N,).

    ``y`` and ``S`` are NaN where the gate skipped the update; ``gated`` marks the samples where
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
    """Two-state [angle, gyro bias] Kalman filter for one tilt axis.

    dt         sample period, s
    settings   :class:`TiltSettings`; keyword changes apply on top: ``TiltBiasKF(0.01, r=1e-4)``
    x0, P0     initial [θ (rad), b (rad/s)] and its 2×2 covariance; ``run`` defaults θ₀ to the first
               accelerometer angle and P0 to diag(r, (0.1 rad/s)²)
    """

    def __init__(self, dt, settings: TiltSettings | None = None, x0=(0.0, 0.0), P0=None, **changes):
        require_positive("TiltBiasKF", dt=dt)
        self.dt = float(dt)
        self.settings = configure(TiltSettings, settings, changes, "TiltBiasKF")
        st = self.settings  # as plain floats for the per-sample arithmetic
        self.q_angle, self.q_bias, self.r = float(st.q_angle), float(st.q_bias), float(st.r)
        self.gate, self.inflation = st.gate, float(st.inflation)
        self.reset(x0, P0)

    def reset(self, x0=(0.0, 0.0), P0=None):
        """Set the state [θ, b] and covariance (default diag(r, (0.1 rad/s)²))."""
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        P0 = np.diag([self.r, 0.1 ** 2]) if P0 is None else np.asarray(P0, dtype=float)
        if x0.shape != (2,) or P0.shape != (2, 2):
            raise ValueError(f"TiltBiasKF: x0 must have 2 values and P0 be 2×2, got shapes {x0.shape} and {P0.shape}")
        self.angle, self.bias = float(x0[0]), float(x0[1])
        self.P00, self.P01, self.P11 = float(P0[0, 0]), float(0.5 * (P0[0, 1] + P0[1, 0])), float(P0[1, 1])

    @property
    def x(self) -> np.ndarray:
        return np.array([self.angle, self.bias])

    @property
    def P(self) -> np.ndarray:
        return np.array([[self.P00, self.P01], [self.P01, self.P11]])

    def step(self, gyro_rate, accel_angle, static_ok=True) -> Step:
        """One predict with the gyro rate (rad/s), one (gated) update with the accel angle (rad).

        A NaN ``accel_angle`` skips the update. Returns Step(x = [θ, b], P (2×2), y, S); y and S
        are NaN if skipped.
        """
        _, _, y, S = self._advance(gyro_rate, accel_angle, static_ok)
        return Step(self.x, self.P, y, S)

    def _advance(self, gyro_rate, accel_angle, static_ok):
        """:meth:`step` on floats, returning (θ, b, y, S): what :meth:`run` stores per sample."""
        dt, P00, P01, P11 = self.dt, self.P00, self.P01, self.P11
        # predict: θ⁻ = θ + (ω − b)Δt; P⁻ = A P Aᵀ + Q written out (P symmetric: P00, P01, P11)
        angle, bias = self.angle + (gyro_rate - self.bias) * dt, self.bias
        P00 += dt * (dt * P11 - 2.0 * P01) + self.q_angle
        P01 -= dt * P11
        P11 += self.q_bias
        y = S = np.nan
        if accel_angle == accel_angle and (static_ok or self.gate != "skip"):  # not NaN, not gated out
            r = self.r if static_ok or self.gate == "none" else self.r * self.inflation
            y = accel_angle - angle
            S = P00 + r
            k0, k1 = P00 / S, P01 / S
            angle += k0 * y
            bias += k1 * y
            # P = (I − K H) P⁻; the bias row uses the prior P01, so update P11 first
            P11 -= k1 * P01
            P01 -= k0 * P01
            P00 -= k0 * P00
        self.angle, self.bias, self.P00, self.P01, self.P11 = angle, bias, P00, P01, P11
        return angle, bias, y, S

    def run(self, gyro_rate, accel_angle, static_ok=None, x0=None, P0=None) -> TiltRun:
        """Run over a recording from (x0, P0): a step for every sample. Returns a :class:`TiltRun`.

        gyro_rate, accel_angle (N,) rad/s and rad; static_ok (N,) bool (default all True).
        x0 defaults to [first accelerometer angle, 0].
        """
        w = np.asarray(gyro_rate, dtype=float)
        z = np.asarray(accel_angle, dtype=float)
        ok = np.ones(len(z), dtype=bool) if static_ok is None else np.asarray(static_ok, dtype=bool)
        if w.ndim != 1 or w.shape != z.shape or ok.shape != z.shape:
            raise ValueError(f"TiltBiasKF.run: gyro_rate, accel_angle and static_ok must be 1-D of equal length, "
                             f"got shapes {w.shape}, {z.shape}, {ok.shape}")
        if not len(z):
            raise ValueError("TiltBiasKF.run: no samples")
        if not np.isfinite(w).all():
            k = int(np.flatnonzero(~np.isfinite(w))[0])
            raise ValueError(f"TiltBiasKF.run: gyro_rate[{k}] is {w[k]}: the prediction needs a finite rate at every sample")
        if x0 is None:
            first = z[~np.isnan(z)]
            x0 = (float(first[0]) if len(first) else 0.0, 0.0)
        self.reset(x0, P0)
        advance, rows = self._advance, []
        for wk, zk, okk in zip(w.tolist(), z.tolist(), ok.tolist()):  # plain floats: fast enough for tuning loops
            rows.append((*advance(wk, zk, okk), self.P00, self.P01, self.P11))
        h = np.array(rows)
        P = np.stack([h[:, 4], h[:, 5], h[:, 5], h[:, 6]], axis=1).reshape(-1, 2, 2)
        return TiltRun(h[:, :2].copy(), P, h[:, 2].copy(), h[:, 3].copy(), gated=~ok)


class TiltAttitude:
    """Roll and pitch from a board's raw counts, sample by sample, as ``firmware/mpu6050_tilt_kf`` does.

    The first ``bias_seconds`` of samples (the board must be still) give the gyro bias both
    filters start from; then for every sample: counts → body frame (SI) with the board's
    sensitivities and mounting, six-face correction f = (f_raw − accel_bias) / accel_scale (body frame),
    accelerometer roll and pitch, the static gate |‖f‖ − g| < eps, one :class:`TiltBiasKF` per axis
    (``settings``, a :class:`TiltSettings`) fed with the body rates p (roll) and q (pitch). Each axis is treated on its own, which holds for
    turns about one axis at a time (θ̇ = q only while φ = 0). Roll is not updated while
    √(f_y² + f_z²) < roll_min·g: near pitch ±90° the accelerometer roll is the angle of noise.
    """

    def __init__(self, board="mpu6050", rate_hz=None, settings: TiltSettings | None = None, eps=DEFAULT_EPS,
                 roll_min=0.5, bias_seconds=2.0, accel_bias=(0.0, 0.0, 0.0), accel_scale=(1.0, 1.0, 1.0)):
        self.board = get_board(board) if isinstance(board, str) else board
        self.rate_hz = float(rate_hz or self.board.rate_hz)
        dt = 1.0 / self.rate_hz
        self.kfs = [TiltBiasKF(dt, settings) for _ in range(2)]
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
        return self.kfs[0]._advance(p, roll, roll_ok)[0], self.kfs[1]._advance(q, pitch, ok)[0]


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
        raise KeyError(f"recording {rec.path or ''} has no tilt-protocol phases ({', '.join(known)}): "
                       f"record it with the guided tilt protocol (kfkit capture --protocol tilt)")
    for label in labels:
        mask = rec.phase(label)
        roll[mask], pitch[mask] = known[label]
    return roll, pitch
