"""Checkpoints of lab 04b (the quaternion multiplicative EKF the student writes).

Expected values come from the lab's reference steps (:mod:`kfkit.labs.lab04b`); the accelerometer Jacobian is
judged against central finite differences of h(q ⊗ exp(δθ/2)), so any correct H passes. A quaternion and its
negative are the same rotation: either passes. Each judge names the classic mistakes it recognises: the product in
the wrong order, the error in the global frame, a scalar-last or unnormalised quaternion, the bias left out of F, a
forgotten reset, a covariance not turned by the reset.
"""

from __future__ import annotations

import numpy as np

from ..frames import (
    cross_matrix,
    quat_conjugate,
    quat_multiply,
    quat_rotate,
    quat_to_dcm,
    quat_to_rotvec,
    rotvec_to_quat,
)
from ..labs.lab04b import (
    UP_N,
    error_state_fd,
    measurement,
    mekf_predict,
    mekf_reset,
    mekf_update,
    process_noise,
    quat_exp,
)
from . import Case, Checkpoint, compare, fmt, register, structural

CASES = 12
FROM_SCALAR_LAST = [3, 0, 1, 2]  # x-y-z-w → w-x-y-z


def _unit_quat(rng):
    q = rng.normal(0.0, 1.0, 4)
    return q / np.linalg.norm(q)


def _random_cov(rng, sigma_angle, sigma_bias):
    """A 6×6 covariance of [δθ, δb] with strong cross-terms (so that F's bias block shows in F P Fᵀ)."""
    A = rng.normal(0.0, 1.0, (6, 6)) * np.r_[[sigma_angle] * 3, [sigma_bias] * 3][:, None]
    return A @ A.T + np.diag(np.r_[[sigma_angle**2] * 3, [sigma_bias**2] * 3])


def _random_field(rng):
    """A plausible Earth field in NED, µT: horizontal 15–35, down −50…60 (either hemisphere)."""
    h, dec = rng.uniform(15.0, 35.0), rng.uniform(-0.3, 0.3)
    return np.array([h * np.cos(dec), h * np.sin(dec), rng.uniform(-50.0, 60.0)])


def _as_quat(got):
    try:
        g = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return None
    return g if g.shape == (4,) else None


def judge_quat(expected, got, atol=1e-9, others=()):
    """None if ``got`` is ``expected`` or its negative (within ``atol``), else why not: scalar-last, not a unit
    quaternion, or one of ``others`` ((quaternion, what it means) pairs a known mistake gives)."""
    problem = compare(expected, got, rtol=0.0, atol=atol)
    g = _as_quat(got)
    if problem is None or g is None:
        return problem
    if np.allclose(-g, expected, rtol=0.0, atol=atol):
        return None
    if np.allclose(np.abs(g[FROM_SCALAR_LAST]), np.abs(expected), rtol=0.0, atol=atol):
        return problem + " — the scalar is last (x, y, z, w): kfkit's quaternions are w-x-y-z, the scalar first"
    if abs(np.linalg.norm(g) - 1.0) > 1e-6:
        return problem + f" — ‖q‖ = {np.linalg.norm(g):.6f}: not a unit quaternion (normalise it)"
    for q, what in others:
        if np.allclose(np.abs(g @ q), 1.0, rtol=0.0, atol=1e-9):
            return problem + f" — {what}"
    return problem


def _triple(got, what="(q, b, P)"):
    """None if ``got`` is a tuple of three, else what is wrong."""
    if not isinstance(got, (tuple, list)) or len(got) != 3:
        return f"expected three values {what}, got {type(got).__name__}"
    return None


# --- 04b.quat_exp ----------------------------------------------------------------------------------


def _quat_exp_cases(rng):
    cases = [
        Case(
            {"omega_prev": np.zeros(3), "omega": np.zeros(3), "dt": 0.01},
            np.array([1.0, 0, 0, 0]),
            "quat_exp at rest (ω = 0: no turn, and no 0/0)",
        )
    ]
    for _ in range(CASES - 1):
        w0, w1, dt = rng.normal(0.0, 4.0, 3), rng.normal(0.0, 4.0, 3), rng.uniform(0.005, 0.02)
        cases.append(Case({"omega_prev": w0, "omega": w1, "dt": dt}, quat_exp(w0, w1, dt)))
    return cases


