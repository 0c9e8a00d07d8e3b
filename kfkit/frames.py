"""Frames, rotations and angles in the kit's conventions.

Navigation frame NED (x north, y east, z down); body frame FRD (x forward, y right,
z down). Euler angles are ZYX ("3-2-1": yaw ψ, then pitch θ, then roll φ) and

    R_nb = Rz(ψ) · Ry(θ) · Rx(φ)        maps body → NED,   R_bn = R_nbᵀ,

which equals ``scipy.spatial.transform.Rotation.from_euler('ZYX', [ψ, θ, φ]).as_matrix()``.
All angles are radians. Functions take arrays with the components on the last axis — Euler angles
[roll, pitch, yaw] (…, 3), quaternions (…, 4), matrices (…, 3, 3), vectors (…, 3) — and broadcast like NumPy.
This module is the kit's only home of rotations: nothing else in ``kfkit`` multiplies quaternions or uses
scipy's ``Rotation`` (``tests/test_architecture.py``); scipy's ``Rotation`` is also the oracle it is tested against.

Quaternions are w-x-y-z (scalar first; scipy's ``as_quat()`` is x-y-z-w), Hamilton product, and
q maps body → navigation frame like R_nb. The names carry the convention and come in pairs:
:func:`euler_to_dcm`/:func:`dcm_to_euler`, :func:`euler_to_quat`/:func:`quat_to_euler`,
:func:`quat_to_dcm`/:func:`dcm_to_quat`, :func:`rotvec_to_quat`/:func:`quat_to_rotvec`,
:func:`euler_rates_to_body_rates`/:func:`body_rates_to_euler_rates`, :func:`quat_multiply`, :func:`quat_conjugate`,
:func:`quat_rotate`, :func:`quat_slerp`, :func:`dcm_slerp`, :func:`random_dcm`, :func:`enu_to_ned` (vectors) and
:func:`enu_to_ned_quat`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

#: Standard gravity, m/s².
G = 9.80665

#: Reference geomagnetic field in London, NED, µT (WMM, 2025: north 19.5, east 0.3,
#: down 45.0). Magnetic declination there is atan2(0.3, 19.5) ≈ +0.9° (east of true north).
MAG_FIELD_LONDON = (19.5, 0.3, 45.0)

#: Mounting matrix M_bs (body ← sensor) for a sensor whose z axis points up when the
#: board lies flat (it reads +1 g on z): y and z are flipped, x stays forward.
MOUNT_Z_UP = np.diag([1.0, -1.0, -1.0])

#: Mounting matrix for a sensor already aligned with the body frame (FRD).
MOUNT_IDENTITY = np.eye(3)


def _require_last_axis(a, n, owner, what):
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{owner} expects {what} on the last axis ({n} values), got shape {a.shape}")


def wrap_angle(a):
    """Wrap angles to (−π, π] (rad)."""
    a = np.asarray(a, dtype=float)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return w if w.ndim else float(w)


def euler_to_dcm(euler):
    """R_nb = Rz(ψ) Ry(θ) Rx(φ), body → NED, from [roll φ, pitch θ, yaw ψ] (…, 3), rad → (…, 3, 3)."""
    e = np.asarray(euler, dtype=float)
    _require_last_axis(e, 3, "euler_to_dcm", "[roll, pitch, yaw]")
    roll, pitch, yaw = e[..., 0], e[..., 1], e[..., 2]
    cf, sf = np.cos(roll), np.sin(roll)
    ct, st = np.cos(pitch), np.sin(pitch)
    cp, sp = np.cos(yaw), np.sin(yaw)
    R = np.empty(roll.shape + (3, 3))
    R[..., 0, 0] = ct * cp
    R[..., 0, 1] = sf * st * cp - cf * sp
    R[..., 0, 2] = cf * st * cp + sf * sp
    R[..., 1, 0] = ct * sp
    R[..., 1, 1] = sf * st * sp + cf * cp
    R[..., 1, 2] = cf * st * sp - sf * cp
    R[..., 2, 0] = -st
    R[..., 2, 1] = sf * ct
    R[..., 2, 2] = cf * ct
    return R


def dcm_to_euler(R):
    """[roll, pitch, yaw] (…, 3), rad, from R_nb (…, 3, 3): the inverse of :func:`euler_to_dcm`.

    φ = atan2(R₃₂, R₃₃), θ = −asin(R₃₁), ψ = atan2(R₂₁, R₁₁). At θ = ±90° (gimbal lock)
    only φ ∓ ψ is defined; the split returned there is arbitrary but R is reproduced.
    """
    R = np.asarray(R, dtype=float)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    # Gimbal lock (cos θ ≈ 0): the entries above are rounding noise, so take ψ = 0 and
    # φ from R₁₂ = sinθ·sinφ, R₂₂ = cosφ, which hold there when ψ = 0.
    lock = np.hypot(R[..., 0, 0], R[..., 1, 0]) < 1e-8
    if np.any(lock):
        roll = np.where(lock, np.arctan2(-np.sign(R[..., 2, 0]) * R[..., 0, 1], R[..., 1, 1]), roll)
        yaw = np.where(lock, 0.0, yaw)
    return np.stack([roll, pitch, yaw], axis=-1)


def euler_to_quat(euler):
    """Quaternion(s) w-x-y-z of R_nb = Rz(ψ) Ry(θ) Rx(φ) from [roll, pitch, yaw] (…, 3), rad.

    q = q_z(ψ) ⊗ q_y(θ) ⊗ q_x(φ), sign chosen with w ≥ 0.
    """
    e = np.asarray(euler, dtype=float)
    cr, sr = np.cos(e[..., 0] / 2), np.sin(e[..., 0] / 2)
    cp, sp = np.cos(e[..., 1] / 2), np.sin(e[..., 1] / 2)
    cy, sy = np.cos(e[..., 2] / 2), np.sin(e[..., 2] / 2)
    q = np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def quat_to_euler(q):
    """[roll, pitch, yaw] (…, 3), rad, of quaternion(s) w-x-y-z (…, 4) body → NED."""
    return dcm_to_euler(quat_to_dcm(q))


def quat_to_dcm(q):
    """R_nb (…, 3, 3) from unit quaternion(s) w-x-y-z (…, 4)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def dcm_to_quat(R):
    """Unit quaternion(s) w-x-y-z (…, 4), w ≥ 0, of rotation matrices R (…, 3, 3), the inverse of
    :func:`quat_to_dcm`.

    Shepperd's method: of 4w² = 1 + tr R, 4x² = 1 + 2R₁₁ − tr R, 4y² = 1 + 2R₂₂ − tr R,
    4z² = 1 + 2R₃₃ − tr R take the largest (never small: their sum is 4), and the other three
    components from the off-diagonal sums and differences, e.g. 4wx = R₃₂ − R₂₃, 4xy = R₁₂ + R₂₁.
    """
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"dcm_to_quat expects rotation matrices of shape (…, 3, 3), got {R.shape}")
    tr = np.trace(R, axis1=-2, axis2=-1)
    diag = np.diagonal(R, axis1=-2, axis2=-1)
    sq = np.concatenate([(1 + tr)[..., None], 1 + 2 * diag - tr[..., None]], axis=-1)  # 4w², 4x², 4y², 4z²
    big = np.argmax(sq, axis=-1)[..., None]
    d = np.stack(
        [
            R[..., 2, 1] - R[..., 1, 2],
            R[..., 0, 2] - R[..., 2, 0],
            R[..., 1, 0] - R[..., 0, 1],  # 4wx, 4wy, 4wz
            R[..., 0, 1] + R[..., 1, 0],
            R[..., 0, 2] + R[..., 2, 0],
            R[..., 1, 2] + R[..., 2, 1],
        ],
        axis=-1,
    )  # 4xy, 4xz, 4yz
    # products 4·q_i·q_j laid out as rows i, columns j (w, x, y, z), diagonal 4q_i²
    P = np.stack(
        [
            np.stack([sq[..., 0], d[..., 0], d[..., 1], d[..., 2]], -1),
            np.stack([d[..., 0], sq[..., 1], d[..., 3], d[..., 4]], -1),
            np.stack([d[..., 1], d[..., 3], sq[..., 2], d[..., 5]], -1),
            np.stack([d[..., 2], d[..., 4], d[..., 5], sq[..., 3]], -1),
        ],
        axis=-2,
    )
    row = np.take_along_axis(P, big[..., None], axis=-2)[..., 0, :]  # 4·q_big·q
    q = row / np.linalg.norm(row, axis=-1, keepdims=True)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def quat_multiply(p, q):
    """Hamilton product p ⊗ q of quaternions w-x-y-z (…, 4), broadcast like NumPy:
    R(p ⊗ q) = R(p)·R(q), so q_nb = q_na ⊗ q_ab chains rotations."""
    p, q = np.broadcast_arrays(np.asarray(p, dtype=float), np.asarray(q, dtype=float))
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_conjugate(q):
    """q* = [w, −x, −y, −z] (…, 4): the inverse rotation of a unit quaternion."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q, v):
    """R(q)·v: vectors v (…, 3) rotated by unit quaternions q (…, 4) w-x-y-z, e.g. body → NED for q_nb.

    v' = v + 2w (u × v) + 2 u × (u × v) with u = [x, y, z] (the vector part), which is R(q)·v without the matrix.
    """
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotvec_to_quat(rotvec):
    """The exponential map: unit quaternion(s) w-x-y-z (…, 4) of rotation vectors θ·n (…, 3), rad —
    a turn by ‖θn‖ about n: q = [cos(θ/2), sin(θ/2)·n]; for small θ, [1, θn/2] to first order."""
    v = np.asarray(rotvec, dtype=float)
    _require_last_axis(v, 3, "rotvec_to_quat", "a rotation vector")
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    # sin(θ/2)/θ, with its series 1/2 − θ²/48 near 0 (no 0/0)
    half_sinc = np.where(angle < 1e-6, 0.5 - angle**2 / 48.0, np.sin(angle / 2) / np.where(angle < 1e-6, 1.0, angle))
    return np.concatenate([np.cos(angle / 2), half_sinc * v], axis=-1)


def quat_to_rotvec(q):
    """The logarithm map: rotation vector(s) θ·n (…, 3), rad, |θ| ≤ π, of unit quaternions w-x-y-z (…, 4);
    the inverse of :func:`rotvec_to_quat` (q and −q give the same rotation vector)."""
    q = np.asarray(q, dtype=float)
    _require_last_axis(q, 4, "quat_to_rotvec", "a quaternion w-x-y-z")
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)  # sin(θ/2)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s < 1e-12, 2.0 / np.where(q[..., :1] == 0, 1.0, q[..., :1]), angle / np.where(s < 1e-12, 1.0, s))
    return scale * q[..., 1:]


def cross_matrix(v):
    """[v×] (…, 3, 3): the matrix with [v×]·u = v × u, of vectors v (…, 3). R(I + [δθ×]) is R turned by the small
    rotation δθ in its own (body) frame, (I + [δθ×])R the same turn in the outer (navigation) frame."""
    v = np.asarray(v, dtype=float)
    _require_last_axis(v, 3, "cross_matrix", "a vector")
    M = np.zeros(v.shape + (3,))
    M[..., 0, 1], M[..., 0, 2], M[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    M[..., 1, 0], M[..., 2, 0], M[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return M


def quat_slerp(q0, q1, fraction):
    """Spherical linear interpolation q0 ⊗ exp(fraction · log(q0* ⊗ q1)) between unit quaternions (…, 4)
    w-x-y-z, ``fraction`` (…) in [0, 1]: the shortest turn from q0 (0) to q1 (1) at constant rate. Computed with
    scipy's Rotation (the kit's rotation oracle), so conversions made with it before are reproduced exactly."""
    q0, q1 = np.broadcast_arrays(np.asarray(q0, dtype=float), np.asarray(q1, dtype=float))
    shape = q0.shape
    r0 = Rotation.from_quat(q0.reshape(-1, 4)[:, [1, 2, 3, 0]])  # scipy is scalar-last
    r1 = Rotation.from_quat(q1.reshape(-1, 4)[:, [1, 2, 3, 0]])
    step = (r0.inv() * r1).as_rotvec() * np.broadcast_to(np.asarray(fraction, dtype=float), shape[:-1]).reshape(-1, 1)
    return (r0 * Rotation.from_rotvec(step)).as_quat()[:, [3, 0, 1, 2]].reshape(shape)


def dcm_slerp(t_known, R_nb, t):
    """Attitudes R_nb (N, 3, 3) known at increasing times ``t_known`` (N,), s, interpolated at times ``t`` (inside
    their span) by slerp between the two neighbouring samples → (len(t), 3, 3)."""
    return Slerp(np.asarray(t_known, dtype=float), Rotation.from_matrix(R_nb))(np.asarray(t, dtype=float)).as_matrix()


def random_dcm(n=None, rng=None):
    """Rotation matrices drawn uniformly over all attitudes (Haar measure): (3, 3) for ``n`` None, else (n, 3, 3);
    ``rng`` a seed or a numpy Generator."""
    return Rotation.random(n, random_state=rng).as_matrix()


#: ENU → NED as a matrix: swap x and y, negate z (a 180° turn about (1, 1, 0)/√2), v_NED = R v_ENU.
R_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: The same rotation as a quaternion w-x-y-z: q_NED = Q_NED_ENU ⊗ q_ENU.
Q_NED_ENU = (0.0, float(np.sqrt(0.5)), float(np.sqrt(0.5)), 0.0)


def enu_to_ned(v_enu):
    """Vectors (…, 3) in ENU (east, north, up) to NED: [n, e, d] = [v_N, v_E, −v_U]. Its own inverse."""
    v = np.asarray(v_enu, dtype=float)
    if v.ndim == 0 or v.shape[-1] != 3:
        raise ValueError(f"enu_to_ned expects vectors with 3 components on the last axis, got shape {v.shape}")
    return v @ R_NED_ENU.T


def enu_to_ned_quat(q_enu):
    """Quaternions (…, 4) w-x-y-z body → ENU to body → NED: q_NED = Q_NED_ENU ⊗ q_ENU."""
    return quat_multiply(Q_NED_ENU, q_enu)


def accel_tilt(f_b):
    """Roll and pitch (rad) from a specific-force vector f_b (m/s², body FRD).

    At rest f_b = R_bn·[0, 0, −g], so  φ = atan2(−f_y, −f_z),  θ = atan2(f_x, √(f_y² + f_z²)).
    Valid only when the linear acceleration is small compared with g.
    Accepts (3,) → two floats, or (N, 3) → two arrays.
    """
    f = np.asarray(f_b, dtype=float)
    if f.ndim == 0 or f.shape[-1] != 3:
        raise ValueError(f"accel_tilt expects specific force with 3 components on the last axis, got shape {f.shape}")
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    roll = np.arctan2(-fy, -fz)
    pitch = np.arctan2(fx, np.hypot(fy, fz))
    if f.ndim == 1:
        return float(roll), float(pitch)
    return roll, pitch


def euler_rates_to_body_rates(euler, euler_dot):
    """Body angular rate ω_b = [p, q, r] (rad/s) from Euler angles and their rates (ZYX).

        p = φ̇ − ψ̇ sin θ
        q = θ̇ cos φ + ψ̇ sin φ cos θ
        r = −θ̇ sin φ + ψ̇ cos φ cos θ

    ``euler`` and ``euler_dot`` are (..., 3) arrays ordered [roll, pitch, yaw].
    """
    e = np.asarray(euler, dtype=float)
    ed = np.asarray(euler_dot, dtype=float)
    phi, theta = e[..., 0], e[..., 1]
    dphi, dtheta, dpsi = ed[..., 0], ed[..., 1], ed[..., 2]
    p = dphi - dpsi * np.sin(theta)
    q = dtheta * np.cos(phi) + dpsi * np.sin(phi) * np.cos(theta)
    r = -dtheta * np.sin(phi) + dpsi * np.cos(phi) * np.cos(theta)
    return np.stack([p, q, r], axis=-1)


def body_rates_to_euler_rates(euler, omega_b):
    """[φ̇, θ̇, ψ̇] (rad/s) from Euler angles [φ, θ, ψ] and body rate [p, q, r] (rad/s), ZYX, the inverse of
    :func:`euler_rates_to_body_rates`:

        φ̇ = p + (q sin φ + r cos φ) tan θ,   θ̇ = q cos φ − r sin φ,   ψ̇ = (q sin φ + r cos φ) / cos θ

    Singular at cos θ = 0 (gimbal lock). ``euler`` and ``omega_b`` are (…, 3); broadcasts over leading axes.
    """
    e = np.asarray(euler, dtype=float)
    w = np.asarray(omega_b, dtype=float)
    sf, cf = np.sin(e[..., 0]), np.cos(e[..., 0])
    ct, tt = np.cos(e[..., 1]), np.tan(e[..., 1])
    p, q, r = w[..., 0], w[..., 1], w[..., 2]
    u = q * sf + r * cf
    return np.stack(np.broadcast_arrays(p + u * tt, q * cf - r * sf, u / ct), axis=-1)


def mount_matrix(spec):
    """A 3×3 mounting matrix M_bs from a nested list (as stored in recording metadata).

    Checks that it is a proper rotation (orthonormal, det +1).
    """
    M = np.asarray(spec, dtype=float)
    if M.shape != (3, 3):
        raise ValueError(f"a mounting matrix must be 3×3, got shape {M.shape}")
    if not np.allclose(M @ M.T, np.eye(3), atol=1e-9) or not np.isclose(np.linalg.det(M), 1.0):
        raise ValueError(f"a mounting matrix must be a rotation (orthonormal, det +1), got {M.tolist()}")
    return M


def _mag_components(m_b):
    m = np.asarray(m_b, dtype=float)
    if m.ndim == 0 or m.shape[-1] != 3:
        raise ValueError(
            f"expected a magnetic field with 3 components on the last axis (µT, body FRD), got shape {m.shape}"
        )
    return m[..., 0], m[..., 1], m[..., 2]


def _heading(y, x, declination, scalar):
    psi = wrap_angle(np.arctan2(y, x) + declination)
    return float(psi) if scalar else psi


def mag_heading(m_b, declination=0.0):
    """Heading ψ (rad, (−π, π]) of a level board from its magnetometer (µT, body FRD).

    Level, m_b = Rz(ψ)ᵀ m_n, so m_x = B_h cos ψ and m_y = −B_h sin ψ:  ψ = atan2(−m_y, m_x).
    That is the magnetic heading; add the ``declination`` (rad, east positive) for true north.
    Wrong by up to the tilt angle × tan(inclination) when the board is not level: see
    :func:`tilt_compensated_heading`. Accepts (3,) → float or (N, 3) → (N,).
    """
    mx, my, _ = _mag_components(m_b)
    return _heading(-my, mx, declination, np.ndim(mx) == 0)


def tilt_compensated_heading(m_b, roll, pitch, declination=0.0):
    """Heading ψ (rad, (−π, π]) from the magnetometer m_b (µT, body FRD) and roll φ, pitch θ (rad).

    De-rotate by roll, then pitch, into the level frame:  m' = Ry(θ) Rx(φ) m_b = Rz(ψ)ᵀ m_n, i.e.

        m'_x = m_x cos θ + (m_y sin φ + m_z cos φ) sin θ
        m'_y = m_y cos φ − m_z sin φ

    and ψ = atan2(−m'_y, m'_x) + declination (rad, east positive; 0 gives magnetic north).
    """
    mx, my, mz = _mag_components(m_b)
    roll, pitch = np.asarray(roll, dtype=float), np.asarray(pitch, dtype=float)
    sf, cf, st, ct = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    mx_level = mx * ct + (my * sf + mz * cf) * st
    my_level = my * cf - mz * sf
    return _heading(-my_level, mx_level, declination, np.ndim(mx_level) == 0)


def declination(field_n=MAG_FIELD_LONDON):
    """Magnetic declination D = atan2(B_E, B_N) (rad, east positive) of a NED field (µT)."""
    return float(np.arctan2(field_n[1], field_n[0]))


# ---- float-only helpers for hot loops ----------------------------------------------------------
# One rotation at a time on plain Python floats, for filters that run a Python loop per sample (the
# MEKF, its magnetometer gate): NumPy's per-call cost (~1 µs) is larger than the arithmetic of a 3-D
# rotation. The same conventions as the array functions above (w-x-y-z, Hamilton product, body → NED)
# and held to scipy's Rotation by tests/test_frames.py, like VQF's quatMultiply and x-io Fusion's
# FusionMath.h. Quaternions are 4-tuples, vectors 3-tuples.

_TWO_PI = 2.0 * math.pi


def quat_multiply_f(p, q):
    """Hamilton product p ⊗ q of two quaternions (w, x, y, z) as a tuple: R(p ⊗ q) = R(p)·R(q)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def quat_to_dcm_f(q):
    """The 3×3 rotation matrix of a unit quaternion (w, x, y, z), row by row, as a 9-tuple
    (r00, r01, r02, r10, …, r22): v_n = R v_b for q body → NED."""
    w, x, y, z = q
    return (
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )


def rotvec_to_quat_f(vx, vy, vz):
    """The exact exponential of a rotation vector v (rad): q = [cos(|v|/2), sin(|v|/2)·v/|v|], the turn by
    |v| about v/|v| (a body rate ω held for dt gives q(t + dt) = q(t) ⊗ exp(ω dt)). Below 1e-8 rad the
    series 1 − |v|²/8, v/2 (exact to double precision)."""
    angle2 = vx * vx + vy * vy + vz * vz
    if angle2 < 1e-16:
        return (1.0 - angle2 / 8.0, 0.5 * vx, 0.5 * vy, 0.5 * vz)
    angle = math.sqrt(angle2)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), vx * s, vy * s, vz * s)


def quat_normalise_f(q):
    """q / |q| for a quaternion (w, x, y, z) as a tuple."""
    w, x, y, z = q
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return (w * n, x * n, y * n, z * n)


def wrap_angle_f(a):
    """One angle (rad) wrapped to (−π, π], like :func:`wrap_angle`."""
    if -math.pi < a <= math.pi:
        return a
    return math.pi - (math.pi - a) % _TWO_PI
