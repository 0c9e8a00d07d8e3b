"""Checkpoints of lab 05 (two-state [angle, gyro bias] tilt filter on an MPU6050): cases, judges and points.

The lab's recordings, windows and reference pipeline are :mod:`kfkit.labs.lab05`'s; the filter's textbook forms
(:func:`~kfkit.filters.tilt_kf_predict`, :func:`~kfkit.filters.tilt_kf_update`, :func:`~kfkit.filters.tilt_kf`) are
the references.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..filters import TiltBiasKF, protocol_angles, tilt, tilt_kf, tilt_kf_predict, tilt_kf_update
from ..frames import G, accel_tilt, mount_matrix, wrap_angle
from ..labs.lab05 import BOARD, Q_BIAS_RATIO, bundled, pipeline_inputs, static_rmse, true_gyro_bias, tune_on_holds
from . import Case, Checkpoint, compare, matches, register

RMSE_LIMIT = np.radians(0.5)  # final checkpoint: static-window RMSE, rad
BIAS_TOLERANCE = 0.10  # final checkpoint: relative bias error in the holds after 30 s
BIAS_AFTER = 30.0  # s
#: final checkpoint: roll RMSE (rad) against the simulation's roll over the nose-up holds (pitch 90°), where the
#: protocol's reference is unknown. There √(f_y² + f_z²) = g·cos θ is noise, so an ungated accelerometer roll is
#: arbitrary (kfkit without the gate: 44° RMS, 140° worst); a gated filter carries roll on the gyro (kfkit: 1.9°).
NOSE_UP_LIMIT = np.radians(10.0)
NOSE_UP = "pitch_90"


# --- conversion ---------------------------------------------------------------------------------------


def _to_body_cases(rng):
    cases = []
    for n in (1, 5, 20):
        acc = rng.integers(-20000, 20000, (n, 3))
        gyr = rng.integers(-3000, 3000, (n, 3))
        f = acc * BOARD.accel.sensitivity @ mount_matrix(BOARD.mount["acc"]).T
        w = gyr * BOARD.gyro.sensitivity @ mount_matrix(BOARD.mount["gyr"]).T
        cases.append(Case({"acc_counts": acc, "gyr_counts": gyr}, (f, w), f"{n} random samples"))
    level = np.array([[0, 0, 16384]])
    cases.insert(
        0,
        Case(
            {"acc_counts": level, "gyr_counts": np.array([[131, 0, 0]])},
            (np.array([[0.0, 0.0, -G]]), np.array([[np.radians(1.0), 0.0, 0.0]])),
            "the board flat and still, turning at 1 °/s about x",
        ),
    )
    return cases


# --- tilt ----------------------------------------------------------------------------------------------


def _tilt_cases(rng):
    cases = []
    for roll, pitch in [(0.0, 0.0), (np.pi / 2, 0.0), (0.0, np.pi / 3), (-2.5, -1.2), (3.0, 0.5)]:
        f = np.array([G * np.sin(pitch), -G * np.sin(roll) * np.cos(pitch), -G * np.cos(roll) * np.cos(pitch)])
        cases.append(Case({"f": f[None, :]}, accel_tilt(f[None, :])))
    f = rng.normal(0.0, G, (25, 3))
    cases.append(Case({"f": f}, accel_tilt(f), "25 random specific forces"))
    return cases


def _judge_tilt(case, got):
    problem = compare(case.expected, got, atol=1e-9)
    if problem is None or not isinstance(got, (tuple, list)) or len(got) != 2:
        return problem
    try:
        roll, pitch = (np.asarray(g, dtype=float) for g in got)
        if np.allclose(np.abs(wrap_angle(roll - case.expected[0])), np.pi, atol=1e-6):
            return problem + " — roll is exactly 180° off"
        if np.allclose(pitch, -case.expected[1], atol=1e-9) and not np.allclose(pitch, case.expected[1], atol=1e-9):
            return problem + " — pitch has the wrong sign"
    except (TypeError, ValueError):
        pass
    return problem


# --- the filter -----------------------------------------------------------------------------------


def _random_state(rng):
    x = np.array([rng.uniform(-1.5, 1.5), rng.normal(0.0, 0.05)])
    L = np.array([[rng.uniform(0.01, 0.1), 0.0], [rng.normal(0.0, 0.005), rng.uniform(0.001, 0.01)]])
    return x, L @ L.T


def _random_Q(rng):
    """A process noise as Van Loan gives it: q_θ, q_b over decades and a negative off-diagonal (the −K²Δt²/2 of
    :func:`kfkit.discrete.angle_bias_process_noise`), 20–50 % of √(q_θ q_b) so that dropping it shows (≥ 2e-8)."""
    q_angle, q_bias = 10 ** rng.uniform(-6, -3), 10 ** rng.uniform(-8, -5)
    cross = -rng.uniform(0.2, 0.5) * np.sqrt(q_angle * q_bias)
    return np.array([[q_angle, cross], [cross, q_bias]])


def _predict_cases(rng):
    cases = []
    for _ in range(10):
        x, P = _random_state(rng)
        args = {
            "x": x,
            "P": P,
            "omega": rng.normal(0.0, 1.0),
            "dt": float(rng.choice([0.01, 0.005, 1 / 104])),
            "Q": _random_Q(rng),
        }
        cases.append(Case(args, tilt_kf_predict(**args)))
    return cases


def _judge_predict(case, got):
    problem = compare(case.expected, got)
    if problem is None:
        return None
    a = case.args
    if compare(tilt_kf_predict(a["x"], a["P"], a["omega"], a["dt"], np.diag(np.diag(a["Q"]))), got) is None:
        return f"{problem} — that is the prediction with Q's off-diagonal left out"
    return problem


def _update_cases(rng):
    cases = []
    for _ in range(10):
        x, P = _random_state(rng)
        args = {"x": x, "P": P, "z": x[0] + rng.normal(0.0, 0.1), "r": 10 ** rng.uniform(-6, -2)}
        cases.append(Case(args, tilt_kf_update(**args)))
    return cases


def _run_cases(rng):
    cases = []
    for gate in tilt.GATINGS * 2:
        n = int(rng.integers(20, 80))
        x0, P0 = _random_state(rng)
        args = {
            "gyro_rate": rng.normal(0.0, 0.5, n),
            "accel_angle": rng.normal(0.0, 0.3, n),
            "static_ok": rng.random(n) > 0.3,
            "dt": 0.01,
            "Q": _random_Q(rng),
            "r": 10 ** rng.uniform(-5, -2),
            "gate": gate,
            "x0": x0,
            "P0": P0,
        }
        cases.append(Case(args, tilt_kf(**args), f"gate={gate!r}, a random sequence of {n} samples"))
    return cases


def _judge_run(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-10)
    if problem is None or not isinstance(got, (tuple, list)) or len(got) != 2:
        return problem
    try:
        x = np.asarray(got[0], dtype=float)
        first = int(np.flatnonzero(~np.isclose(x, case.expected[0], rtol=1e-6, atol=1e-10).all(axis=1))[0])
    except (TypeError, ValueError, IndexError):
        return problem
    ok = bool(case.args["static_ok"][first])
    return f"{problem}; first differs at sample {first}, where static_ok is {ok}"


# --- tuning and the whole pipeline ------------------------------------------------------------------


@lru_cache(maxsize=1)
def _tuned_pitch():
    """kfkit's tuning on the bundled pitch axis and its RMSEs, computed once per process."""
    axes, dt, r, q0 = pipeline_inputs()
    gyro, angle, ok, ref = axes["pitch"]
    q_angle, q_bias = tune_on_holds(gyro, angle, ok, ref, dt, r, q0)
    best = static_rmse(TiltBiasKF(dt, q_angle=q_angle, q_bias=q_bias, r=r).run(gyro, angle, ok).angle, ref)
    start = static_rmse(TiltBiasKF(dt, q_angle=q0, q_bias=Q_BIAS_RATIO * q0, r=r).run(gyro, angle, ok).angle, ref)
    return (
        {"gyro_rate": gyro, "accel_angle": angle, "static_ok": ok, "reference": ref, "dt": dt, "r": r, "q0": q0},
        best,
        start,
    )


