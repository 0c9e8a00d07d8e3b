"""Checkpoints of lab 04's core path (sections 2–7: an Euler-angle EKF built step by step, then run whole).

``04.euler_rates``, ``04.predict``, ``04.measurement``, ``04.jacobian``, ``04.numerical_jacobian``, ``04.update`` and
``04.ekf_rmse``. Every expected value comes from kfkit's reference (:mod:`kfkit.filters.euler_ekf`); the
Jacobian is judged against central finite differences of kfkit's h(x), so any correct H passes.
The student's ``run_ekf`` feeds each step the midpoint rate ½(ω_{k−1} + ω_k): its references run kfkit's filter on
:func:`kfkit.labs.lab04.midpoint_rates`. The recordings and their truth come from :mod:`kfkit.labs.lab04`, which the
notebook uses too. The lab's other checkpoints are in :mod:`.ekf_attitude_optional`; :mod:`.lab04` registers both.
"""

from __future__ import annotations

import numpy as np

from ..filters.euler_ekf import (
    EulerAttitudeEKFSettings,
    attitude_jacobian,
    attitude_measurement,
    euler_ekf_predict,
    euler_ekf_update,
    euler_process_noise,
)
from ..frames import MAG_FIELD_LONDON, body_rates_to_euler_rates, wrap_angle
from ..labs.lab04 import (
    ACCEL_GATE,
    BURST_ACCEL,
    BURSTS,
    RECORDING,
    TURNS,
    accelerated,
    bundled_inputs,
    noise_free_turns,
)
from ..metrics import angle_error, rmse
from . import Case, Checkpoint, compare, fmt, matches, register, structural

#: the full filter must reach these RMSEs on the bundled recording (rad): roll, pitch, yaw
RMSE_LIMITS = np.radians([1.0, 1.0, 2.0])
#: … and, with a gyro bias it was not told about (EXTRA_BIAS on x and y, or on z alone, the signs drawn), these. The
#: calibrated gyro alone stays within the limits above on this recording, so these cases show the updates at work:
#: the tilt bias needs the accelerometer (kfkit: roll, pitch ≤ 1.6°; the gyro alone drifts by tens of degrees), the
#: heading bias the magnetometer throughout (kfkit: yaw 3.4–3.6°; a filter that uses only its first magnetometer
#: sample drifts to 9–10°)
EXTRA_BIAS = np.radians(0.3)
BIASED_RMSE_LIMITS = np.radians([3.0, 3.0, 5.0])
#: the noise-free turns: kfkit, fed the midpoint rate, stays within 0.002°; fed the rate at the step's end, 0.2–0.4°
TURN_RMSE_LIMITS = np.radians([0.05, 0.05, 0.05])
TILT_ADVICE = "the gyro alone drifts like this: are the accelerometer and magnetometer updates applied?"
HEADING_ADVICE = (
    "the heading drifts with the gyro's bias: only the magnetometer can hold it, so every new magnetometer "
    "sample must be used, not only the first"
)
GATE_ADVICE = (
    "the filter follows the accelerated specific force: where |‖f‖ − g| > accel_gate, is R's accelerometer "
    "block inflated?"
)
TURN_ADVICE = (
    "the estimate runs about half a sample ahead of the truth while turning: the step from t_{k−1} to t_k "
    "needs the mean rate over it, ½(ω_{k−1} + ω_k), not the sample at its end"
)
ANGLES = ("roll", "pitch", "yaw")


def _random_state(rng, max_pitch=np.radians(80.0)):
    return np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-max_pitch, max_pitch), rng.uniform(-np.pi, np.pi)])


def _random_field(rng):
    """A plausible Earth field in NED, µT: horizontal 15–35, down −50…60 (either hemisphere)."""
    h, dec = rng.uniform(15.0, 35.0), rng.uniform(-0.3, 0.3)
    return np.array([h * np.cos(dec), h * np.sin(dec), rng.uniform(-50.0, 60.0)])


