"""Truth motions and the IMU simulator that turns them into sensor counts.

A :class:`Motion` is the truth: Euler angles, body angular rate and the linear
acceleration of the board in NED. :func:`simulate_imu` produces what a board would send:

    gyro   ω_s = M_bsᵀ ω_b + b_g(t) + n_g
    accel  f_s = M_bsᵀ R_bn (a_n − g_n) + b_a(t) + n_a,      g_n = [0, 0, g]
    mag    m_s = M_bsᵀ R_bn m_n + n_m

with constant bias plus a bias random walk b(t), white noise of density N (σ = N·√rate),
quantisation to the LSB and saturation at full scale. Every random draw is seeded.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frames import MAG_FIELD_LONDON, G, dcm_to_euler, euler_rates_to_body_rates, euler_to_dcm, mount_matrix
from .io import Recording
from .sensors import SensorSpec
from .sensors import board as get_board


@dataclass
class Motion:
    """Truth sampled at the IMU rate.

    t        (N,)   s, sampled at rate_hz (Hz)
    euler    (N, 3) [roll, pitch, yaw], rad (ZYX)
    omega_b  (N, 3) body angular rate [p, q, r], rad/s
    acc_n    (N, 3) linear acceleration of the board in NED (gravity excluded), m/s²
    phases   labelled time windows [(start_s, end_s, label), …], e.g. (0, 10, "stationary");
             the simulator copies them into the recording's metadata
    """

    t: np.ndarray
    rate_hz: float
    euler: np.ndarray
    omega_b: np.ndarray
    acc_n: np.ndarray
    description: str = ""
    phases: list = field(default_factory=list)


def sample_times(duration: float, rate_hz: float) -> np.ndarray:
    """t_k = k / rate_hz for k = 0 … ⌊duration·rate_hz⌋ − 1 (s)."""
    return np.arange(int(round(duration * rate_hz))) / rate_hz


def stationary(duration: float, rate_hz: float, roll=0.0, pitch=0.0, yaw=0.0) -> Motion:
    """A board at rest at a fixed attitude (rad)."""
    t = sample_times(duration, rate_hz)
    euler = np.tile([roll, pitch, yaw], (len(t), 1)).astype(float)
    zeros = np.zeros((len(t), 3))
    return Motion(
        t,
        rate_hz,
        euler,
        zeros,
        zeros.copy(),
        f"stationary at roll {np.degrees(roll):.0f}°, pitch {np.degrees(pitch):.0f}°",
    )


def sine_roll(
    duration=60.0,
    rate_hz=104.0,
    amplitude=np.radians(30.0),
    freq_hz=0.1,
    still=5.0,
    shakes=(25.0, 45.0),
    shake_duration=3.0,
    shake_accel=3.0,
    shake_freq_hz=2.0,
    vibration_rms=0.0,
    seed=0,
) -> Motion:
    """A board rolled back and forth by hand about its x axis, as in lab 01.

    Roll φ(t) = A·w(t)·sin(2πf(t − t₀)) after ``still`` seconds at rest, where the envelope
    w rises smoothly from 0 to 1 over one second so the rate has no jump. Pitch = yaw = 0,
    so the body rate is p = φ̇.

    Linear accelerations that fool an accelerometer-only tilt:
    - ``shakes``: start times (s) of sideways shakes, a_east = A_s·cos(2πf_s τ) for
      ``shake_duration`` seconds (whole cycles, so the board ends where it began);
    - ``vibration_rms``: white hand vibration on the north/east/down axes, m/s² RMS.
    """
    t = sample_times(duration, rate_hz)
    tau = np.clip(t - still, 0.0, None)
    ramp = np.clip(tau, 0.0, 1.0)
    w = 0.5 * (1.0 - np.cos(np.pi * ramp))
    w_dot = np.where((tau > 0) & (tau < 1.0), 0.5 * np.pi * np.sin(np.pi * ramp), 0.0)
    omega = 2.0 * np.pi * freq_hz
    roll = amplitude * w * np.sin(omega * tau)
    roll_dot = amplitude * (w_dot * np.sin(omega * tau) + w * omega * np.cos(omega * tau))
    euler = np.column_stack([roll, np.zeros_like(t), np.zeros_like(t)])
    euler_dot = np.column_stack([roll_dot, np.zeros_like(t), np.zeros_like(t)])

    acc_n = np.zeros((len(t), 3))
    for t0 in shakes:
        inside = (t >= t0) & (t < t0 + shake_duration)
        acc_n[inside, 1] += shake_accel * np.cos(2.0 * np.pi * shake_freq_hz * (t[inside] - t0))
    if vibration_rms > 0:
        acc_n += np.random.default_rng(seed).normal(0.0, vibration_rms, acc_n.shape)
    desc = (
        f"roll sine {np.degrees(amplitude):.0f}° at {freq_hz:g} Hz after {still:g} s at rest; "
        f"sideways shakes of {shake_accel:g} m/s² at t = {', '.join(f'{s:g}' for s in shakes)} s; "
        f"hand vibration {vibration_rms:g} m/s² RMS"
    )
    return Motion(t, rate_hz, euler, euler_rates_to_body_rates(euler, euler_dot), acc_n, desc)


def tilt_protocol(axes=("pitch", "roll"), hold=2.0, move=1.5, rate_hz=100.0, seed=0, *, hand_accel=1.5) -> Motion:
    """Lab 05's guided tilt protocol: per axis, 0° → 90° → 0° by hand with rests in between.

    For each entry of ``axes`` ("pitch" or "roll"; repeat entries for a longer record): ``hold``
    seconds at 0°, a turn to 90° over ``move`` seconds, ``hold`` at 90°, a turn back, ``hold`` at 0°.
    A turn follows α(s) = (π/2)·(1 − cos(π s / move))/2, so the rate starts and ends at zero.
    While turning, the hand also accelerates the board: a_n(s) = A·sin(2π s / move) on each NED
    axis with A ~ N(0, hand_accel²) (m/s²), one whole cycle so the board ends at rest.
    Holds are labelled "<axis>_0" and "<axis>_90" (all 0° holds of an axis share a label); turns
    are unlabelled.
    """
    unknown = [a for a in axes if a not in ("roll", "pitch")]
    if unknown or not axes:
        raise ValueError(f"tilt_protocol: axes must be 'roll' or 'pitch', got {list(axes)}")
    rng = np.random.default_rng(seed)
    per_axis = 3 * hold + 2 * move
    t = sample_times(per_axis * len(axes), rate_hz)
    euler, euler_dot, acc_n = np.zeros((len(t), 3)), np.zeros((len(t), 3)), np.zeros((len(t), 3))
    phases = []
    for i, axis in enumerate(axes):
        col, t0 = ("roll", "pitch").index(axis), i * per_axis
        up, back = t0 + hold, t0 + 2 * hold + move  # start times of the two turns
        phases += [(t0, up, f"{axis}_0"), (up + move, back, f"{axis}_90"), (back + move, t0 + per_axis, f"{axis}_0")]
        held = (t >= up + move) & (t < back)
        euler[held, col] = np.pi / 2
        for start, sign in ((up, 1.0), (back, -1.0)):
            inside = (t >= start) & (t < start + move)
            s = t[inside] - start
            euler[inside, col] = np.pi / 4 * (1.0 - sign * np.cos(np.pi * s / move))
            euler_dot[inside, col] = sign * np.pi**2 / (4 * move) * np.sin(np.pi * s / move)
            acc_n[inside] = np.outer(np.sin(2 * np.pi * s / move), rng.normal(0.0, hand_accel, 3))
    desc = (
        f"tilt protocol ({', '.join(axes)}): per axis {hold:g} s at 0°, turn to 90° in {move:g} s, {hold:g} s at 90°, "
        f"back, {hold:g} s at 0°; hand acceleration {hand_accel:g} m/s² RMS amplitude while turning"
    )
    return Motion(t, rate_hz, euler, euler_rates_to_body_rates(euler, euler_dot), acc_n, desc, phases)


def _sensor_signal(rng, truth_s, spec: SensorSpec, rate_hz, bias, bias_rw):
    """truth (sensor frame, SI) + bias + bias random walk + white noise → counts."""
    n = len(truth_s)
    walk = np.cumsum(rng.normal(0.0, bias_rw / np.sqrt(rate_hz), (n, 3)), axis=0)
    noise = rng.normal(0.0, spec.noise_std(rate_hz), (n, 3))
    return spec.to_counts(truth_s + bias + walk + noise)


def simulate_imu(
    motion: Motion,
    board="nucleo-iks02a1",
    seed=0,
    *,
    gyro_bias=None,
    accel_bias=None,
    gyro_bias_rw=1e-4,
    accel_bias_rw=1e-4,
    field_n=MAG_FIELD_LONDON,
    mag_rate_hz=None,
    mag_disturbance=None,
    accel_scale=None,
    gyro_scale=None,
    mag_hard_iron=None,
    mag_soft_iron=None,
) -> Recording:
    """Simulate the board's IMU over ``motion`` and return a recording in counts.

    gyro_bias, accel_bias  constant biases (3,) in the sensor frame, SI; by default drawn
                           from N(0, (typical/2)²) per axis with the datasheet's typical offset;
                           or one per sample (N, 3): a bias path the caller carries from call to
                           call (the virtual board's), with *_bias_rw = 0
    *_bias_rw              bias random-walk densities (rad/s/√s, m/s²/√s); each call starts its walk
                           at 0. The defaults are large for the boards' gyros (the bundled labs 02–04
                           unit's walks at 4.4e-6): kept, since bundled recordings are made with them
    field_n                local magnetic field in NED, µT
    mag_rate_hz            magnetometer output rate; rows without a new sample are left
                           empty (NaN). Defaults to the board's.
    mag_disturbance        extra field (N, 3) in NED, µT, added to field_n sample by sample
                           (see :func:`mag_disturbance`); None adds nothing

    Imperfections a calibration removes (sensor frame; the defaults add nothing and draw no
    random numbers; given values are recorded in ``meta["sim"]``):
    accel_scale, gyro_scale  per-axis scale factors k (3,): x_s = k ⊙ x_true,s + b + …
    mag_hard_iron            hard iron h (3,), µT:  m_s = W m_true,s + h + n
    mag_soft_iron            soft iron W (3, 3)
    """
    b = get_board(board) if isinstance(board, str) else board
    rng = np.random.default_rng(seed)
    rate = float(motion.rate_hz)
    R_bn = np.swapaxes(euler_to_dcm(motion.euler), -1, -2)
    g_n = np.array([0.0, 0.0, G])
    f_b = np.einsum("nij,nj->ni", R_bn, motion.acc_n - g_n)

    def to_sensor(x_b, key):  # x_s = M_bsᵀ x_b, row-wise
        return x_b @ mount_matrix(b.mount[key])

    if gyro_bias is None:
        gyro_bias = rng.normal(0.0, b.gyro.bias_typical / 2, 3)
    if accel_bias is None:
        accel_bias = rng.normal(0.0, b.accel.bias_typical / 2, 3)
    imperfections = {}

    def scaled(x_s, scale, key):  # k ⊙ x_s, only when a scale error is asked for
        if scale is None:
            return x_s
        imperfections[key] = np.asarray(scale, float).tolist()
        return x_s * np.asarray(scale, float)

    gyr = _sensor_signal(
        rng, scaled(to_sensor(motion.omega_b, "gyr"), gyro_scale, "gyro_scale"), b.gyro, rate, gyro_bias, gyro_bias_rw
    )
    acc = _sensor_signal(
        rng, scaled(to_sensor(f_b, "acc"), accel_scale, "accel_scale"), b.accel, rate, accel_bias, accel_bias_rw
    )

    n = len(motion.t)
    data = {"t": motion.t.astype(float), "seq": np.arange(n, dtype=np.int64) % 65536}
    for key, counts in (("a", acc), ("g", gyr)):
        for i, axis in enumerate("xyz"):
            data[key + axis] = counts[:, i]
    sensors = {"acc": b.accel.metadata(), "gyr": b.gyro.metadata()}
    if b.mag is not None:
        m_b = np.einsum("nij,j->ni", R_bn, np.asarray(field_n, dtype=float))
        if mag_disturbance is not None:
            disturbance = np.asarray(mag_disturbance, dtype=float)
            if disturbance.shape != m_b.shape:
                raise ValueError(
                    f"mag_disturbance must be one NED vector per sample, shape {m_b.shape}; got {disturbance.shape}"
                )
            m_b = m_b + np.einsum("nij,nj->ni", R_bn, disturbance)
        m_s = to_sensor(m_b, "mag")
        if mag_soft_iron is not None:
            imperfections["mag_soft_iron"] = np.asarray(mag_soft_iron, float).tolist()
            m_s = m_s @ np.asarray(mag_soft_iron, float).T
        hard = 0.0
        if mag_hard_iron is not None:
            imperfections["mag_hard_iron"] = np.asarray(mag_hard_iron, float).tolist()
            hard = np.asarray(mag_hard_iron, float)
        mag = _sensor_signal(rng, m_s, b.mag, rate, hard, 0.0).astype(float)
        mag_rate = mag_rate_hz or b.mag_rate_hz or rate
        tick = np.floor(motion.t * mag_rate + 1e-9)
        fresh = np.concatenate([[True], np.diff(tick) > 0])
        mag[~fresh] = np.nan
        for i, axis in enumerate("xyz"):
            data["m" + axis] = mag[:, i]
        sensors["mag"] = b.mag.metadata()
    for i, name in enumerate(("true_roll", "true_pitch", "true_yaw")):
        data[name] = motion.euler[:, i]
    meta = {
        "board": b.name,
        "rate_hz": rate,
        "source": "simulated",
        "description": motion.description,
        "seed": seed,
        "units": {"t": "s", "sensors": "counts (see sensors.*.sensitivity)", "true_*": "rad"},
        "sensors": sensors,
        "mount": {k: v for k, v in b.mount.items() if k in sensors},
        "sim": {
            "gyro_bias": np.asarray(gyro_bias, float).tolist(),
            "accel_bias": np.asarray(accel_bias, float).tolist(),
            "field_n": list(map(float, field_n)),
            **imperfections,
        },
    }
    if motion.phases:
        meta["phases"] = [{"label": label, "start": float(t0), "end": float(t1)} for t0, t1, label in motion.phases]
    return Recording(meta, data)


# --- attitude motions (lab 04) --------------------------------------------------------------


def _smooth_step(u):
    """Minimum-jerk step s(u) = 10u³ − 15u⁴ + 6u⁵ on [0, 1] and its derivative ds/du (0 outside)."""
    u = np.clip(u, 0.0, 1.0)
    inside = (u > 0.0) & (u < 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2), np.where(inside, 30.0 * u**2 * (1.0 - u) ** 2, 0.0)


def _window(t, t0, t1, ramp=1.0):
    """Weight 0 → 1 → 0 over [t0, t1] (s) with minimum-jerk ramps of ``ramp`` s, and its time derivative."""
    up, dup = _smooth_step((t - t0) / ramp)
    down, ddown = _smooth_step((t1 - t) / ramp)
    return up * down, (dup * down - up * ddown) / ramp


def euler_moves(t, start, moves):
    """Euler angles built from smooth moves, and their time derivatives (rad, rad/s).

    ``start`` is [roll, pitch, yaw] at t = 0; each move ``(t0, t1, axis, delta)`` turns Euler
    angle ``axis`` (0 roll, 1 pitch, 2 yaw) by ``delta`` rad along a minimum-jerk step between
    t0 and t1 (s). Moves may overlap. Returns (euler, euler_dot), both (N, 3).
    """
    euler = np.tile(np.asarray(start, dtype=float), (len(t), 1))
    euler_dot = np.zeros_like(euler)
    for t0, t1, axis, delta in moves:
        s, ds = _smooth_step((t - t0) / (t1 - t0))
        euler[:, axis] += delta * s
        euler_dot[:, axis] += delta * ds / (t1 - t0)
    return euler, euler_dot


def _motion_from_euler(t, rate_hz, euler, euler_dot, acc_n, description, phases) -> Motion:
    """A Motion whose ω_b comes from the Euler angles and their rates (ZYX kinematics); the stored
    angles are the canonical ZYX angles of the same rotation (pitch within ±90°)."""
    omega_b = euler_rates_to_body_rates(euler, euler_dot)
    canonical = dcm_to_euler(euler_to_dcm(euler))
    return Motion(t, rate_hz, canonical, omega_b, acc_n, description, phases)


def _still_windows(duration, busy):
    """The complement of the busy windows [(t0, t1), …] in [0, duration], labelled 'stationary'."""
    windows, t = [], 0.0
    for t0, t1 in sorted(busy):
        if t0 > t:
            windows.append((t, t0, "stationary"))
        t = max(t, t1)
    if t < duration:
        windows.append((t, duration, "stationary"))
    return windows


def attitude_tour(
    rate_hz=104.0, yaw0=np.radians(30.0), swing=np.radians(40.0), translate_accel=2.0, vibration_rms=0.0, seed=0
) -> Motion:
    """Lab 04: a board turned by hand about all its axes, with rests in between (60 s).

    0–5 s at rest; roll swings ±``swing`` (5–15 s); pitch swings ±0.9·``swing`` (17–27 s); a yaw
    turn of +170° and back (29–39 s, through ±180° from ``yaw0``); the board slid back and forth
    on the table at constant attitude for 6 s (41–47 s), a_N = A (cos ωτ − cos 2ωτ),
    a_E = ½A (cos 2ωτ − cos 4ωτ) with ω = π rad/s and A = ``translate_accel`` (m/s²; peaks at 2A):
    three whole 2 s cycles that start and end at rest where they began (±A/π² m); a tumble about
    all three axes at once (49–57 s); at rest to 60 s. Every move is a minimum-jerk step, so
    rates are smooth; ω_b comes from the Euler rates.
    ``vibration_rms``: white hand vibration (m/s² RMS, seeded) while the board is moving.
    Phases: 'stationary', 'roll', 'pitch', 'yaw', 'linear_acceleration', 'tumble'.
    """
    duration = 60.0
    t = sample_times(duration, rate_hz)
    a, p = swing, 0.9 * swing
    moves = [
        (5.0, 7.5, 0, a),
        (7.5, 12.5, 0, -2 * a),
        (12.5, 15.0, 0, a),
        (17.0, 19.5, 1, p),
        (19.5, 24.5, 1, -2 * p),
        (24.5, 27.0, 1, p),
        (29.0, 34.0, 2, np.radians(170.0)),
        (34.0, 39.0, 2, -np.radians(170.0)),
        (49.0, 52.0, 0, np.radians(30.0)),
        (52.0, 55.0, 0, -np.radians(50.0)),
        (55.0, 57.0, 0, np.radians(20.0)),
        (49.0, 52.5, 1, -np.radians(25.0)),
        (52.5, 55.5, 1, np.radians(40.0)),
        (55.5, 57.0, 1, -np.radians(15.0)),
        (49.0, 53.0, 2, -np.radians(90.0)),
        (53.0, 57.0, 2, np.radians(90.0)),
    ]
    busy = {
        "roll": (5.0, 15.0),
        "pitch": (17.0, 27.0),
        "yaw": (29.0, 39.0),
        "linear_acceleration": (41.0, 47.0),
        "tumble": (49.0, 57.0),
    }
    acc_n = np.zeros((len(t), 3))
    t0, t1 = busy["linear_acceleration"]
    inside = (t >= t0) & (t < t1)
    tau = t[inside] - t0
    acc_n[inside, 0] = translate_accel * (np.cos(np.pi * tau) - np.cos(2 * np.pi * tau))
    acc_n[inside, 1] = 0.5 * translate_accel * (np.cos(2 * np.pi * tau) - np.cos(4 * np.pi * tau))
    if vibration_rms > 0:
        moving = np.any([(t >= b0) & (t < b1) for b0, b1 in busy.values()], axis=0)
        acc_n[moving] += np.random.default_rng(seed).normal(0.0, vibration_rms, (int(moving.sum()), 3))
    phases = sorted(_still_windows(duration, busy.values()) + [(b0, b1, k) for k, (b0, b1) in busy.items()])
    desc = (
        f"attitude tour: rest, roll ±{np.degrees(a):.0f}°, pitch ±{np.degrees(p):.0f}°, yaw +170° and back "
        f"from {np.degrees(yaw0):.0f}°, sliding on the table (up to {2 * translate_accel:g} m/s²), a tumble about all "
        f"axes, rests in between; hand vibration {vibration_rms:g} m/s² RMS while moving"
    )
    return _motion_from_euler(t, rate_hz, *euler_moves(t, [0.0, 0.0, yaw0], moves), acc_n, desc, phases)


def pitch_over(rate_hz=104.0, peak=np.radians(110.0), wobble=np.radians(5.0), yaw0=np.radians(30.0)) -> Motion:
    """Lab 04's gimbal lock: the nose pitched up through vertical and back, then down through it (36 s).

    The board turns about its y axis by ``peak`` (> 90°: past vertical, onto its back) in 6 s,
    holds 2 s, returns in 6 s (3–17 s), rests, then does the same nose down (19–33 s); roll and
    yaw wobble by ±``wobble`` at 0.2 and 0.15 Hz while the board is moving. The stored truth is the canonical ZYX
    triple: past vertical the pitch turns back below 90° while roll and yaw jump by 180°.
    Phases: 'stationary', 'nose_up', 'nose_down', and 'near_vertical' where the nose is within 10°
    of straight up or down.
    """
    duration = 36.0
    t = sample_times(duration, rate_hz)
    moves = [(3.0, 9.0, 1, peak), (11.0, 17.0, 1, -peak), (19.0, 25.0, 1, -peak), (27.0, 33.0, 1, peak)]
    euler, euler_dot = euler_moves(t, [0.0, 0.0, yaw0], moves)
    busy = {"nose_up": (3.0, 17.0), "nose_down": (19.0, 33.0)}
    for t0, t1 in busy.values():  # wobble e(t)·w·sin(2πf(t − t0)) while the board is held up
        e, de = _window(t, t0, t1)
        for axis, f in ((0, 0.2), (2, 0.15)):
            arg = 2 * np.pi * f * (t - t0)
            euler[:, axis] += e * wobble * np.sin(arg)
            euler_dot[:, axis] += wobble * (de * np.sin(arg) + e * 2 * np.pi * f * np.cos(arg))
    # nose (body x) within 10° of vertical ⇔ |R_nb[2, 0]| = |sin θ| > cos 10°
    near = np.abs(np.sin(euler[:, 1])) > np.cos(np.radians(10.0))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(int), [0]])))
    ends = np.append(t, duration)  # a window ends at the first sample after it
    vertical = [(float(t[i]), float(ends[j]), "near_vertical") for i, j in zip(edges[::2], edges[1::2])]
    phases = sorted(_still_windows(duration, busy.values()) + [(b0, b1, k) for k, (b0, b1) in busy.items()] + vertical)
    desc = (
        f"pitch over: nose up through vertical to {np.degrees(peak):.0f}° and back, then nose down the same; "
        f"roll and yaw wobble ±{np.degrees(wobble):.0f}°"
    )
    return _motion_from_euler(t, rate_hz, euler, euler_dot, np.zeros((len(t), 3)), desc, phases)


def yaw_sweeps(
    rate_hz=104.0,
    duration=30.0,
    amplitude=np.radians(60.0),
    period=10.0,
    still=3.0,
    disturbance=(12.0, 20.0),
    yaw0=np.radians(30.0),
) -> Motion:
    """Lab 04's magnetic disturbance: slow heading sweeps ±``amplitude`` with ``period`` (s) after
    ``still`` s at rest, roll and pitch wobbling ±10°. The window ``disturbance`` (s) is labelled
    'mag_disturbance' for :func:`mag_disturbance`, which makes the field that goes with it.
    Phases: 'stationary', 'sweeps', 'mag_disturbance'.
    """
    t = sample_times(duration, rate_hz)
    half = period / 2
    n_half = int((duration - still) // half)
    moves = [
        (still + k * half, still + (k + 1) * half, 2, amplitude * (1 if k == 0 else 2) * (-1) ** k)
        for k in range(n_half)
    ]
    euler, euler_dot = euler_moves(t, [0.0, 0.0, yaw0], moves)
    s, ds = _smooth_step(t - still)  # wobble fades in over one second
    for axis, f in ((0, 0.23), (1, 0.17)):
        w = np.radians(10.0) * np.sin(2 * np.pi * f * (t - still))
        euler[:, axis] += s * w
        euler_dot[:, axis] += ds * w + s * np.radians(10.0) * 2 * np.pi * f * np.cos(2 * np.pi * f * (t - still))
    phases = [(0.0, still, "stationary"), (still, duration, "sweeps"), (*map(float, disturbance), "mag_disturbance")]
    desc = (
        f"heading sweeps ±{np.degrees(amplitude):.0f}° every {period:g} s with roll/pitch wobble ±10°; "
        f"magnetic disturbance window {disturbance[0]:g}–{disturbance[1]:g} s"
    )
    return _motion_from_euler(t, rate_hz, euler, euler_dot, np.zeros((len(t), 3)), desc, phases)


def mag_disturbance(motion: Motion, field=(-10.0, 8.0, 10.0), label="mag_disturbance") -> np.ndarray:
    """Extra magnetic field (N, 3) in NED, µT, for ``simulate_imu(…, mag_disturbance=…)``.

    Zero outside the motion's windows labelled ``label``; inside, ``field`` (µT, NED: a steel desk
    or a laptop near the board) faded in and out with a one-second minimum-jerk ramp at each end.
    """
    windows = [(t0, t1) for t0, t1, name in motion.phases if name == label]
    if not windows:
        raise ValueError(f"motion has no phase {label!r}; phases: {sorted({p[2] for p in motion.phases})}")
    weight = np.max([_window(motion.t, t0, t1)[0] for t0, t1 in windows], axis=0)
    return weight[:, None] * np.asarray(field, dtype=float)


# --- calibration motions (labs 02 and 03) -----------------------------------------------------


def _pose_sequence(rate_hz, poses, hold, move, description) -> Motion:
    """Rest at each pose ``(roll, pitch, yaw, label)`` (rad) for ``hold`` s, turning between poses in
    ``move`` s along minimum-jerk steps of the Euler angles; each rest is a phase (label None: none)."""
    duration = len(poses) * hold + (len(poses) - 1) * move
    t = sample_times(duration, rate_hz)
    moves, phases = [], []
    for i, pose in enumerate(poses):
        start = i * (hold + move)
        if pose[3] is not None:
            phases.append((start, start + hold, pose[3]))
        if i:
            moves += [(start - move, start, axis, pose[axis] - poses[i - 1][axis]) for axis in range(3)]
    euler, euler_dot = euler_moves(t, poses[0][:3], moves)
    return _motion_from_euler(t, rate_hz, euler, euler_dot, np.zeros((len(t), 3)), description, phases)


def six_faces(hold=5.0, move=3.0, rate_hz=104.0, seed=0) -> Motion:
    """Lab 02's six-face calibration: the board rests on each face in turn.

    Phases ``"x_up"``, ``"x_down"``, ``"y_up"``, ``"y_down"``, ``"z_up"``, ``"z_down"`` name the
    body axis pointing up (it reads +g of specific force: f_b = R_bn·[0, 0, −g]); each window
    covers only the ``hold`` seconds at rest, the ``move``-second turns between faces are
    unlabelled. Like a board on an imperfect table, each face is off by a random tilt of
    N(0, (0.5°)²) about roll and pitch and at a random heading (seeded).
    Order: z_down (flat), y_down (roll 90°), z_up (roll 180°), y_up (roll 270°),
    x_up (pitch 90°), x_down (pitch −90°).
    """
    rng = np.random.default_rng(seed)
    nominal = [
        (0, 0, "z_down"),
        (90, 0, "y_down"),
        (180, 0, "z_up"),
        (270, 0, "y_up"),
        (360, 90, "x_up"),
        (360, -90, "x_down"),
    ]
    poses = [
        (
            np.radians(r) + rng.normal(0.0, np.radians(0.5)),
            np.radians(p) + rng.normal(0.0, np.radians(0.5)),
            rng.uniform(-np.pi, np.pi),
            label,
        )
        for r, p, label in nominal
    ]
    return _pose_sequence(
        rate_hz,
        poses,
        hold,
        move,
        f"six faces: {hold:g} s at rest on each face (z down, y down, z up, y up, x up, x down), "
        f"{move:g} s turns between them; faces tilted by about 0.5° at random headings",
    )


def mag_rotations(duration=60.0, rate_hz=104.0, seed=0) -> Motion:
    """Lab 03's magnetometer calibration motion: slow tumbling that covers the sphere.

    Figure-eight style: roll φ = 170°·sin(2π τ/20 s + a), pitch θ = 75°·sin(2π τ/13 s),
    yaw ψ = ψ₀ + 360°·τ/25 s, where τ(t) = ∫e dt runs on a clock e(t) that ramps from 0 to 1 in the first
    two seconds and back to 0 in the last two (the board starts and ends at rest). a and ψ₀ are
    drawn from ``seed``. One phase ``"mag_rotations"`` covers the whole recording.
    """
    rng = np.random.default_rng(seed)
    a, yaw0 = rng.uniform(-0.3, 0.3), rng.uniform(-np.pi, np.pi)
    t = sample_times(duration, rate_hz)
    up, dup = _smooth_step(t / 2.0)
    down, ddown = _smooth_step((duration - t) / 2.0)
    e = up * down  # clock rate, 0 → 1 → 0
    tau = np.concatenate([[0.0], np.cumsum((e[1:] + e[:-1]) / 2) / rate_hz])
    w_r, w_p, w_y = 2 * np.pi / 20.0, 2 * np.pi / 13.0, 2 * np.pi / 25.0
    A_r, A_p = np.radians(170.0), np.radians(75.0)
    euler = np.column_stack([A_r * (np.sin(w_r * tau + a) - np.sin(a)), A_p * np.sin(w_p * tau), yaw0 + w_y * tau])
    rates = np.column_stack([A_r * w_r * np.cos(w_r * tau + a), A_p * w_p * np.cos(w_p * tau), np.full_like(tau, w_y)])
    euler_dot = rates * e[:, None]
    return _motion_from_euler(
        t,
        rate_hz,
        euler,
        euler_dot,
        np.zeros((len(t), 3)),
        f"slow tumbling over {duration:g} s covering the sphere (roll ±170°, pitch ±75°, yaw turning at 14.4°/s)",
        [(0.0, float(duration), "mag_rotations")],
    )


def axis_turns(angle=np.radians(90.0), hold=2.0, move=3.0, rate_hz=104.0, yaw=0.0) -> Motion:
    """Lab 03's alignment check: from flat, turn by ``angle`` about body x, back; about y, back; about z, back.

    Each turn is a minimum-jerk move of ``move`` s with ``hold`` s rests around it; the phases
    ``"turn_x"``, ``"turn_y"``, ``"turn_z"`` each cover a rest, the turn out, a rest, the turn back and
    a rest, so integrating the gyro over one phase starts and ends at rest.
    """
    poses = []
    for axis in range(3):
        out = [0.0, 0.0, yaw]
        out[axis] += angle
        poses += [(0.0, 0.0, yaw, None), (*out, None), (0.0, 0.0, yaw, None)]
    m = _pose_sequence(
        rate_hz,
        poses,
        hold,
        move,
        f"turns of {np.degrees(angle):.0f}° about body x, y and z and back, {hold:g} s rests",
    )
    step = hold + move  # pose i starts resting at i·step
    m.phases = [(3 * i * step, (3 * i + 2) * step + hold, f"turn_{axis}") for i, axis in enumerate("xyz")]
    return m


def heading_steps(
    headings=np.radians([0.0, 60.0, 120.0, 180.0, 240.0, 300.0]),
    tilt=(np.radians(20.0), np.radians(-15.0)),
    hold=4.0,
    move=2.0,
    rate_hz=104.0,
) -> Motion:
    """Lab 03's heading test: the board turned through known ``headings`` (rad) flat, then again tilted
    by ``tilt`` = (roll, pitch) (rad), resting ``hold`` s at each. Phases ``"heading_flat"`` and
    ``"heading_tilted"`` label the rests; the tilted pass visits the headings in reverse order."""
    flat = [(0.0, 0.0, float(h), "heading_flat") for h in headings]
    tilted = [(tilt[0], tilt[1], float(h), "heading_tilted") for h in headings[::-1]]  # turn back, not round
    return _pose_sequence(
        rate_hz,
        flat + tilted,
        hold,
        move,
        f"turned flat through headings {', '.join(f'{np.degrees(h):.0f}°' for h in headings)}, "
        f"then again tilted (roll {np.degrees(tilt[0]):.0f}°, pitch {np.degrees(tilt[1]):.0f}°), "
        f"{hold:g} s at each",
    )
