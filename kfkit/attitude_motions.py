"""Lab 04's attitude motions: the board turned by hand about all its axes, pitched through vertical, swept in
heading beside a magnetic disturbance.

Each is a :class:`kfkit.motions.Motion` built from minimum-jerk moves of the Euler angles (rad; ω_b from their
rates), with rests labelled 'stationary'; :func:`mag_disturbance` is the extra field (NED, µT) that goes with
:func:`yaw_sweeps`'s 'mag_disturbance' window.
"""

from __future__ import annotations

import numpy as np

from .motions import Motion, _motion_from_euler, _smooth_step, euler_moves, sample_times


def _window(t, t0, t1, ramp=1.0):
    """Weight 0 → 1 → 0 over [t0, t1] (s) with minimum-jerk ramps of ``ramp`` s, and its time derivative."""
    up, dup = _smooth_step((t - t0) / ramp)
    down, ddown = _smooth_step((t1 - t) / ramp)
    return up * down, (dup * down - up * ddown) / ramp


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