def _tune_cases(rng):
    args, best, start = _tuned_pitch()
    return [Case(dict(args), {"best": best, "start": start}, "the bundled recording's pitch")]


def _judge_tune(case, got):
    try:
        q_angle, q_bias = (float(v) for v in got)
    except (TypeError, ValueError):
        return f"expected two numbers (q_angle, q_bias), got {type(got).__name__}"
    if not (q_angle > 0 and q_bias >= 0):
        return f"q_angle must be > 0 and q_bias ≥ 0, got {q_angle:.3g}, {q_bias:.3g}"
    a = case.args
    rmse = static_rmse(
        TiltBiasKF(a["dt"], q_angle=q_angle, q_bias=q_bias, r=a["r"])
        .run(a["gyro_rate"], a["accel_angle"], a["static_ok"])
        .angle,
        a["reference"],
    )
    if rmse > 1.1 * case.expected["best"]:
        return (
            f"static-window RMSE {np.degrees(rmse):.3f}° with q_angle = {q_angle:.2e}, q_bias = {q_bias:.2e}; "
            f"kfkit's tuning reaches {np.degrees(case.expected['best']):.3f}°"
            f" (from {np.degrees(case.expected['start']):.3f}° at q0)"
        )
    return None


def _final_cases(rng):
    tilt, still, faces = bundled()
    roll_ref, pitch_ref = protocol_angles(tilt)
    settled = (tilt.t >= BIAS_AFTER) & ~(np.isnan(roll_ref) & np.isnan(pitch_ref))  # the holds after 30 s
    return [
        Case(
            {"tilt": tilt, "still": still, "faces": faces},
            {
                "ref": (roll_ref, pitch_ref),
                "bias": true_gyro_bias(tilt)[:2],
                "settled": settled,
                "nose_up": tilt.phase(NOSE_UP),
                "true_roll": tilt["true_roll"],
            },
            "the bundled recordings 05_tilt_protocol, 05_stationary, 05_six_faces",
        )
    ]