def _random_cov(rng, n, scale):
    A = rng.normal(0.0, scale, (n, n))
    return A @ A.T + np.eye(n) * scale**2


# --- 04.euler_rates ---------------------------------------------------------------------------


def _euler_rates_cases(rng):
    cases = [
        Case(
            {"euler": np.array([0.3, 0.0, 0.0]), "omega_b": np.array([0.0, 0.0, 0.5])},
            body_rates_to_euler_rates([0.3, 0.0, 0.0], [0.0, 0.0, 0.5]),
            "euler_rates(φ = 17°, θ = 0, r = 0.5 rad/s)",
        )
    ]
    for _ in range(11):
        e, w = _random_state(rng), rng.normal(0.0, 1.0, 3)
        cases.append(Case({"euler": e, "omega_b": w}, body_rates_to_euler_rates(e, w)))
    return cases


def _judge_euler_rates(case, got):
    problem = compare(case.expected, got)
    if problem is None or structural(problem):
        return problem
    phi, theta = case.args["euler"][:2]
    p, q, r = case.args["omega_b"]
    g = np.asarray(got, float)
    if np.allclose(g, case.args["omega_b"]):
        return problem + " — these are the body rates p, q, r unchanged: Euler angle rates differ from them (φ̇ = p + …)"
    u = q * np.sin(phi) + r * np.cos(phi)
    if (
        np.allclose(g[:2], case.expected[:2])
        and np.isclose(g[2], u / np.cos(phi))
        and not np.isclose(np.cos(phi), np.cos(theta))
    ):
        return problem + " — ψ̇ looks divided by cos φ: the widely copied mistake"
    return problem


# --- 04.predict -------------------------------------------------------------------------------


def crossing_rate(x, psi_dot):
    """A body rate ω_b that turns the yaw at ``psi_dot`` (rad/s) at state x, with φ̇ = θ̇ = 0: the rate
    about the vertical, ω_b = R_bn·(0, 0, ψ̇) (from ψ̇ = (q sin φ + r cos φ)/cos θ, q cos φ = r sin φ, p = −ψ̇ sin θ)."""
    phi, theta = x[0], x[1]
    return psi_dot * np.array([-np.sin(theta), np.sin(phi) * np.cos(theta), np.cos(phi) * np.cos(theta)])


def _predict_cases(rng):
    """Random states and rates, the first two turning the yaw across +180° and −180° whatever the seed
    (ψ starts 1 mrad short of ±π and turns at 1 rad/s for dt ≥ 5 ms: 5 mrad past it)."""
    cases = []
    for i in range(12):
        x = _random_state(rng)
        w = rng.normal(0.0, 1.0, 3)
        if i < 2:
            sense = 1.0 if i == 0 else -1.0
            x[2] = sense * (np.pi - 1e-3)
            w = crossing_rate(x, sense * 1.0)
        dt = float(rng.choice([0.01, 1 / 104, 0.005]))
        P = _random_cov(rng, 3, np.radians(rng.uniform(0.5, 5.0)))
        Q = euler_process_noise(x, np.radians(rng.uniform(0.05, 1.0)), dt)
        args = {"x": x, "P": P, "omega_b": w, "dt": dt, "Q": Q}
        cases.append(Case(args, euler_ekf_predict(**args)))
    return cases


def _judge_predict(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-9)
    if problem is None or not isinstance(got, (tuple, list)) or len(got) != 2:
        return problem
    try:
        x = np.asarray(got[0], dtype=float)
    except (TypeError, ValueError):
        return problem
    return problem + _unwrapped(x, case.expected[0])


def _unwrapped(x, want) -> str:
    """' — the yaw is right but not wrapped …' when x equals ``want`` up to whole turns of ψ, else ''."""
    if x.shape == (3,) and np.allclose(wrap_angle(x - want), 0.0, atol=1e-9) and not np.allclose(x, want):
        return f" — the yaw {x[2]:.4f} rad is right but not wrapped to (−π, π]"
    return ""


