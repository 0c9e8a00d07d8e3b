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

from .frames import G, MAG_FIELD_LONDON, euler_rates_to_body_rates, euler_to_dcm, mount_matrix
from .io import Recording
from .sensors import SensorSpec, board as get_board


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
    return Motion(t, rate_hz, euler, zeros, zeros.copy(), f"stationary at roll {np.degrees(roll):.0f}°, pitch {np.degrees(pitch):.0f}°")


def sine_roll(duration=60.0, rate_hz=104.0, amplitude=np.radians(30.0), freq_hz=0.1, still=5.0,
              shakes=(25.0, 45.0), shake_duration=3.0, shake_accel=3.0, shake_freq_hz=2.0,
              vibration_rms=0.0, seed=0) -> Motion:
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
    desc = (f"roll sine {np.degrees(amplitude):.0f}° at {freq_hz:g} Hz after {still:g} s at rest; "
            f"sideways shakes of {shake_accel:g} m/s² at t = {', '.join(f'{s:g}' for s in shakes)} s; "
            f"hand vibration {vibration_rms:g} m/s² RMS")
    return Motion(t, rate_hz, euler, euler_rates_to_body_rates(euler, euler_dot), acc_n, desc)


def _sensor_signal(rng, truth_s, spec: SensorSpec, rate_hz, bias, bias_rw):
    """truth (sensor frame, SI) + bias + bias random walk + white noise → counts."""
    n = len(truth_s)
    walk = np.cumsum(rng.normal(0.0, bias_rw / np.sqrt(rate_hz), (n, 3)), axis=0)
    noise = rng.normal(0.0, spec.noise_std(rate_hz), (n, 3))
    return spec.to_counts(truth_s + bias + walk + noise)


def simulate_imu(motion: Motion, board="nucleo-iks02a1", seed=0, *, gyro_bias=None, accel_bias=None,
                 gyro_bias_rw=1e-4, accel_bias_rw=1e-4, field_n=MAG_FIELD_LONDON,
                 mag_rate_hz=None) -> Recording:
    """Simulate the board's IMU over ``motion`` and return a recording in counts.

    gyro_bias, accel_bias  constant biases (3,) in the sensor frame, SI; by default drawn
                           from N(0, (typical/2)²) per axis with the datasheet's typical offset
    *_bias_rw              bias random-walk densities (rad/s/√s, m/s²/√s)
    field_n                local magnetic field in NED, µT
    mag_rate_hz            magnetometer output rate; rows without a new sample are left
                           empty (NaN). Defaults to the board's.
    """
    b = get_board(board) if isinstance(board, str) else board
    rng = np.random.default_rng(seed)
    rate = float(motion.rate_hz)
    R_bn = np.swapaxes(euler_to_dcm(*motion.euler.T), -1, -2)
    g_n = np.array([0.0, 0.0, G])
    f_b = np.einsum("nij,nj->ni", R_bn, motion.acc_n - g_n)

    def to_sensor(x_b, key):  # x_s = M_bsᵀ x_b, row-wise
        return x_b @ mount_matrix(b.mount[key])

    if gyro_bias is None:
        gyro_bias = rng.normal(0.0, b.gyro.bias_typical / 2, 3)
    if accel_bias is None:
        accel_bias = rng.normal(0.0, b.accel.bias_typical / 2, 3)
    gyr = _sensor_signal(rng, to_sensor(motion.omega_b, "gyr"), b.gyro, rate, gyro_bias, gyro_bias_rw)
    acc = _sensor_signal(rng, to_sensor(f_b, "acc"), b.accel, rate, accel_bias, accel_bias_rw)

    n = len(motion.t)
    data = {"t": motion.t.astype(float), "seq": np.arange(n, dtype=np.int64) % 65536}
    for key, counts in (("a", acc), ("g", gyr)):
        for i, axis in enumerate("xyz"):
            data[key + axis] = counts[:, i]
    sensors = {"acc": b.accel.metadata(), "gyr": b.gyro.metadata()}
    if b.mag is not None:
        m_b = np.einsum("nij,j->ni", R_bn, np.asarray(field_n, dtype=float))
        mag = _sensor_signal(rng, to_sensor(m_b, "mag"), b.mag, rate, 0.0, 0.0).astype(float)
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
        "sim": {"gyro_bias": np.asarray(gyro_bias, float).tolist(), "accel_bias": np.asarray(accel_bias, float).tolist(),
                "field_n": list(map(float, field_n))},
    }
    if motion.phases:
        meta["phases"] = [{"label": label, "start": float(t0), "end": float(t1)} for t0, t1, label in motion.phases]
    return Recording(meta, data)