def _judge_final(case, got):
    try:
        roll, pitch, roll_bias, pitch_bias = (np.asarray(g, dtype=float) for g in got)
    except (TypeError, ValueError):
        return "expected four arrays (roll, pitch, roll_bias, pitch_bias)"
    n = len(case.args["tilt"])
    if any(a.shape != (n,) for a in (roll, pitch, roll_bias, pitch_bias)):
        shapes = ", ".join(str(a.shape) for a in (roll, pitch, roll_bias, pitch_bias))
        return f"expected four arrays of {n} samples, got shapes {shapes}"
    problems = []
    for name, est, ref in (("roll", roll, case.expected["ref"][0]), ("pitch", pitch, case.expected["ref"][1])):
        err = static_rmse(est, ref)
        if not err < RMSE_LIMIT:
            problems.append(
                f"{name} RMSE on the static windows {np.degrees(err):.2f}° (limit {np.degrees(RMSE_LIMIT):.1f}°)"
            )
    nose_up = case.expected["nose_up"]
    err = np.sqrt(np.mean(wrap_angle(roll[nose_up] - case.expected["true_roll"][nose_up]) ** 2))
    if not err < NOSE_UP_LIMIT:
        problems.append(
            f"roll RMSE {np.degrees(err):.1f}° while the board points nose-up"
            f" (limit {np.degrees(NOSE_UP_LIMIT):.0f}°): "
            "there f_y and f_z are only noise, so the accelerometer roll must not update the filter"
        )
    settled = case.expected["settled"]
    for name, est, true in (
        ("roll", roll_bias, case.expected["bias"][0]),
        ("pitch", pitch_bias, case.expected["bias"][1]),
    ):
        tolerance = BIAS_TOLERANCE * abs(true)
        if abs(est[0] - true) <= tolerance:  # started at the answer: nothing left for the filter to find
            problems.append(
                f"{name} gyro bias is {np.degrees(est[0]):+.3f} °/s already at the first sample (simulated "
                f"{np.degrees(true):+.3f} °/s): start the bias state at 0 so that the check sees the filter find it"
            )
            continue
        worst = int(np.argmax(np.where(settled, np.abs(est - true), -np.inf)))
        if not abs(est[worst] - true) <= tolerance:
            problems.append(
                f"{name} gyro bias {np.degrees(est[worst]):+.3f} °/s at t = {case.args['tilt'].t[worst]:.2f} s "
                f"(a hold after {BIAS_AFTER:.0f} s), simulated {np.degrees(true):+.3f} °/s "
                f"(tolerance {100 * BIAS_TOLERANCE:.0f} %)"
            )
    return "; ".join(problems) or None


# --- questions ---------------------------------------------------------------------------------------------------


