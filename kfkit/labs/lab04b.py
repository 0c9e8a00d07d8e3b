"""Lab 04b (the quaternion MEKF the student writes): the lab's reference steps, its settings and its runs on BROAD.

The error state is δx = [δθ, δb] (rad, rad/s): δθ a small rotation in the **body** frame, q_true = q ⊗ exp(δθ/2)
(q body → NED, w-x-y-z), b_true = b + δb. The steps below are the textbook MEKF the lab derives, written for the
checkpoints to compare with (:mod:`kfkit.checkpoints.lab04b`); the notebook's student writes the same five.

    quat_exp       δq = exp(ω̄Δt/2) = [cos(θ/2), sin(θ/2)·n], θ·n = ω̄Δt, ω̄ = (ω_{k−1} + ω_k)/2
    mekf_predict   q ← q ⊗ δq (with ω − b),  P ← F P Fᵀ + G Q Gᵀ,  F = [[R(δq)ᵀ, −IΔt], [0, I]],  G = diag(−I, I)
    accel_jacobian H = [[f̂_b×], 0] with f̂_b = R(q)ᵀ·(0, 0, −g)
    mekf_update    y = z − h(q), K = P Hᵀ S⁻¹, δx = K y, P ← (I − K H) P, then mekf_reset
    mekf_reset     q ← q ⊗ exp(δθ/2), b ← b + δb, P ← J P Jᵀ with J = diag(I − [δθ/2 ×], I)
"""

from __future__ import annotations

import numpy as np

from .. import datasets
from ..filters.attitude_run import hold_last_sample, learn_field, tilt_heading
from ..frames import (
    G,
    cross_matrix,
    enu_to_ned_quat,
    euler_to_quat,
    quat_conjugate,
    quat_multiply,
    quat_rotate,
    quat_to_dcm,
    rotvec_to_quat,
)
from ..metrics import attitude_rmse
from ..rest_calibration import gyro_bias

#: the specific force an accelerometer at rest reads, in NED (m/s²): the reaction to gravity, "up"
UP_N = np.array([0.0, 0.0, -G])

#: the lab's tuning: σ_g per sample (rad/s), σ_bw (rad/s/√s) and σ_m per axis (µT) are kfkit's MEKF's defaults at
#: 100 Hz; σ_a (m/s²) is the size of the hand's pushes, which the model calls noise (the median |‖f‖ − g| while
#: moving is 1.2 m/s² on trial 06, 2.9 on 28), where kfkit's MEKF low-passes the accelerometer first and then keeps
#: 0.02 at 100 Hz, raised with the linear acceleration it measures;
#: above ACCEL_GATE m/s² of |‖f‖ − g|, σ_a² is multiplied by GATE_FACTOR
TUNING = {"gyro_noise": np.radians(0.2), "bias_rw": 1e-5, "accel_noise": 2.0, "mag_noise": 1.0}
ACCEL_GATE, GATE_FACTOR = 1.0, 100.0
#: the start's covariance: 2° per attitude axis, 0.1 °/s per bias axis
P0 = np.diag(np.r_[[np.radians(2.0) ** 2] * 3, [np.radians(0.1) ** 2] * 3])
#: the bundled BROAD excerpts the lab runs on
TRIALS = ("04_broad_fast_rotation", "04_broad_stationary_magnet")


def quat_exp(omega_prev, omega, dt):
    """δq = exp(ω̄Δt/2) (4,), the rotation over one step at the midpoint rate ω̄ = (ω_prev + ω)/2 (rad/s)."""
    return rotvec_to_quat(0.5 * (np.asarray(omega_prev, float) + np.asarray(omega, float)) * dt)


def transition(dq, dt):
    """The error state's F (6×6) over a step that turned the body by δq: [[R(δq)ᵀ, −IΔt], [0, I]]."""
    F = np.eye(6)
    F[:3, :3], F[:3, 3:] = quat_to_dcm(dq).T, -np.eye(3) * dt
    return F


def process_noise(dt, gyro_noise, bias_rw):
    """G Q Gᵀ (6×6) with Q = diag(σ_g²Δt² I, σ_bw²Δt I) and G = diag(−I, I) (the signs cancel in G Q Gᵀ)."""
    return np.diag(np.r_[[(gyro_noise * dt) ** 2] * 3, [bias_rw**2 * dt] * 3])


def mekf_predict(q, b, P, omega_prev, omega, dt, gyro_noise, bias_rw):
    """One prediction: (q ⊗ δq, b, F P Fᵀ + G Q Gᵀ) with δq = quat_exp(ω_prev − b, ω − b, Δt)."""
    dq = quat_exp(np.asarray(omega_prev) - b, np.asarray(omega) - b, dt)
    F = transition(dq, dt)
    return quat_multiply(q, dq), np.array(b, float), F @ P @ F.T + process_noise(dt, gyro_noise, bias_rw)