# --- 04.measurement and 04.jacobian -------------------------------------------------------------


def _measurement_cases(rng):
    cases = [
        Case(
            {"x": np.zeros(3), "field_n": np.array(MAG_FIELD_LONDON)},
            attitude_measurement(np.zeros(3), MAG_FIELD_LONDON),
            "measurement(level, facing north, London)",
        )
    ]
    for _ in range(11):
        x, m = _random_state(rng), _random_field(rng)
        cases.append(Case({"x": x, "field_n": m}, attitude_measurement(x, m)))
    return cases


def finite_difference_jacobian(h, x, step=1e-6):
    """∂h/∂x by central differences, (h(x + δeⱼ) − h(x − δeⱼ)) / 2δ, column by column."""
    x = np.asarray(x, dtype=float)
    columns = []
    for j in range(len(x)):
        d = np.zeros_like(x)
        d[j] = step
        columns.append((np.asarray(h(x + d)) - np.asarray(h(x - d))) / (2 * step))
    return np.column_stack(columns)


def _jacobian_cases(rng):
    cases = []
    for i in range(12):
        x = np.zeros(3) if i == 0 else _random_state(rng)
        m = np.array(MAG_FIELD_LONDON) if i == 0 else _random_field(rng)
        cases.append(Case({"x": x, "field_n": m}, attitude_jacobian(x, m)))
    return cases


def _judge_jacobian(case, got):
    """Against finite differences of kfkit's h(x) (any correct H passes); names the wrong column."""
    x, m = case.args["x"], case.args["field_n"]
    fd = finite_difference_jacobian(lambda v: attitude_measurement(v, m), x)
    try:
        H = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return f"expected a 6×3 array, got {type(got).__name__}"
    if H.shape != (6, 3):
        return f"expected shape (6, 3), got shape {H.shape}"
    bad = ~np.isclose(H, fd, rtol=1e-5, atol=1e-5)
    if not bad.any():
        return None
    where = []
    for j in np.flatnonzero(bad.any(axis=0)):
        parts = [
            part
            for part, rows in (("accelerometer rows", slice(0, 3)), ("magnetometer rows", slice(3, 6)))
            if bad[rows, j].any()
        ]
        where.append(f"∂h/∂{'φθψ'[j]} ({', '.join(parts)})")
    first = int(np.flatnonzero(bad.any(axis=0))[0])
    return (
        f"columns {'; '.join(where)} differ from finite differences of h: "
        f"expected {fmt(fd[:, first])}, got {fmt(H[:, first])}"
    )


# --- 04.numerical_jacobian --------------------------------------------------------------------

#: the first cases: h_i(x) = b_i + a_iᵀx + ½ xᵀC_i x with curvatures C of this size, judged this tightly. A central
#: difference is exact on a quadratic (its error is ε²·h‴/6 and h‴ = 0), up to rounding (≈ 1e-16·|h|/ε: 1e-10 at
#: ε = 1e-6); a one-sided difference is off by ε·C_jj/2, which no step ε brings below the tolerance: 5e-6 at ε = 1e-8
#: (where rounding is already 1e-8), 5e-4 at 1e-6.
QUADRATIC, QUADRATIC_CURVATURE, QUADRATIC_TOL = "a quadratic h(x)", 1e3, 1e-7


def _quadratic(rng):
    """A random h(x) = b + A x + ½ [xᵀC_i x]_i (4 outputs, 3 inputs), a point x near 0 (|h| ≈ 1: small rounding)
    and its Jacobian A + [C_i x]_i."""
    A, b = rng.normal(0.0, 1.0, (4, 3)), rng.normal(0.0, 1.0, 4)
    C = rng.normal(0.0, QUADRATIC_CURVATURE, (4, 3, 3))
    C = C + np.swapaxes(C, 1, 2)
    x = rng.normal(0.0, 1e-3, 3)
    return (lambda v: b + A @ v + 0.5 * np.einsum("i,kij,j->k", v, C, v)), x, A + C @ x


