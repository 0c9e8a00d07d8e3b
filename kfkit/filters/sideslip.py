"""Lab 06: sideslip angle β from steering, yaw rate and lateral acceleration (bicycle-model KF).

State x = [β, r] (rad, rad/s), optionally [β, r, b_ay] with a lateral-accelerometer bias
(m/s²); input δ (road-wheel steering, rad); measurement z = [r, a_y] (rad/s, m/s²). The linear
bicycle model (:func:`kfkit.vehicle.linear_model`) at the measured speed V_x is discretised
exactly (ZOH + Van Loan, :func:`kfkit.discrete.discretize`) and the measurement has a direct
feed-through D: a_y responds to δ at once, through the front tyre force::

    predict   x⁻ = Ad x + Bd δ_{k−1}          P⁻ = Ad P Adᵀ + Qd
    update    y = z − (C x⁻ + D δ_k)          S = C P⁻ Cᵀ + R,  K = P⁻ Cᵀ S⁻¹
              x = x⁻ + K y                    P = (I − K C) P⁻ (I − K C)ᵀ + K R Kᵀ   (Joseph form; the
              2-state loop is written out on floats with the equal P⁻ − K S Kᵀ)

Process noise (continuous white noise, tuning knobs): ``q_beta`` on β̇ (rad²/s) for lateral
force model errors (cornering stiffness, bank, tyre nonlinearity), ``q_r`` on ṙ (rad²/s³) for
yaw-moment errors, ``q_bias_ay`` for the a_y bias random walk ((m/s²)²/s).

Low speed: the model's coefficients grow like 1/V_x and 1/V_x² as V_x → 0. Below ``v_min``
(default 2 m/s) the filter does not use the model: it predicts the kinematic (no-slip) sideslip
β⁻ = b·δ/L, which is the model's own steady state as V_x → 0, with variance ``beta_low_std²``
and no correlation to r, keeps r⁻ = r (P_rr grows by q_r·dt), and updates with the yaw rate
only (a_y carries no information on β at a crawl). Nothing divides by V_x there, so a stop or a
start from rest is safe; the run's ``low_speed`` mask says which samples were handled so.

:class:`SideslipKF` is the filter (construct with dt and a :class:`SideslipKFSettings`; ``step`` one
sample, ``run`` a drive → :class:`SideslipRun`); ``estimate_sideslip(..., model=linear_model)``
(:mod:`kfkit.filters.sideslip_estimate`) runs it over a drive.

Speed and sample-interval changes: (Ad, Bd, Qd) are recomputed whenever V_x moves to another
``vx_step`` bin (default 0.05 m/s; the model is evaluated at the bin centre, so V_x is off by at most
vx_step/2 and the 1/V_x² coefficient by at most vx_step/V_x: 2.5 % at v_min = 2 m/s, 1 % at 5 m/s,
0.2 % at 25 m/s, far inside the ±20 % to which a cornering stiffness is known) or the sample interval
moves to another 0.1 % bin around the median interval (logger timestamps jitter; without bins that
would be two matrix exponentials per sample). Each bin is computed once per run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from threadpoolctl import ThreadpoolController

from ..discrete import discretize
from ..vehicle import BicycleParams, linear_model
from .contract import FilterRun, State, Step, check_settings, configure, sample_period, shaped
from .linear import KalmanFilter


@dataclass(frozen=True)
class SideslipKFSettings:
    """Tuning of the sideslip filter (see the module doc); the defaults are lab 06's.

    q_beta        process noise on β̇, rad²/s (lateral force model errors)                      1e-4
    q_r           process noise on ṙ, rad²/s³ (yaw-moment errors)                               1e-3
    gyro_noise    yaw-rate σ per sample, rad/s                                                0.003
    accel_noise   lateral-acceleration σ per sample, m/s²                                      0.05
    v_min         below this speed the kinematic β = b·δ/L is used, m/s                         2.0
    beta_low_std  σ of that kinematic β, rad                                                     1°
    bias_ay       add an a_y bias state b_ay (m/s²)                                           False
    q_bias_ay     its random walk, (m/s²)²/s                                                   1e-5
    bias_ay_std   its initial σ, m/s²                                                           0.3
    vx_step       width of the speed bins the model is cached at, m/s (≤ v_min)                0.05
    """

    q_beta: float = 1e-4
    q_r: float = 1e-3
    gyro_noise: float = 0.003
    accel_noise: float = 0.05
    v_min: float = 2.0
    beta_low_std: float = math.radians(1.0)
    bias_ay: bool = False
    q_bias_ay: float = 1e-5
    bias_ay_std: float = 0.3
    vx_step: float = 0.05

    def __post_init__(self):
        check_settings(
            self,
            positive=(
                "q_beta",
                "q_r",
                "gyro_noise",
                "accel_noise",
                "v_min",
                "beta_low_std",
                "q_bias_ay",
                "bias_ay_std",
                "vx_step",
            ),
            flags=("bias_ay",),
        )
        if self.vx_step > self.v_min:
            raise ValueError(
                f"SideslipKFSettings: vx_step = {self.vx_step} m/s is coarser than v_min = {self.v_min} m/s: "
                "the slowest speed bin the model is used at would be 0 m/s"
            )

    @property
    def n(self) -> int:
        """Number of states: 2 ([β, r]) or 3 (with b_ay)."""
        return 3 if self.bias_ay else 2


@dataclass
class SideslipState(State):
    """What a sideslip filter carries between samples: x, P, the previous sample's steering δ_{k−1} (rad; None
    before the first) and the time of the last sample a run filtered (s; None after a lone step)."""

    delta_prev: float | None = None
    t_prev: float | None = None


@dataclass
class SideslipRun(FilterRun):
    """:class:`FilterRun` of a :class:`SideslipKF` or :class:`~kfkit.filters.sideslip_ekf.SideslipEKF`
    (x = [β, r(, b_ay)], y = [r, a_y] innovations) with

    vx         the speeds it was run at, m/s (N,)
    low_speed  True where V_x < v_min (kinematic β, yaw-rate-only update: y[:, 1] and S[:, 1] NaN)
    """

    vx: np.ndarray = field(default=None)
    low_speed: np.ndarray = field(default=None)

    @property
    def beta(self) -> np.ndarray:
        """Sideslip β, rad (N,)."""
        return self.x[:, 0]

    @property
    def yaw_rate(self) -> np.ndarray:
        """Yaw rate r, rad/s (N,)."""
        return self.x[:, 1]

    @property
    def vy(self) -> np.ndarray:
        """Lateral velocity V_x·tan β, m/s (N,)."""
        return self.vx * np.tan(self.beta)

    @property
    def bias_ay(self) -> np.ndarray | None:
        """a_y bias estimate, m/s² (N,), or None without the bias state."""
        return self.x[:, 2] if self.x.shape[1] > 2 else None


def sideslip_step(x, P, delta_prev, z, delta, Ad, Bd, Qd, C, D, R):
    """One predict + update of the sideslip KF with the D-term; returns (x, P, y, S).

    x (n,) with n = 2 or 3 (bias state), z = [r, a_y]; Ad, Bd, Qd from :func:`kfkit.discrete.discretize`.
    x⁻ = Ad x + Bd δ_{k−1}, P⁻ = Ad P Adᵀ + Qd; y = z − C x⁻ − D δ_k, S = C P⁻ Cᵀ + R;
    K = P⁻ Cᵀ S⁻¹, x = x⁻ + K y, P = (I − K C) P⁻ (I − K C)ᵀ + K R Kᵀ.
    """
    return sideslip_update(*sideslip_predict(x, P, delta_prev, Ad, Bd, Qd), z, delta, C, D, R)


def sideslip_predict(x, P, delta_prev, Ad, Bd, Qd):
    """x⁻ = Ad x + Bd δ_{k−1},  P⁻ = Ad P Adᵀ + Qd → (x⁻, P⁻)."""
    return Ad @ x + Bd[:, 0] * delta_prev, Ad @ P @ Ad.T + Qd


def sideslip_update(x, P, z, delta, C, D, R):
    """y = z − C x⁻ − D δ_k, S = C P⁻ Cᵀ + R, K = P⁻ Cᵀ S⁻¹; x = x⁻ + K y, P = (I − K C) P⁻ (I − K C)ᵀ + K R Kᵀ
    → (x, P, y, S)."""
    y = z - C @ x - D[:, 0] * delta
    PCt = P @ C.T
    S = C @ PCt + R
    K = PCt @ _inv2(S)
    IKC = np.eye(len(x)) - K @ C
    return x + K @ y, IKC @ P @ IKC.T + K @ R @ K.T, y, S


def _inv2(S):
    """Inverse of a 2×2 matrix by its adjugate (S is an innovation covariance: det > 0)."""
    (a, b), (c, d) = S.tolist()
    det = a * d - b * c
    return np.array([[d, -b], [-c, a]]) / det


def _as_inputs(t, delta, yaw_rate, ay, vx):
    arrays = {"t": t, "delta": delta, "yaw_rate": yaw_rate, "ay": ay, "vx": vx}
    out = {}
    for name, value in arrays.items():
        a = np.asarray(value, dtype=float)
        if a.ndim != 1:
            raise ValueError(f"sideslip filter: {name} must be a 1-D array of samples, got shape {a.shape}")
        out[name] = a
    lengths = {name: len(a) for name, a in out.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(
            "sideslip filter: inputs have mismatched lengths: " + ", ".join(f"{k} {n}" for k, n in lengths.items())
        )
    if lengths["t"] < 2:
        raise ValueError(f"sideslip filter: need at least 2 samples, got {lengths['t']}")
    for name, a in out.items():
        bad = ~np.isfinite(a)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(
                f"sideslip filter: {name}[{k}] is {a[k]} (at t = {out['t'][k] if name != 't' else '?'} s); "
                f"{int(bad.sum())} non-finite value(s) in {name}: drop or interpolate those samples first"
            )
    steps = np.diff(out["t"])
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        raise ValueError(
            f"sideslip filter: t must increase; t[{k}] = {out['t'][k]} s after t[{k - 1}] = {out['t'][k - 1]} s"
        )
    if np.any(out["vx"] < 0):
        k = int(np.argmax(out["vx"] < 0))
        raise ValueError(
            f"sideslip filter: vx[{k}] = {out['vx'][k]} m/s is negative (reversing): the bicycle model here "
            "is for forward driving; cut the recording or pass speeds ≥ 0"
        )
    return out


DT_BIN = 1e-3  # relative width of the sample-interval bins (0.1 %: 10 µs at 100 Hz)


class _ModelCache:
    """(Ad, Bd, Qd, C, D) per bin of V_x (``vx_step`` m/s wide) and of dt (0.1 % around ``dt0``).

    The model is discretised at the bin's speed and interval: V_x = key·vx_step, dt = dt0·(1 + DT_BIN)^key,
    so an evenly sampled drive uses its exact interval.
    """

    def __init__(self, model, params, Qc, bias, vx_step, dt0):
        self.model, self.params, self.Qc, self.bias, self.vx_step, self.dt0 = model, params, Qc, bias, vx_step, dt0
        self.table = {}

    def __call__(self, vx, dt):
        key = (round(vx / self.vx_step), round(math.log(dt / self.dt0) / math.log1p(DT_BIN)))
        entry = self.table.get(key)
        if entry is None:
            A, B, C, D = self.model(self.params, key[0] * self.vx_step)
            if self.bias:  # b_ay is a random walk that adds to the a_y measurement
                A = np.pad(A, ((0, 1), (0, 1)))
                B = np.vstack([B, [[0.0]]])
                C = np.hstack([C, [[0.0], [1.0]]])
            Ad, Bd, Qd = discretize(A, B, self.dt0 * (1.0 + DT_BIN) ** key[1], self.Qc)
            flat = (*Ad.ravel().tolist(), *Bd.ravel().tolist(), Qd[0, 0], Qd[0, 1], Qd[1, 1], C[1, 0], C[1, 1], D[1, 0])
            entry = ((Ad, Bd, Qd, C, D), flat)
            self.table[key] = entry
        return entry


class SideslipKF:
    """The lab 06 filter: sideslip β from steering, yaw rate and lateral acceleration (module doc), a
    :class:`~kfkit.filters.contract.TunedFilter`.

    dt        nominal sample interval, s (or ``rate_hz``, Hz): the step's default and the centre of the interval bins
    params    the car (:class:`BicycleParams`)
    settings  :class:`SideslipKFSettings`; keyword changes apply on top: ``SideslipKF(0.01, car, bias_ay=True)``
    model     ``model(params, vx)`` → (A, B, C, D); may be swapped for a teaching comparison
    x0, P0    initial state (default 0) and covariance (default diag((2°)², (2°/s)², bias_ay_std²)),
              one step before the first sample
    """

    def __init__(
        self,
        dt=None,
        params: BicycleParams = BicycleParams(),
        settings: SideslipKFSettings | None = None,
        *,
        rate_hz=None,
        model=linear_model,
        x0=None,
        P0=None,
        **changes,
    ):
        self.dt, self.params, self.model = sample_period("SideslipKF", dt, rate_hz), params, model
        self.settings = st = configure(SideslipKFSettings, settings, changes, "SideslipKF")
        n = st.n
        self.R = np.diag([st.gyro_noise**2, st.accel_noise**2])
        self._models = _ModelCache(
            model, params, np.diag([st.q_beta, st.q_r, st.q_bias_ay][:n]), st.bias_ay, st.vx_step, self.dt
        )
        self._kinematic_gain = params.b / params.wheelbase
        self._x0, self._P0 = (
            np.zeros(n),
            np.diag([math.radians(2.0) ** 2, math.radians(2.0) ** 2, st.bias_ay_std**2][:n]),
        )
        self.reset(x0, P0)

    def reset(self, x0=None, P0=None):
        """State ← the start (a given x0 or P0 replaces the start's); δ_{k−1} and the last time forgotten."""
        self._x0, self._P0 = _start(self, x0, P0)
        self.state = SideslipState(self._x0.copy(), self._P0.copy())

    def step(self, delta, yaw_rate, ay, vx, dt=None) -> Step:
        """One sample: road-wheel steering δ (rad), yaw rate (rad/s), a_y (m/s²), speed V_x (m/s), dt (s,
        default the nominal one) → Step(x, P, y = [r, a_y] innovations, S, x⁻, P⁻); below v_min y[1] and S's
        a_y row and column are NaN (no a_y update). The prediction uses the previous sample's δ."""
        st, s = self.settings, self.state
        dt = self.dt if dt is None else dt
        delta_prev = delta if s.delta_prev is None else s.delta_prev
        s.delta_prev, s.t_prev = delta, None
        if vx < st.v_min:
            x_prior, P_prior, s.x, s.P, y, S = low_speed_step(
                s.x, s.P, yaw_rate, delta * self._kinematic_gain, st, dt, st.q_bias_ay * dt
            )
        elif st.n == 2:
            x_prior, P_prior, s.x, s.P, y, S = _step2(
                s.x, s.P, delta_prev, (yaw_rate, ay), delta, self._models(vx, dt)[1], self.R
            )
        else:
            Ad, Bd, Qd, C, D = self._models(vx, dt)[0]
            x_prior, P_prior = sideslip_predict(s.x, s.P, delta_prev, Ad, Bd, Qd)
            s.x, s.P, y, S = sideslip_update(x_prior, P_prior, np.array([yaw_rate, ay]), delta, C, D, self.R)
        return Step(s.x, s.P, y, S, x_prior, P_prior)

    def run(self, t, delta, yaw_rate, ay, vx, *, resume=False) -> SideslipRun:
        """:meth:`step` over a drive: t (s), delta (rad, road wheel), yaw_rate (rad/s), ay (m/s²), vx (m/s ≥ 0),
        equal-length 1-D arrays, ISO 8855 signs → :class:`SideslipRun`. From the start, the first step's dt the
        nominal one; with ``resume=True`` from the current state, the first dt from the last run's last time."""
        return _run_drive(self, _as_inputs(t, delta, yaw_rate, ay, vx), resume)


def _start(kf, x0, P0):
    """A sideslip filter's start (x0, P0) with a given x0 or P0 (checked against its state size) replacing ``kf``'s."""
    n, owner = len(kf._x0), type(kf).__name__
    return (
        kf._x0 if x0 is None else shaped(owner, "x0", x0, (n,)),
        kf._P0 if P0 is None else shaped(owner, "P0", P0, (n, n)),
    )


def _run_drive(kf, d, resume) -> SideslipRun:
    """``kf.step`` (either sideslip filter) over the checked drive ``d``, with one BLAS thread →
    :class:`SideslipRun`."""
    if not resume:
        kf.reset()
    t_prev = kf.state.t_prev
    ts, N, n = d["t"].tolist(), len(d["t"]), len(kf.state.x)
    dts = [None if t_prev is None else ts[0] - t_prev] + [b - a for a, b in zip(ts[:-1], ts[1:])]
    out = [
        np.empty((N, n)),
        np.empty((N, n, n)),
        np.empty((N, 2)),
        np.empty((N, 2, 2)),
        np.empty((N, n)),
        np.empty((N, n, n)),
    ]
    step = kf.step
    with _blas_controller().limit(limits=1, user_api="blas"):
        for k, args in enumerate(
            zip(d["delta"].tolist(), d["yaw_rate"].tolist(), d["ay"].tolist(), d["vx"].tolist(), dts)
        ):
            s = step(*args)
            out[0][k], out[1][k], out[2][k], out[3][k], out[4][k], out[5][k] = s.x, s.P, s.y, s.S, s.x_prior, s.P_prior
    kf.state.t_prev = ts[-1]
    return SideslipRun(*out, vx=d["vx"], low_speed=d["vx"] < kf.settings.v_min)


@lru_cache(maxsize=1)
def _blas_controller():
    """BLAS thread control: the filter loop runs with one BLAS thread. scipy's expm on these 2×2–6×6
    matrices wakes OpenBLAS's thread pool, which on a busy machine costs more than the work itself
    (``benchmarks/bench_sideslip.py``'s "BLAS threads" table measures both ways)."""
    return ThreadpoolController()


def _step2(x, P, delta_prev, z, delta, m, R):
    """:func:`sideslip_step` for x = [β, r] written out on floats (no 2×2 NumPy calls: the benchmark's speed table) →
    (x⁻, P⁻, x, P, y, S).

    C = [[0, 1], [c21, c22]], D = [0, d2] as the bicycle model has them; P⁺ = P⁻ − K S Kᵀ, which equals
    the Joseph form for the optimal gain and stays symmetric as computed here.
    """
    a11, a12, a21, a22, b1, b2, q11, q12, q22, c21, c22, d2 = m
    x0, x1 = x.tolist()
    (p11, p12), (_, p22) = P.tolist()
    # predict
    x0, x1 = a11 * x0 + a12 * x1 + b1 * delta_prev, a21 * x0 + a22 * x1 + b2 * delta_prev
    m11, m12 = a11 * p11 + a12 * p12, a11 * p12 + a12 * p22
    m21, m22 = a21 * p11 + a22 * p12, a21 * p12 + a22 * p22
    p11, p12, p22 = m11 * a11 + m12 * a12 + q11, m11 * a21 + m12 * a22 + q12, m21 * a21 + m22 * a22 + q22
    x_prior, P_prior = np.array([x0, x1]), np.array([[p11, p12], [p12, p22]])
    # update: PCᵀ columns are P[:, 1] and P·[c21, c22]
    y1, y2 = z[0] - x1, z[1] - c21 * x0 - c22 * x1 - d2 * delta  # z = (r, a_y)
    u0, u1 = p11 * c21 + p12 * c22, p12 * c21 + p22 * c22
    s11, s12, s22 = p22 + R[0, 0], u1, c21 * u0 + c22 * u1 + R[1, 1]
    det = s11 * s22 - s12 * s12
    i11, i12, i22 = s22 / det, -s12 / det, s11 / det
    k11, k12 = p12 * i11 + u0 * i12, p12 * i12 + u0 * i22
    k21, k22 = p22 * i11 + u1 * i12, p22 * i12 + u1 * i22
    x0, x1 = x0 + k11 * y1 + k12 * y2, x1 + k21 * y1 + k22 * y2
    # P − K S Kᵀ = P − K (PCᵀ)ᵀ
    p11, p12, p22 = p11 - (k11 * p12 + k12 * u0), p12 - (k11 * p22 + k12 * u1), p22 - (k21 * p22 + k22 * u1)
    return (
        x_prior,
        P_prior,
        np.array([x0, x1]),
        np.array([[p11, p12], [p12, p22]]),
        np.array([y1, y2]),
        np.array([[s11, s12], [s12, s22]]),
    )


def low_speed_step(x, P, yaw_rate, beta_kin, settings, dt, q_bias_dt=0.0):
    """Below v_min (both sideslip filters): β⁻ = b δ / L (kinematic, variance beta_low_std², no correlation), r⁻ = r
    (P_rr grows by q_r·dt), a bias state's variance by ``q_bias_dt``; the yaw rate (gyro_noise²) updates alone.
    Returns (x⁻, P⁻, x, P, y, S) with the a_y entries of the innovation y and of S NaN (no a_y update)."""
    x_prior, P_prior = x.copy(), P.copy()
    x_prior[0] = beta_kin
    P_prior[0, :] = P_prior[:, 0] = 0.0
    P_prior[0, 0] = settings.beta_low_std**2
    P_prior[1, 1] += settings.q_r * dt
    if len(x) > 2:
        P_prior[2, 2] += q_bias_dt
    y, S = np.full(2, np.nan), np.full((2, 2), np.nan)
    y[0] = yaw_rate - x_prior[1]
    S[0, 0] = P_prior[1, 1] + settings.gyro_noise**2
    K = P_prior[:, 1] / S[0, 0]
    P = P_prior - np.outer(K, P_prior[1, :])  # (I − K e_rᵀ) P⁻: the scalar update, exact for a scalar measurement
    return x_prior, P_prior, x_prior + K * y[0], 0.5 * (P + P.T), y, S


def kinematic_sideslip(t, yaw_rate, ay, vx, vy0=0.0):
    """Open-loop kinematic lateral velocity: v̇_y = a_y − V_x·r (m/s²) integrated (trapezoid).

    Exact kinematics of a rigid body in the plane, no tyre model; but an a_y bias b makes v_y
    drift by b·t (m/s) and nothing pulls it back. Returns (v_y (m/s), β = atan(v_y / V_x) rad;
    NaN where V_x = 0).
    """
    t, r, ay, vx = (np.asarray(v, dtype=float) for v in (t, yaw_rate, ay, vx))
    rate = ay - vx * r
    vy = vy0 + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = np.where(vx > 0, np.arctan2(vy, vx), np.nan)
    return vy, beta


def copied_kinematic_kf(t, yaw_rate, ay, vx, q=1e-4, gyro_noise=0.003, accel_noise=0.05):
    """NOT a valid filter: the widely copied "kinematic" KF, kept for lab 06's lesson.

    State [v_y, r] with F = [[1, dt], [0, 1]] (so v_y ← v_y + r·dt adds rad to m/s), measuring
    z = [a_y·dt, r] with H = I (a velocity increment compared with a velocity).
    Returns (v_y, β = atan(v_y / V_x)) like :func:`kinematic_sideslip`.
    """
    t, r, ay, vx = (np.asarray(v, dtype=float) for v in (t, yaw_rate, ay, vx))
    dt = float(np.median(np.diff(t)))
    kf = KalmanFilter(
        F=[[1.0, dt], [0.0, 1.0]],
        H=np.eye(2),
        Q=q * np.eye(2),
        R=np.diag([(accel_noise * dt) ** 2, gyro_noise**2]),
        x0=np.zeros(2),
        P0=np.eye(2),
    )
    run = kf.run(np.column_stack([ay * dt, r]))
    vy = run.x[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = np.where(vx > 0, np.arctan2(vy, vx), np.nan)
    return vy, beta