def _judge_quat_exp(case, got):
    a = case.args
    ends = [
        (
            rotvec_to_quat(w * a["dt"]),
            f"that is the turn at the rate {'at the step’s start' if i == 0 else 'at its end'}"
            f" alone: use the midpoint rate (ω_prev + ω)/2",
        )
        for i, w in enumerate((a["omega_prev"], a["omega"]))
    ]
    whole = rotvec_to_quat((a["omega_prev"] + a["omega"]) * a["dt"])
    return judge_quat(
        case.expected,
        got,
        others=ends + [(whole, "that turns twice as far: the quaternion holds cos(θ/2), sin(θ/2), the half angle")],
    )


# --- 04b.mekf_predict ------------------------------------------------------------------------------


def _predict_cases(rng):
    cases = []
    for _ in range(CASES):
        q, b = _unit_quat(rng), rng.normal(0.0, 0.02, 3)
        P = _random_cov(rng, np.radians(rng.uniform(1.0, 5.0)), np.radians(rng.uniform(0.05, 0.5)))
        w0, w1, dt = rng.normal(0.0, 3.0, 3), rng.normal(0.0, 3.0, 3), rng.uniform(0.005, 0.02)
        args = {
            "q": q,
            "b": b,
            "P": P,
            "omega_prev": w0,
            "omega": w1,
            "dt": dt,
            "gyro_noise": np.radians(rng.uniform(0.05, 1.0)),
            "bias_rw": rng.uniform(1e-5, 1e-3),
        }
        cases.append(Case(args, mekf_predict(**args)))
    return cases


def _judge_predict(case, got):
    problem = _triple(got)
    if problem is not None:
        return problem
    a = case.args
    q_new, b_new, P_new = case.expected
    dq = quat_exp(a["omega_prev"] - a["b"], a["omega"] - a["b"], a["dt"])
    q_problem = judge_quat(
        q_new,
        got[0],
        others=[
            (
                quat_multiply(dq, a["q"]),
                "that is δq ⊗ q, the turn applied in the navigation frame: the gyro measures in "
                "the body frame, so q ⊗ δq",
            ),
            (
                quat_multiply(a["q"], quat_exp(a["omega_prev"], a["omega"], a["dt"])),
                "the gyro bias b is not subtracted",
            ),
        ],
    )
    if q_problem is not None:
        return f"q: {q_problem}"
    if (problem := compare(b_new, got[1])) is not None:
        return f"b: {problem} — the prediction leaves the bias as it is"
    P_problem = compare(P_new, got[2], rtol=1e-6, atol=1e-15)
    if P_problem is None or structural(P_problem):
        return None if P_problem is None else f"P: {P_problem}"
    GQG = process_noise(a["dt"], a["gyro_noise"], a["bias_rw"])
    R_step, I, dt = quat_to_dcm(dq).T, np.eye(3), a["dt"]
    known = [
        (
            np.block([[R_step, 0 * I], [0 * I, I]]),
            "the bias is left out of F: its top-right block is −I·Δt (a bias error turns the attitude error)",
        ),
        (
            np.block([[I, -quat_to_dcm(a["q"]) * dt], [0 * I, I]]),
            "that is the error in the global (NED) frame: the lab's δθ is in the body frame, whose F is "
            "[[R(δq)ᵀ, −IΔt], [0, I]]",
        ),
        (np.block([[R_step.T, -I * dt], [0 * I, I]]), "F's attitude block is R(δq): the error turns back, R(δq)ᵀ"),
    ]
    for F, what in known:
        if np.allclose(got[2], F @ a["P"] @ F.T + GQG, rtol=1e-6, atol=1e-15):
            return f"P: {P_problem} — {what}"
    F = np.block([[R_step, -I * dt], [0 * I, I]])
    if np.allclose(got[2], F @ a["P"] @ F.T, rtol=1e-6, atol=1e-15):
        return f"P: {P_problem} — G Q Gᵀ is not added"
    return f"P: {P_problem}"