def _numerical_jacobian_cases(rng):
    cases = []
    for i in range(4):
        h, x, jac = _quadratic(rng)
        cases.append(
            Case(
                {"h": h, "x": x},
                jac,
                f"{QUADRATIC} = b + A x + ½ xᵀC x (case {i + 1}), on which a central difference is exact",
            )
        )
    for _ in range(8):
        x, m = _random_state(rng), _random_field(rng)
        cases.append(
            Case(
                {"h": (lambda v, m=m: attitude_measurement(v, m)), "x": x},
                attitude_jacobian(x, m),
                f"kfkit's attitude h(x) at x = {fmt(x)}",
            )
        )
    return cases


def one_sided_step(h, x, difference, delta=1e-3):
    """The step ε with which a one-sided difference of ``h`` at ``x`` is off by ``difference`` (got − the Jacobian,
    m × n): (h(x + εe_j) − h(x))/ε − ∂h/∂x_j ≈ (ε/2)·∂²h/∂x_j², one ε for every entry (the second derivatives by
    central second differences with step ``delta``); None if ``difference`` does not have that shape."""
    x = np.asarray(x, dtype=float)
    h0 = np.asarray(h(x), dtype=float)
    curvature = np.column_stack(
        [
            (np.asarray(h(x + e), float) - 2 * h0 + np.asarray(h(x - e), float)) / delta**2
            for e in np.eye(len(x)) * delta
        ]
    )
    pattern = 0.5 * curvature
    if not np.any(pattern):
        return None
    eps = float(np.sum(difference * pattern) / np.sum(pattern * pattern))
    return eps if np.linalg.norm(difference - eps * pattern) <= 0.1 * np.linalg.norm(difference) else None


def _judge_numerical_jacobian(case, got):
    tol = QUADRATIC_TOL if case.label.startswith(QUADRATIC) else 1e-5
    problem = compare(case.expected, got, rtol=tol, atol=tol)
    if problem is None or structural(problem):
        return problem and problem + " — one row per output of h, one column per state"
    eps = one_sided_step(case.args["h"], case.args["x"], np.asarray(got, dtype=float) - case.expected)
    if eps is not None:
        return (
            problem + f" — a one-sided difference (h(x {'+' if eps > 0 else '−'} ε eⱼ) − h(x))/(±ε), "
            f"ε ≈ {abs(eps):.1g}: its error ε·h″/2 falls only as ε does, until rounding stops it; the "
            "central difference's ε²·h‴/6 is far smaller"
        )
    return problem


# --- 04.update --------------------------------------------------------------------------------