def vector_jacobian(q, v_n):
    """H (3×6) of a reference vector v_n (NED) seen in the body frame, R(q)ᵀ v_n, w.r.t. [δθ, δb]."""
    H = np.zeros((3, 6))
    H[:, :3] = cross_matrix(quat_rotate(quat_conjugate(q), v_n))
    return H


def accel_jacobian(q):
    """H (3×6) of the accelerometer's h(q) = R(q)ᵀ·(0, 0, −g): [[f̂_b×], 0]."""
    return vector_jacobian(q, UP_N)


def measurement(q, field_n):
    """h(q) (6,): the accelerometer's R(q)ᵀ·(0, 0, −g) (m/s²) and the magnetometer's R(q)ᵀ·m_n (µT)."""
    return np.r_[quat_rotate(quat_conjugate(q), UP_N), quat_rotate(quat_conjugate(q), field_n)]


def mekf_reset(q, b, P, dx):
    """Fold the estimated error into the nominal state: (q ⊗ exp(δθ/2), b + δb, J P Jᵀ), J = diag(I − [δθ/2 ×], I)."""
    J = np.eye(6)
    J[:3, :3] -= cross_matrix(0.5 * np.asarray(dx[:3]))
    return quat_multiply(q, rotvec_to_quat(dx[:3])), np.asarray(b) + dx[3:], J @ P @ J.T


def mekf_update(q, b, P, z, R, field_n):
    """One update with z = [f_b (m/s²), m_b (µT)] (NaN magnetometer: its rows left out), then the reset."""
    rows = slice(0, 3) if np.isnan(z[3:]).any() else slice(0, 6)
    H = np.vstack([accel_jacobian(q), vector_jacobian(q, field_n)])[rows]
    y = (z - measurement(q, field_n))[rows]
    S = H @ P @ H.T + R[rows, rows]
    K = np.linalg.solve(S, H @ P).T
    return mekf_reset(q, b, (np.eye(6) - K @ H) @ P, K @ y)


def error_state_fd(h, q, eps=1e-6):
    """Central finite differences of h(q ⊗ exp(δθ/2)) w.r.t. δθ at 0: the attitude columns (m×3) of H."""
    return np.stack(
        [
            (h(quat_multiply(q, rotvec_to_quat(eps * e))) - h(quat_multiply(q, rotvec_to_quat(-eps * e)))) / (2 * eps)
            for e in np.eye(3)
        ],
        axis=-1,
    )


def broad(name):
    """A bundled BROAD excerpt as lab 04 prepares it, cut where its movement ends (BROAD counts nothing after it):
    (recording, gyr rad/s less the first rest's mean (lab 02's bias), acc m/s², mag µT, field_n µT NED learned from
    the first samples (magnetic north, as the truth's), truth quaternions body → NED (NaN where the markers were not
    seen), the movement mask)."""
    rec = datasets.load(name)
    end = np.flatnonzero(rec.phase("movement"))[-1] + 1
    first_rest = rec.phase("rest") & (rec.t < rec.phases[0]["end"])
    gyr, acc, mag = (rec.body(s)[:end] for s in ("gyr", "acc", "mag"))
    gyr = gyr - gyro_bias(rec.body("gyr")[first_rest])
    return rec, gyr, acc, mag, learn_field(acc, mag), euler_to_quat(rec.truth()[:end]), rec.phase("movement")[:end]


def initial_state(acc, mag, field_n):
    """The start (q, b, P): q from one accelerometer and magnetometer sample (tilt, then heading), b = 0 (the rest's
    bias is already removed), P = P0."""
    return euler_to_quat(tilt_heading(acc, mag, field_n)), np.zeros(3), P0.copy()


def noise_matrix(acc, accel_noise, mag_noise, accel_gate=ACCEL_GATE):
    """R (6×6) for one sample: σ_a² per accelerometer axis, × GATE_FACTOR when |‖f‖ − g| > accel_gate (the hand
    pushes the board: the accelerometer reads more than gravity), and σ_m² per magnetometer axis."""
    ra = accel_noise**2 * (GATE_FACTOR if abs(np.linalg.norm(acc) - G) > accel_gate else 1.0)
    return np.diag([ra] * 3 + [mag_noise**2] * 3)


def vqf_quat(gyr, acc, mag, rate_hz):
    """VQF 2.1.2 (Laidig and Seel 2023, causal, its defaults) on the same samples (the magnetometer's NaN rows holding
    the last sample), quaternions body → NED; None when the vqf package is not installed (environment.txt pins it)."""
    try:
        from vqf import VQF
    except ImportError:
        return None
    c = np.ascontiguousarray
    return enu_to_ned_quat(VQF(1.0 / rate_hz).updateBatch(c(gyr), c(acc), c(hold_last_sample(mag)))["quat9D"])


def errors_text(q, q_true, moving):
    """BROAD's total (heading / inclination) RMSE over the movement, in degrees, as text."""
    e = {k: np.degrees(v) for k, v in attitude_rmse(q, q_true, moving).items()}
    return f"{e['total']:5.2f} ({e['heading']:.2f} / {e['inclination']:.2f})"