# --- 04b.accel_jacobian ----------------------------------------------------------------------------


def _jacobian_cases(rng):
    cases = []
    for _ in range(CASES):
        q = _unit_quat(rng)
        H = np.zeros((3, 6))
        H[:, :3] = error_state_fd(lambda p: quat_rotate(quat_conjugate(p), UP_N), q)
        cases.append(Case({"q": q}, H, f"q = {fmt(q)}"))
    return cases


def _judge_jacobian(case, got):
    problem = compare(case.expected, got, rtol=1e-5, atol=1e-5)
    if problem is None:
        return None
    if structural(problem):
        return problem + " — one row per accelerometer axis, one column per error state [δθ, δb]"
    g = np.asarray(got, float)
    glob = quat_to_dcm(case.args["q"]).T @ cross_matrix(UP_N)
    if np.allclose(g[:, :3], glob, atol=1e-5):
        return problem + (
            " — that is the error in the global (NED) frame, R(q)·(I + [δθ×]) read as (I + [δθ×])·R(q): "
            "the lab's δθ is in the body frame, q_true = q ⊗ exp(δθ/2)"
        )
    if np.allclose(g, -case.expected, atol=1e-5):
        return problem + " — the sign is flipped: [f̂×]·δθ = f̂ × δθ"
    return problem


# --- 04b.mekf_reset --------------------------------------------------------------------------------


def _reset_cases(rng):
    cases = []
    for _ in range(CASES):
        direction = rng.normal(0.0, 1.0, 3)
        dx = np.r_[direction / np.linalg.norm(direction) * np.radians(rng.uniform(1.0, 5.0)), rng.normal(0.0, 1e-3, 3)]
        args = {
            "q": _unit_quat(rng),
            "b": rng.normal(0.0, 0.02, 3),
            "P": _random_cov(rng, np.radians(rng.uniform(1.0, 5.0)), np.radians(0.2)),
            "dx": dx,
        }
        cases.append(Case(args, mekf_reset(**args)))
    return cases


def first_order_reset(q, q_exact):
    """q ⊗ [1, δθ/2]/‖[1, δθ/2]‖, the other reset the lab accepts, of the δθ that turns q into
    q_exact = q ⊗ exp(δθ/2)."""
    dq = np.r_[1.0, 0.5 * quat_to_rotvec(quat_multiply(quat_conjugate(q), q_exact))]
    return quat_multiply(q, dq / np.linalg.norm(dq))


def judge_reset_quat(q, q_exact, got, others=()):
    """None if ``got`` is either accepted reset of q (exact or first order, normalised), else why not."""
    if judge_quat(first_order_reset(q, q_exact), got, atol=1e-8) is None:
        return None
    return judge_quat(q_exact, got, atol=1e-8, others=others)


def _judge_reset(case, got):
    problem = _triple(got)
    if problem is not None:
        return problem
    a = case.args
    q_new, b_new, P_new = case.expected
    dq = rotvec_to_quat(a["dx"][:3])
    q_problem = judge_reset_quat(
        a["q"],
        q_new,
        got[0],
        others=[
            (quat_multiply(dq, a["q"]), "that is δq ⊗ q: the error is in the body frame, q ⊗ δq"),
            (a["q"], "q did not change: fold δθ into it"),
        ],
    )
    if q_problem is not None:
        return f"q: {q_problem}"
    if (problem := compare(b_new, got[1])) is not None:
        return f"b: {problem} — b + δb"
    P_problem = compare(P_new, got[2], rtol=1e-6, atol=1e-15)
    if P_problem is not None and not structural(P_problem) and np.allclose(got[2], a["P"], rtol=1e-9, atol=0.0):
        return (
            f"P: {P_problem} — P was not turned by the reset: the new error is measured from the new q, "
            "so P ← J P Jᵀ with J = diag(I − [δθ/2 ×], I)"
        )
    return None if P_problem is None else f"P: {P_problem}"


