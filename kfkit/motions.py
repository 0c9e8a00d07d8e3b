"""Truth motions: what a board does, sampled at the IMU rate, for :func:`kfkit.sim.simulate_imu` to sense.

A :class:`Motion` is the truth: Euler angles [roll, pitch, yaw] (rad, ZYX), body angular rate (rad/s) and the
linear acceleration of the board in NED (m/s², gravity excluded), with labelled time windows (phases). Here: the
simple motions (at rest, lab 01's sine roll, lab 05's tilt protocol) and the smooth moves the other motions are
built from: a minimum-jerk step s(u) = 10u³ − 15u⁴ + 6u⁵ per Euler angle (:func:`euler_moves`), ω_b from the
Euler rates. Lab 04's motions are in :mod:`kfkit.attitude_motions`, labs 02 and 03's in
:mod:`kfkit.calibration_motions`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frames import dcm_to_euler, euler_rates_to_body_rates, euler_to_dcm


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


# --- smooth moves (the motions of labs 02–04) ---------------------------------------------------


def _smooth_step(u):
    """Minimum-jerk step s(u) = 10u³ − 15u⁴ + 6u⁵ on [0, 1] and its derivative ds/du (0 outside)."""
    u = np.clip(u, 0.0, 1.0)
    inside = (u > 0.0) & (u < 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2), np.where(inside, 30.0 * u**2 * (1.0 - u) ** 2, 0.0)


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
