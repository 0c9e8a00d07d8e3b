"""Single-track (bicycle) vehicle models (made discrete by :func:`kfkit.discrete.discretize`) and simulated
drives; their files are :mod:`kfkit.io`'s vehicle format (``# kfkit-vehicle v1``; a CSV of your own:
:mod:`kfkit.readers.vehicle_csv`).

Axes and signs follow ISO 8855: x forward, y left, z up; steering δ > 0 turns left, yaw rate
r > 0 is a left turn, lateral acceleration a_y > 0 points left. (The IMU labs use FRD: an IMU
mounted FRD gives r = −g_z and a_y = −f_y.) Sideslip β = atan(v_y / V_x) is the angle between
the heading and the velocity of the centre of gravity (CG).

Linear model (small angles, per-axle cornering stiffnesses Cf, Cr > 0 in N/rad), state [β, r],
input δ, outputs [r, a_y]::

    β̇  = −(Cf+Cr)/(m Vx)·β + [(b Cr − a Cf)/(m Vx²) − 1]·r + Cf/(m Vx)·δ        rad/s
    ṙ  =  (b Cr − a Cf)/Iz·β − (a² Cf + b² Cr)/(Iz Vx)·r + a Cf/Iz·δ             rad/s²
    a_y = Vx (β̇ + r) = −(Cf+Cr)/m·β + (b Cr − a Cf)/(m Vx)·r + Cf/m·δ            m/s²

Reference for the model and the default car: R. Rajamani, *Vehicle Dynamics and Control*,
2nd ed., Springer 2012, ch. 2–3 (lateral dynamics; the example car of ch. 3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .frames import G
from .io import Recording

KMH = 1.0 / 3.6  # m/s per km/h


# --- parameters -----------------------------------------------------------------------------


@dataclass(frozen=True)
class BicycleParams:
    """Single-track vehicle parameters (SI). The default is a mid-size passenger car.

    m   mass, kg                                   1573
    Iz  yaw moment of inertia about the CG, kg·m²   2873
    a   CG → front axle, m                          1.10
    b   CG → rear axle, m                           1.58
    Cf  front-axle cornering stiffness, N/rad       160 000  (2 × 80 000 per tyre)
    Cr  rear-axle cornering stiffness, N/rad        160 000  (2 × 80 000 per tyre)
    mu  tyre–road friction coefficient (nonlinear model only), 1.0 (dry asphalt)

    Numbers from the example passenger sedan of R. Rajamani, *Vehicle Dynamics and Control* (2nd ed.,
    Springer 2012, ch. 3, lateral vehicle dynamics), whose Cαf = Cαr = 80 000 N/rad are per tyre (his
    equations carry 2Cα per axle); the bicycle model lumps both tyres of an axle, so Cf = Cr =
    160 000 N/rad here. Plausible: 80 000 N/rad ≈ 1400 N/° per tyre (passenger tyres: 1000–2000 N/°),
    Iz ≈ m·a·b (2734 kg·m²), 59 % of the weight on the front axle. Understeering: a·Cf < b·Cr
    (176 000 < 252 800 N·m/rad), understeer gradient K ≈ 0.0018 rad/(m/s²) ≈ 1°/g.
    """

    m: float = 1573.0
    Iz: float = 2873.0
    a: float = 1.10
    b: float = 1.58
    Cf: float = 160_000.0
    Cr: float = 160_000.0
    mu: float = 1.0

    def __post_init__(self):
        for name in ("m", "Iz", "a", "b", "Cf", "Cr", "mu"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
                raise ValueError(f"BicycleParams.{name} must be a finite positive number, got {value!r}")

    @property
    def wheelbase(self) -> float:
        """L = a + b, m."""
        return self.a + self.b

    @property
    def understeer_gradient(self) -> float:
        """K = m/L·(b/Cf − a/Cr), rad per m/s² (> 0: understeer); steady state δ = L/R + K·a_y."""
        return self.m / self.wheelbase * (self.b / self.Cf - self.a / self.Cr)

    def scaled(self, cornering: float = 1.0) -> BicycleParams:
        """The same car with both cornering stiffnesses multiplied by ``cornering`` (e.g. 0.8)."""
        return replace(self, Cf=self.Cf * cornering, Cr=self.Cr * cornering)


# --- the linear model and its discretisation -----------------------------------------------


def _check_speed(vx, who="linear_model"):
    vx = float(vx)
    if not (math.isfinite(vx) and vx > 0):
        raise ValueError(
            f"{who}: the bicycle model needs a forward speed Vx > 0 m/s (its coefficients divide by Vx), "
            f"got Vx = {vx!r}"
        )
    return vx


def linear_model(params: BicycleParams, vx: float):
    """Continuous linear bicycle model at speed ``vx`` (m/s): (A, B, C, D) for x = [β, r], u = δ, z = [r, a_y].

    ẋ = A x + B δ,  z = C x + D δ; the equations are in the module docstring. Raises for vx ≤ 0.
    """
    vx = _check_speed(vx)
    m, Iz, a, b, Cf, Cr = params.m, params.Iz, params.a, params.b, params.Cf, params.Cr
    # the matrices as the equations write them, one row a line
    # fmt: off
    A = np.array([[-(Cf + Cr) / (m * vx), (b * Cr - a * Cf) / (m * vx ** 2) - 1.0],
                  [(b * Cr - a * Cf) / Iz, -(a * a * Cf + b * b * Cr) / (Iz * vx)]])
    B = np.array([[Cf / (m * vx)], [a * Cf / Iz]])
    C = np.array([[0.0, 1.0],
                  [-(Cf + Cr) / m, (b * Cr - a * Cf) / (m * vx)]])
    D = np.array([[0.0], [Cf / m]])
    # fmt: on
    return A, B, C, D


def steady_state(params: BicycleParams, vx: float, delta: float):
    """Steady cornering of the linear model at constant δ (rad): (β, r, a_y) from 0 = A x + B δ."""
    A, B, C, D = linear_model(params, vx)
    x = -np.linalg.solve(A, B[:, 0] * delta)
    z = C @ x + D[:, 0] * delta
    return float(x[0]), float(x[1]), float(z[1])


def units_consistent(model, params: BicycleParams = BicycleParams(), vx: float = 15.0, rtol=1e-9):
    """Dimensional check of a model function ``model(params, vx) → (A, B, C, D)`` by changing units.

    Re-express the car in other units of length (×λ), mass (×μ) and time (×τ): a quantity with
    dimension Lᵖ Mᵍ Tˢ changes by λᵖ μᵍ τˢ. Each entry of A, B, C, D has a known dimension
    (rad is dimensionless): β̇ per β is 1/T, β̇ per r is 1, ṙ per β is 1/T², a_y per β is L/T², …
    A correct model rescales exactly so; a coefficient with a wrong power of Vx does not.
    Returns a dict 'A[i,j]' → True / False for every entry (entries that are 0 are skipped).
    """
    lam, mu, tau = 0.37, 2.9, 1.7  # arbitrary unit changes
    other = BicycleParams(
        m=params.m * mu,
        Iz=params.Iz * mu * lam**2,
        a=params.a * lam,
        b=params.b * lam,
        Cf=params.Cf * mu * lam / tau**2,
        Cr=params.Cr * mu * lam / tau**2,
        mu=params.mu,
    )
    # dimension exponents (L, T) of each entry; mass never survives in a ratio of the outputs
    dims = {
        "A": [[(0, -1), (0, 0)], [(0, -2), (0, -1)]],
        "B": [[(0, -1)], [(0, -2)]],
        "C": [[(0, 0), (0, 0)], [(1, -2), (1, -1)]],
        "D": [[(0, 0)], [(1, -2)]],
    }
    base = dict(zip("ABCD", model(params, vx)))
    moved = dict(zip("ABCD", model(other, vx * lam / tau)))
    result = {}
    for name, table in dims.items():
        for i, row in enumerate(table):
            for j, (p, s) in enumerate(row):
                ref = float(np.asarray(base[name])[i, j])
                if ref == 0.0:
                    continue
                got = float(np.asarray(moved[name])[i, j])
                result[f"{name}[{i},{j}]"] = bool(abs(got - ref * lam**p * tau**s) <= rtol * abs(ref * lam**p * tau**s))
    return result


def miscopied_linear_model(params: BicycleParams, vx: float):
    """NOT a vehicle model: the widely copied version of :func:`linear_model` with three errors.

    Kept only so lab 06 can show what it does. Compared with the correct model:
    β̇'s r-coefficient (b Cr − a Cf)/(m Vx) − 1 (should be over m Vx²: units m/s, not 1);
    ṙ's β-coefficient (b Cr − a Cf)/(Iz Vx) (should not divide by Vx: units 1/(m·s), not 1/s²);
    a_y's r-coefficient (b Cr − a Cf)/(m Vx) + Vx (the centripetal Vx·r counted twice).
    """
    A, B, C, D = linear_model(params, vx)
    A, C = A.copy(), C.copy()
    A[0, 1] = (params.b * params.Cr - params.a * params.Cf) / (params.m * vx) - 1.0
    A[1, 0] = (params.b * params.Cr - params.a * params.Cf) / (params.Iz * vx)
    C[1, 1] += vx
    return A, B, C, D


# --- the nonlinear single-track truth model ---------------------------------------------------


@dataclass(frozen=True)
class MagicFormula:
    """Pacejka's magic formula for one axle: F_y = D sin(C atan(Bα − E(Bα − atan Bα))), N.

    D = µ·F_z (peak force), C = 1.3 (shape factor typical of lateral force), E = −1.0
    (curvature; E < 1); B = C_α / (C·D) so that the initial slope B·C·D equals the axle's
    cornering stiffness C_α (N/rad).
    """

    B: float
    C: float
    D: float
    E: float

    @classmethod
    def for_axle(cls, stiffness, vertical_load, mu, C=1.3, E=-1.0):
        D = mu * vertical_load
        return cls(stiffness / (C * D), C, D, E)

    def force(self, alpha):
        """Lateral force (N) at slip angle ``alpha`` (rad); works on floats and arrays."""
        x = self.B * alpha
        return self.D * np.sin(self.C * np.arctan(x - self.E * (x - np.arctan(x))))

    def slope(self, alpha):
        """dF_y/dα (N/rad) at ``alpha`` (rad): the local cornering stiffness, B·C·D at α = 0, 0 at the
        force's peak and negative beyond it. With x = Bα, φ = x − E(x − atan x):
        dF/dα = D cos(C atan φ)·C/(1 + φ²)·B(1 − E + E/(1 + x²))."""
        x = self.B * alpha
        phi = x - self.E * (x - np.arctan(x))
        return (
            self.D
            * np.cos(self.C * np.arctan(phi))
            * self.C
            / (1.0 + phi * phi)
            * self.B
            * (1.0 - self.E + self.E / (1.0 + x * x))
        )


def axle_tyres(params: BicycleParams):
    """Front and rear :class:`MagicFormula` with static loads F_zf = m g b/L, F_zr = m g a/L."""
    L = params.wheelbase
    return (
        MagicFormula.for_axle(params.Cf, params.m * G * params.b / L, params.mu),
        MagicFormula.for_axle(params.Cr, params.m * G * params.a / L, params.mu),
    )


def peak_friction(t, ay, window_s: float = 0.5) -> float:
    """The friction a drive shows without its sideslip: µ ≥ max |ā_y| / g, ā_y the lateral acceleration (m/s²)
    averaged over ``window_s`` seconds (a centred moving mean, at the median sample interval of ``t``, s).

    Each axle's force is at most µ F_z and the static loads add up to m g, so m |a_y| ≤ µ m g: the tyres made at
    least the grip the car measured. On a drive at the limit (a race track) the bound is µ itself; on a gentle drive
    it says only that µ is above it. The mean keeps a corner's sustained force and averages out the body's vibration
    (white noise of σ per sample shrinks by √(samples in the window)), which a single sample's peak would count.
    """
    t, ay = np.asarray(t, dtype=float), np.asarray(ay, dtype=float)
    if not np.all(np.isfinite(ay)):
        k = int(np.argmax(~np.isfinite(ay)))
        raise ValueError(f"peak_friction: ay[{k}] is {ay[k]}: drop or interpolate non-finite samples first")
    n = max(1, int(round(window_s / float(np.median(np.diff(t))))))
    if len(ay) < n:
        raise ValueError(
            f"peak_friction: the drive ({len(ay)} samples) is shorter than the {window_s:g} s window ({n} samples)"
        )
    return float(np.max(np.abs(np.convolve(ay, np.ones(n) / n, mode="valid"))) / G)


MIN_TRUTH_SPEED = 0.5  # m/s: slip angles atan(v/Vx) are meaningless at a standstill


def simulate_nonlinear(params: BicycleParams, t, delta, vx, substeps: int = 4):
    """Drive the nonlinear single-track model with steering ``delta`` (rad) and speed ``vx`` (m/s).

    State [v_y, r] in the body frame; slip angles α_f = δ − atan((v_y + a r)/V_x),
    α_r = −atan((v_y − b r)/V_x); magic-formula tyre forces (:func:`axle_tyres`);
        m (v̇_y + V_x r) = F_yf cos δ + F_yr,     I_z ṙ = a F_yf cos δ − b F_yr.
    V_x is prescribed (the driver holds the speed), which is the lab's "slowly varying V_x".
    Fixed-step RK4 with ``substeps`` steps per sample and δ, V_x held over each sample (the
    same zero-order hold the filter assumes): deterministic, aligned with the samples and fast
    in plain Python; the fastest mode at 2 m/s is ≈ (Cf+Cr)/(m Vx) ≈ 100 /s, so a 2.5 ms step
    keeps |λ h| < 0.3, well inside RK4's stability region (2.8). solve_ivp would need the inputs
    interpolated and adapts its step for nothing. Returns dict of arrays: vy, r, beta, ay (m/s²).
    """
    t = np.asarray(t, dtype=float)
    delta = np.asarray(delta, dtype=float)
    vx = np.broadcast_to(np.asarray(vx, dtype=float), t.shape)
    if np.any(vx < MIN_TRUTH_SPEED):
        k = int(np.argmax(vx < MIN_TRUTH_SPEED))
        raise ValueError(
            f"simulate_nonlinear: V_x = {vx[k]:.3g} m/s at t = {t[k]:.3f} s is below {MIN_TRUTH_SPEED} m/s, "
            "where tyre slip angles are undefined"
        )
    front, rear = axle_tyres(params)
    m, Iz, a, b = params.m, params.Iz, params.a, params.b

    def forces(vy, r, d, u):
        fyf = front.force(d - math.atan((vy + a * r) / u)) * math.cos(d)
        fyr = rear.force(-math.atan((vy - b * r) / u))
        return fyf, fyr

    def deriv(vy, r, d, u):
        fyf, fyr = forces(vy, r, d, u)
        return (fyf + fyr) / m - u * r, (a * fyf - b * fyr) / Iz

    N = len(t)
    vys, rs, ays = np.empty(N), np.empty(N), np.empty(N)
    vy = r = 0.0
    for k in range(N):
        d, u = float(delta[k]), float(vx[k])
        fyf, fyr = forces(vy, r, d, u)
        vys[k], rs[k], ays[k] = vy, r, (fyf + fyr) / m
        if k + 1 == N:
            break
        h = (t[k + 1] - t[k]) / substeps
        for _ in range(substeps):
            k1 = deriv(vy, r, d, u)
            k2 = deriv(vy + 0.5 * h * k1[0], r + 0.5 * h * k1[1], d, u)
            k3 = deriv(vy + 0.5 * h * k2[0], r + 0.5 * h * k2[1], d, u)
            k4 = deriv(vy + h * k3[0], r + h * k3[1], d, u)
            vy += h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            r += h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return {"vy": vys, "r": rs, "beta": np.arctan2(vys, vx), "ay": ays}


# --- scenarios ---------------------------------------------------------------------------------


@dataclass
class Drive:
    """A prescribed drive: times (s), road-wheel steering δ (rad), speed V_x (m/s), labelled windows."""

    t: np.ndarray
    delta: np.ndarray
    vx: np.ndarray
    phases: list
    description: str


def ay_gain(params: BicycleParams, vx: float, freq_hz: float) -> float:
    """|a_y/δ| (m/s² per rad) of the linear model for sinusoidal steering at ``freq_hz``."""
    A, B, C, D = linear_model(params, vx)
    s = 2j * math.pi * freq_hz
    H = C @ np.linalg.solve(s * np.eye(2) - A, B) + D
    return float(abs(H[1, 0]))


def _speed_ramp(t, t0, t1, v0, v1):
    """V_x going smoothly (cosine blend) from v0 at t0 to v1 at t1."""
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return v0 + (v1 - v0) * 0.5 * (1.0 - np.cos(np.pi * s))


def slalom(
    speed_kmh=20.0,
    cone_spacing=9.0,
    cones=10,
    peak_ay=3.0,
    rate_hz=100.0,
    lead=2.0,
    start_kmh=None,
    params: BicycleParams = BicycleParams(),
) -> Drive:
    """Slalom through ``cones`` cones ``cone_spacing`` m apart at ``speed_kmh``.

    The car passes one cone per half steering period, so δ(t) = δ₀ sin(2π f t) with
    f = V_x / (2·spacing). δ₀ is chosen so the *linear* model's a_y amplitude at that f is
    ``peak_ay`` (m/s²); keep it ≤ 4 m/s² to stay where tyres are nearly linear. With
    ``start_kmh`` the car first accelerates from that speed over ``lead`` s (and brakes back to
    it after the cones), which exercises the filter's low-speed guard.
    """
    v = speed_kmh * KMH
    freq = v / (2.0 * cone_spacing)
    duration = cones * cone_spacing / v
    ramp = 0.0 if start_kmh is None else 3.0
    t = np.arange(0.0, ramp + lead + duration + lead + ramp, 1.0 / rate_hz)
    t0 = ramp + lead
    amplitude = peak_ay / ay_gain(params, v, freq)
    s = (t - t0) * (t >= t0) * (t < t0 + duration)
    delta = amplitude * np.sin(2 * np.pi * freq * s)
    vx = np.full_like(t, v)
    if start_kmh is not None:
        up = _speed_ramp(t, 0.0, ramp, 0.0, 1.0) - _speed_ramp(t, t[-1] - ramp, t[-1], 0.0, 1.0)
        vx = start_kmh * KMH + (v - start_kmh * KMH) * up
    phases = [(t0, t0 + duration, "slalom")]
    text = (
        f"slalom at {speed_kmh:g} km/h through {cones} cones {cone_spacing:g} m apart: steering "
        f"{math.degrees(amplitude):.2f}° (road wheel) at {freq:.3f} Hz, linear-model a_y amplitude {peak_ay:g} m/s²"
    )
    if start_kmh is not None:
        text += f"; from {start_kmh:g} km/h up to speed in {ramp:g} s before and back down after"
    return Drive(t, delta, vx, phases, text)


def lane_change(
    speed_kmh=60.0,
    offset=3.5,
    change_length=40.0,
    hold_length=25.0,
    rate_hz=100.0,
    lead=2.0,
    end_kmh=None,
    params: BicycleParams = BicycleParams(),
) -> Drive:
    """A double lane change (ISO 3888-1 style, approximated): out by ``offset`` m, hold, and back.

    Each lane change is one full sine period of steering over ``change_length`` m of travel;
    its amplitude is scaled (on the nonlinear model, in its linear range) so the car's lateral
    displacement is ``offset`` m. The ISO 3888-1 track is a limit test (≈ 25 m per change);
    the default 40 m keeps a_y near 3 m/s², in the tyres' linear range. With ``end_kmh`` the
    car brakes gently through the manoeuvre.
    """
    v = speed_kmh * KMH
    T, H = change_length / v, hold_length / v
    t = np.arange(0.0, lead + 2 * T + H + lead, 1.0 / rate_hz)
    s1 = np.clip(t - lead, 0.0, T)
    s2 = np.clip(t - lead - T - H, 0.0, T)
    shape = np.sin(2 * np.pi * s1 / T) * (s1 < T) - np.sin(2 * np.pi * s2 / T) * (s2 < T)
    vx = np.full_like(t, v) if end_kmh is None else _speed_ramp(t, lead, t[-1] - lead, v, end_kmh * KMH)
    probe = simulate_nonlinear(params, t, 1e-3 * shape, vx)
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (probe["r"][1:] + probe["r"][:-1]) * np.diff(t))])
    lateral_rate = vx * np.sin(heading + probe["beta"])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (lateral_rate[1:] + lateral_rate[:-1]) * np.diff(t))])
    k_hold = int(np.searchsorted(t, lead + T + 0.5 * H))
    amplitude = 1e-3 * offset / y[k_hold]
    phases = [
        (lead, lead + T, "lane_out"),
        (lead + T, lead + T + H, "hold"),
        (lead + T + H, lead + 2 * T + H, "lane_back"),
    ]
    text = (
        f"double lane change at {speed_kmh:g} km/h"
        + ("" if end_kmh is None else f" braking to {end_kmh:g} km/h")
        + f": {offset:g} m out over {change_length:g} m, {hold_length:g} m hold, back; steering amplitude "
        f"{math.degrees(amplitude):.2f}° (road wheel)"
    )
    return Drive(t, amplitude * shape, vx, phases, text)


# --- sensors and recordings -------------------------------------------------------------------


@dataclass(frozen=True)
class VehicleSensors:
    """Sensor models of a production ESC cluster (σ per sample at 100 Hz; biases drawn per drive).

    gyro_noise   yaw-rate noise, rad/s                    0.003 (≈ 0.17 °/s)
    gyro_bias    σ of the constant yaw-rate bias, rad/s   0.002
    accel_noise  lateral-acceleration noise, m/s²         0.05
    accel_bias   σ of the constant a_y bias, m/s²         0.1 (mounting tilt, road bank)
    steer_ratio  steering-wheel to road-wheel ratio       16; the steering-wheel angle sensor
    steer_lsb    steering-wheel angle resolution, rad     0.1° → road wheel 0.1°/16
    wheel_noise  per-wheel speed noise, m/s               0.05; V_x = mean of the two rear wheels
    speed_lsb    wheel-speed resolution, m/s              1/64 km/h (a common CAN scaling)
    """

    gyro_noise: float = 0.003
    gyro_bias: float = 0.002
    accel_noise: float = 0.05
    accel_bias: float = 0.1
    steer_ratio: float = 16.0
    steer_lsb: float = math.radians(0.1)
    wheel_noise: float = 0.05
    speed_lsb: float = KMH / 64.0


def _quantise(x, lsb):
    return np.round(np.asarray(x) / lsb) * lsb


def simulate_drive(
    drive: Drive,
    params: BicycleParams = BicycleParams(),
    sensors: VehicleSensors = VehicleSensors(),
    seed=0,
    *,
    gyro_bias=None,
    accel_bias=None,
) -> Recording:
    """Simulate ``drive`` on the nonlinear model and its sensors → a vehicle :class:`Recording`.

    Columns t, delta, yaw_rate, ay, vx (measured, SI) and true_beta, true_yaw_rate, true_vy.
    Biases are drawn from ``sensors`` with the seed unless given (rad/s, m/s²).
    """
    rng = np.random.default_rng(seed)
    truth = simulate_nonlinear(params, drive.t, drive.delta, drive.vx)
    N = len(drive.t)
    bg = rng.normal(0.0, sensors.gyro_bias) if gyro_bias is None else float(gyro_bias)
    ba = rng.normal(0.0, sensors.accel_bias) if accel_bias is None else float(accel_bias)
    yaw_rate = truth["r"] + bg + rng.normal(0.0, sensors.gyro_noise, N)
    ay = truth["ay"] + ba + rng.normal(0.0, sensors.accel_noise, N)
    delta = _quantise(drive.delta * sensors.steer_ratio, sensors.steer_lsb) / sensors.steer_ratio
    wheels = [_quantise(drive.vx + rng.normal(0.0, sensors.wheel_noise, N), sensors.speed_lsb) for _ in range(2)]
    vx = np.maximum(0.5 * (wheels[0] + wheels[1]), 0.0)
    rate = 1.0 / float(np.median(np.diff(drive.t)))
    meta = {
        "rate_hz": round(rate, 6),
        "source": "simulated",
        "description": drive.description,
        "axes": "ISO 8855 (x forward, y left, z up)",
        "units": {
            "t": "s",
            "delta": "rad (road wheel)",
            "yaw_rate": "rad/s",
            "ay": "m/s^2",
            "vx": "m/s",
            "true_beta": "rad",
            "true_yaw_rate": "rad/s",
            "true_vy": "m/s",
        },
        "vehicle": {k: getattr(params, k) for k in ("m", "Iz", "a", "b", "Cf", "Cr", "mu")},
        "phases": [{"label": lab, "start": round(s, 6), "end": round(e, 6)} for s, e, lab in drive.phases],
        "sim": {"seed": seed, "gyro_bias": bg, "accel_bias": ba, "sensors": sensors.__dict__},
    }
    data = {
        "t": drive.t,
        "delta": delta,
        "yaw_rate": yaw_rate,
        "ay": ay,
        "vx": vx,
        "true_beta": truth["beta"],
        "true_yaw_rate": truth["r"],
        "true_vy": truth["vy"],
    }
    return Recording(meta, {k: np.asarray(v, dtype=float) for k, v in data.items()})