# --- 04b.mekf_update -------------------------------------------------------------------------------


def _update_cases(rng):
    cases = []
    for i in range(CASES):
        q_true, m = _unit_quat(rng), _random_field(rng)
        q = quat_multiply(q_true, rotvec_to_quat(rng.normal(0.0, np.radians(3.0), 3)))
        P = _random_cov(rng, np.radians(rng.uniform(1.0, 5.0)), np.radians(rng.uniform(0.05, 0.5)))
        sa, sm = rng.uniform(0.05, 0.5), rng.uniform(0.3, 2.0)
        z = measurement(q_true, m) + rng.normal(0.0, 1.0, 6) * np.r_[[sa] * 3, [sm] * 3]
        if i % 3 == 2:
            z[3:] = np.nan  # no new magnetometer sample
        args = {
            "q": q,
            "b": rng.normal(0.0, 0.02, 3),
            "P": P,
            "z": z,
            "R": np.diag([sa**2] * 3 + [sm**2] * 3),
            "field_n": m,
        }
        label = f"a{' magnetometer-less (NaN)' if i % 3 == 2 else ''} update at q = {fmt(q)}"
        cases.append(Case(args, mekf_update(**args), label))
    return cases


def _judge_update(case, got):
    problem = _triple(got)
    if problem is not None:
        return problem
    q_new, b_new, P_new = case.expected
    q_problem = judge_reset_quat(
        case.args["q"],
        q_new,
        got[0],
        others=[(case.args["q"], "q did not change: after the update, fold δθ into q and δb into b (the reset)")],
    )
    if q_problem is not None:
        return f"q: {q_problem}"
    if (problem := compare(b_new, got[1], rtol=1e-5, atol=1e-9)) is not None:
        return f"b: {problem} — b + δb, with δb the last three elements of K·y"
    P_problem = compare(P_new, got[2], rtol=1e-5, atol=1e-15)
    return None if P_problem is None else f"P: {P_problem}"


register(
    Checkpoint(
        "04b.quat_exp",
        "quat_exp",
        _quat_exp_cases,
        _judge_quat_exp,
        points=1,
        hint="a turn by θ = ‖ω̄‖Δt about n = ω̄/‖ω̄‖ is [cos(θ/2), sin(θ/2)·n], scalar first; at θ = 0 it is "
        "[1, 0, 0, 0].",
    ),
    Checkpoint(
        "04b.mekf_predict",
        "mekf_predict",
        _predict_cases,
        _judge_predict,
        points=2,
        hint="turn q by δq = quat_exp(ω_prev − b, ω − b, Δt) on the right (the body frame); P ← F P Fᵀ + G Q "
        "Gᵀ with F = [[R(δq)ᵀ, −IΔt], [0, I]] and Q = diag(σ_g²Δt² I, σ_bw²Δt I). Return (q, b, P).",
    ),
    Checkpoint(
        "04b.accel_jacobian",
        "accel_jacobian",
        _jacobian_cases,
        _judge_jacobian,
        points=2,
        what="random attitudes",
        hint="write h(q) = R(q)ᵀ(0, 0, −g) with R(q ⊗ exp(δθ/2)) ≈ R(q)(I + [δθ×]) and keep the first-order "
        "term in δθ; compare each column with your finite differences.",
    ),
    Checkpoint(
        "04b.mekf_reset",
        "mekf_reset",
        _reset_cases,
        _judge_reset,
        points=1,
        hint="q ⊗ exp(δθ/2) (the body frame, on the right), b + δb, and P ← J P Jᵀ with "
        "J = diag(I − [δθ/2 ×], I). Return (q, b, P).",
    ),
    Checkpoint(
        "04b.mekf_update",
        "mekf_update",
        _update_cases,
        _judge_update,
        points=2,
        hint="h = [R(q)ᵀ(0, 0, −g); R(q)ᵀm_n], H = [[ĥ_a×], 0; [ĥ_m×], 0]; K = P Hᵀ S⁻¹, δx = K y, "
        "P = (I − K H) P, then mekf_reset; with NaN in z[3:] keep only the first three rows.",
    ),
)