def _about_down(angle):
    """Rz(angle): a turn about the NED down axis."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _update_cases(rng):
    """Random updates; the first two are turned about the vertical so that the update's yaw step δ crosses ±180°
    whatever the seed: turning the prior's and the truth's yaw and the field m_n by the same angle s leaves the
    update unchanged (R_bn(ψ + s)·Rz(s) m_n = R_bn(ψ) m_n), so with ψ = ±π − δ/2 the new yaw lands at ±π + δ/2."""
    cases = []
    for i in range(12):
        x_true, m = _random_state(rng), _random_field(rng)
        x = x_true + rng.normal(0.0, np.radians(3.0), 3)
        if i < 2:
            x[2] = x_true[2] - (1 if i == 0 else -1) * np.radians(3.0)
        x[2] = wrap_angle(x[2])
        P = _random_cov(rng, 3, np.radians(rng.uniform(1.0, 5.0)))
        sa, sm = rng.uniform(0.05, 0.5), rng.uniform(0.3, 2.0)
        noise = rng.normal(0.0, 1.0, 6) * np.r_[[sa] * 3, [sm] * 3]
        R = np.diag([sa**2] * 3 + [sm**2] * 3)
        if i < 2:
            z = attitude_measurement(x_true, m) + noise
            step = wrap_angle(euler_ekf_update(x, P, z, R, m)[0][2] - x[2])
            turn = np.sign(step) * np.pi - step / 2 - x[2]
            x[2], x_true[2], m = wrap_angle(x[2] + turn), x_true[2] + turn, _about_down(turn) @ m
        z = attitude_measurement(x_true, m) + noise
        if i % 3 == 2:
            z[3:] = np.nan  # no new magnetometer sample
        args = {"x": x, "P": P, "z": z, "R": R, "field_n": m}
        label = f"a{' magnetometer-less (NaN)' if i % 3 == 2 else ''} update at x = {fmt(x)}" + (
            " (the yaw crosses ±180°)" if i < 2 else ""
        )
        cases.append(Case(args, euler_ekf_update(**args), label))
    return cases


def _judge_update(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-9)
    if problem is None or not isinstance(got, (tuple, list)) or len(got) != 4:
        return problem
    try:
        return problem + _unwrapped(np.asarray(got[0], dtype=float), case.expected[0])
    except (TypeError, ValueError):
        return problem


# --- 04.ekf_rmse ------------------------------------------------------------------------------


def _rmse_cases(rng):
    rec, gyr, acc, mag = bundled_inputs()
    tuning = EulerAttitudeEKFSettings()  # the lab's defaults
    args = {
        "gyr": gyr,
        "acc": acc,
        "mag": mag,
        "rate_hz": rec.rate_hz,
        "gyro_noise": tuning.gyro_noise,
        "accel_noise": tuning.accel_noise,
        "mag_noise": tuning.mag_noise,
        "field_n": np.array(MAG_FIELD_LONDON),
    }
    tilt_bias = EXTRA_BIAS * np.r_[rng.choice([-1.0, 1.0], 2), 0.0]
    heading_bias = EXTRA_BIAS * np.r_[0.0, 0.0, rng.choice([-1.0, 1.0])]
    pushed, _ = accelerated(acc, rec.truth(), rec.t, rng)
    w, f, m, turns_truth = noise_free_turns(rng)
    turns = dict(args, gyr=w, acc=f, mag=m, rate_hz=104.0)
    truth = rec.truth()

    def biased(bias):
        shown = ", ".join(f"{v:+.1f}" for v in np.degrees(bias))
        return f"{RECORDING} with an extra gyro bias of ({shown}) °/s the filter does not know about"

    return [
        Case(args, (truth, RMSE_LIMITS, ""), f"the bundled recording {RECORDING} (calibrated)"),
        Case(dict(args, gyr=gyr + tilt_bias), (truth, BIASED_RMSE_LIMITS, TILT_ADVICE), biased(tilt_bias)),
        Case(dict(args, gyr=gyr + heading_bias), (truth, BIASED_RMSE_LIMITS, HEADING_ADVICE), biased(heading_bias)),
        Case(
            dict(args, acc=pushed, accel_gate=ACCEL_GATE),
            (truth, RMSE_LIMITS, GATE_ADVICE),
            f"{RECORDING} with {BURSTS} bursts of {BURST_ACCEL:g} m/s² linear acceleration and accel_gate = "
            f"{ACCEL_GATE:g} m/s²",
        ),
        Case(
            turns,
            (turns_truth, TURN_RMSE_LIMITS, TURN_ADVICE),
            f"{TURNS} fast turns (up to 6 rad/s) seen by noise-free sensors",
        ),
    ]


def _estimate(got, rows):
    """The (rows, 3) float array x of run_ekf's answer (x, P, nis), or (None, what is wrong with it)."""
    try:
        x = np.asarray(got[0] if isinstance(got, (tuple, list)) else got, dtype=float)
    except (TypeError, ValueError):
        return None, f"expected (x, P, nis) with x of shape (N, 3), got {type(got).__name__}"
    if x.shape != (rows, 3):
        return None, f"expected {rows} rows of [roll, pitch, yaw] (shape {(rows, 3)}), got shape {x.shape}"
    if not np.isfinite(x).all():
        return None, f"the estimate holds NaN or inf from row {int(np.argmax(~np.isfinite(x).all(axis=1)))}"
    return x, None


