"""Labs 02 and 03's calibration motions: rests on the six faces, a slow tumble covering the sphere for the
magnetometer, turns about each body axis, known headings flat and tilted.

Each is a :class:`kfkit.motions.Motion` of rests at poses (rad) joined by minimum-jerk turns of the Euler angles,
its phases naming the rests the labs read (``"x_up"``, …, ``"mag_rotations"``, ``"turn_x"``, …,
``"heading_flat"``).
"""

from __future__ import annotations

import numpy as np

from .motions import Motion, _motion_from_euler, _smooth_step, euler_moves, sample_times


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