def steady_gain_q(tau, dt, r):
    """q (rad²) whose steady-state gain K makes an error decay as e^(−t/τ): (1 − K) = e^(−Δt/τ) per step, and the
    scalar random-walk filter's fixed point K²/(1 − K) = q/r. (√(q/r) ≈ Δt/τ, the lab's approximation, is within
    4 % of it for τ ≥ 30 Δt.)"""
    K = 1.0 - np.exp(-dt / tau)
    return r * K**2 / (1.0 - K)


TIME_CONSTANT_TOLERANCE = 0.10  # relative: the exact fixed point and the lab's K ≈ √(q/r) ≈ Δt/τ both pass


def _time_constant_cases(rng):
    cases = [
        Case({"tau": 1.0, "dt": 0.01, "r": 1.6e-5}, steady_gain_q(1.0, 0.01, 1.6e-5), "the question: 1 s at 100 Hz")
    ]
    for _ in range(5):
        args = {
            "tau": float(rng.uniform(0.3, 5.0)),
            "dt": float(rng.choice([0.01, 1 / 104, 0.005])),
            "r": float(10 ** rng.uniform(-6, -4)),
        }
        cases.append(Case(args, steady_gain_q(**args)))
    return cases


def _judge_time_constant(case, got):
    try:
        q = float(got)
    except (TypeError, ValueError):
        return f"expected one number q_θ (rad²), got {type(got).__name__}"
    want = case.expected
    if not abs(q - want) <= TIME_CONSTANT_TOLERANCE * want:
        return f"expected q_θ ≈ {want:.3g} rad² (within {100 * TIME_CONSTANT_TOLERANCE:.0f} %), got {q:.3g}"
    return None


register(
    Checkpoint(
        "05.to_body",
        "to_body",
        _to_body_cases,
        matches(rtol=1e-9, atol=1e-12),
        points=1,
        hint="counts / 16384 is in g and counts / 131 in °/s: convert to m/s² and rad/s, then to the body frame "
        "(this sensor's z points up when the board is flat: y and z change sign).",
    ),
    Checkpoint(
        "05.accel_tilt",
        "accel_tilt",
        _tilt_cases,
        _judge_tilt,
        points=1,
        hint="at rest f = [g sinθ, −g sinφ cosθ, −g cosφ cosθ]: roll from f_y and f_z, pitch from f_x against "
        "the length of (f_y, f_z); level must give (0, 0).",
    ),
    Checkpoint(
        "05.kf_predict",
        "kf_predict",
        _predict_cases,
        _judge_predict,
        points=1,
        hint="x⁻ = A x + B ω with A = [[1, −dt], [0, 1]], B = [dt, 0]; P⁻ = A P Aᵀ + Q, all of Q: Van Loan's has "
        "an off-diagonal.",
    ),
    Checkpoint(
        "05.kf_update",
        "kf_update",
        _update_cases,
        matches(),
        points=2,
        hint="H = [1, 0]: y = z − x[0], S = P[0, 0] + r, K = P Hᵀ / S (a 2-vector); x + K y, (I − K H) P. "
        "Return (x, P, y, S).",
    ),
    Checkpoint(
        "05.run_kf",
        "run_kf",
        _run_cases,
        _judge_run,
        points=2,
        hint="predict at every sample; update when static_ok, or else: 'none' updates anyway, 'skip' does not "
        "update, 'inflate' updates with r × 100. Keep x and P after each sample.",
    ),
    Checkpoint(
        "05.tune",
        "tune",
        _tune_cases,
        _judge_tune,
        points=2,
        what="bundled recording",
        hint="minimise the mean squared error on the holds over log₁₀ q_angle (q_bias = 10⁻⁴ q_angle); the "
        "cost has more than one dip: scan the six decades above q0 first, then refine near the best "
        "with scipy.optimize.minimize_scalar.",
    ),
    Checkpoint(
        "05.final",
        "estimate_tilt",
        _final_cases,
        _judge_final,
        points=3,
        what="bundled recordings",
        hint="six-face-correct the accelerometer, gate roll where √(f_y² + f_z²) is small (pitch near 90°), "
        "use your tuned q's, and feed the filter the raw gyro rates from a bias state of 0, so that it has "
        "the bias to find.",
    ),
    Checkpoint(
        "05.time_constant",
        "q_for_time_constant",
        _time_constant_cases,
        _judge_time_constant,
        points=1,
        hint="an error shrinks by (1 − K) per step, so K ≈ Δt/τ; section 7 relates the steady gain to q_θ and r.",
    ),
)