def _judge_rmse(case, got):
    truth, limits, advice = case.expected
    x, problem = _estimate(got, len(truth))
    if x is None:
        return problem
    err = rmse(angle_error(x, truth), 0.0)
    over = [
        f"{name} RMSE {np.degrees(e):.2g}° (limit {np.degrees(lim):.2g}°)"
        for name, e, lim in zip(ANGLES, err, limits)
        if not e < lim
    ]
    return None if not over else "; ".join(over + [advice] * bool(advice))


register(
    Checkpoint(
        "04.euler_rates",
        "euler_rates",
        _euler_rates_cases,
        _judge_euler_rates,
        points=1,
        hint="φ̇ = p + (q sin φ + r cos φ) tan θ, θ̇ = q cos φ − r sin φ, ψ̇ = (q sin φ + r cos φ)/cos θ: "
        "it is the pitch θ that makes Euler angles singular.",
    ),
    Checkpoint(
        "04.predict",
        "ekf_predict",
        _predict_cases,
        _judge_predict,
        points=2,
        hint="x⁻ = x + f(x, ω)·dt with ψ wrapped to (−π, π]; P⁻ = F P Fᵀ + Q with F = I + dt·A and A the "
        "Jacobian ∂f/∂x given above (its third column is zero). Return (x, P).",
    ),
    Checkpoint(
        "04.measurement",
        "measurement",
        _measurement_cases,
        matches(),
        points=1,
        hint="h = [R_bn·(0, 0, −g); R_bn·m_n] with R_bn = R_nbᵀ and R_nb = Rz(ψ) Ry(θ) Rx(φ) "
        "(frames.euler_to_dcm); level and facing north it is [0, 0, −g, m_N, m_E, m_D].",
    ),
    Checkpoint(
        "04.jacobian",
        "jacobian",
        _jacobian_cases,
        _judge_jacobian,
        points=2,
        what="random states",
        hint="column j is ∂h/∂xⱼ; the accelerometer rows do not depend on ψ (gravity is vertical), and "
        "∂R_bn/∂ψ = (∂R_nb/∂ψ)ᵀ — compare your columns one by one with numerical_jacobian.",
    ),
    Checkpoint(
        "04.numerical_jacobian",
        "numerical_jacobian",
        _numerical_jacobian_cases,
        _judge_numerical_jacobian,
        points=1,
        hint="column j is (h(x + ε eⱼ) − h(x − ε eⱼ)) / 2ε, the central difference the lab asks for (a "
        "one-sided difference fails the quadratic cases); with ε around 1e-6 both rounding and "
        "truncation errors stay below 1e-8.",
    ),
    Checkpoint(
        "04.update",
        "ekf_update",
        _update_cases,
        _judge_update,
        points=2,
        hint="y = z − h(x), S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x + K y (ψ wrapped), P = (I − K H) P; "
        "with NaN in z[3:] keep only the first three rows of z, h, H and R. Return (x, P, y, S).",
    ),
    Checkpoint(
        "04.ekf_rmse",
        "run_ekf",
        _rmse_cases,
        _judge_rmse,
        points=2,
        what="runs on the bundled recording",
        hint="initialise from the first accelerometer and magnetometer samples, then predict with every gyro "
        "sample (the step from t_{k−1} to t_k with ½(ω_{k−1} + ω_k)) and update with every accelerometer sample, "
        "adding "
        "the magnetometer rows whenever a new magnetometer sample arrived; if 04.predict and 04.update pass, "
        "look at dt, Q and R.",
    ),
)
