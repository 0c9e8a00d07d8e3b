"""Checkpoints of lab 04 (attitude with an Euler-angle EKF).

Every expected value comes from kfkit's reference (:mod:`kfkit.filters.euler_ekf`); the
Jacobian is judged against central finite differences of kfkit's h(x), so any correct H passes.
``04.real_ekf`` runs the student's filter on a real recording (BROAD trial 06, bundled): its bar is
kfkit's result on the same samples plus the error of the optical truth itself, measured at rest.
"""
from __future__ import annotations

import numpy as np

from .. import datasets
from ..calibration import Calibration, calibration_for, gyro_bias
from ..filters.euler_ekf import (EulerAttitudeEKFSettings, attitude_jacobian, attitude_measurement, euler_ekf_predict,
                                 euler_ekf_update, euler_process_noise)
from ..filters.attitude_run import learn_field
from ..filters.euler_ekf_fast import FastEulerAttitudeEKF
from ..frames import MAG_FIELD_LONDON, body_rates_to_euler_rates, euler_to_dcm, euler_to_quat, wrap_angle
from ..metrics import angle_error, attitude_rmse, rmse
from . import Case, Checkpoint, compare, fmt, matches, register, structural

RECORDING = "04_attitude_tour"
#: the full filter must reach these RMSEs on the bundled recording (rad): roll, pitch, yaw
RMSE_LIMITS = np.radians([1.0, 1.0, 2.0])
#: … and, with a gyro bias it was not told about, these: the calibrated gyro alone stays within the
#: limits above on this recording, so this case is the one that shows the updates are at work
#: (kfkit's reference: 1.4°, 1.1°, 2.8°; the gyro alone: 9.2°, 8.0°, 5.6°)
EXTRA_GYRO_BIAS = np.radians([0.3, -0.3, 0.2])
BIASED_RMSE_LIMITS = np.radians([3.0, 3.0, 5.0])
ANGLES = ("roll", "pitch", "yaw")


def _random_state(rng, max_pitch=np.radians(80.0)):
    return np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-max_pitch, max_pitch), rng.uniform(-np.pi, np.pi)])


def _random_field(rng):
    """A plausible Earth field in NED, µT: horizontal 15–35, down −50…60 (either hemisphere)."""
    h, dec = rng.uniform(15.0, 35.0), rng.uniform(-0.3, 0.3)
    return np.array([h * np.cos(dec), h * np.sin(dec), rng.uniform(-50.0, 60.0)])


def _random_cov(rng, n, scale):
    A = rng.normal(0.0, scale, (n, n))
    return A @ A.T + np.eye(n) * scale ** 2


# --- 04.euler_rates ---------------------------------------------------------------------------

def _euler_rates_cases(rng):
    cases = [Case({"euler": np.array([0.3, 0.0, 0.0]), "omega_b": np.array([0.0, 0.0, 0.5])},
                  body_rates_to_euler_rates([0.3, 0.0, 0.0], [0.0, 0.0, 0.5]), "euler_rates(φ = 17°, θ = 0, r = 0.5 rad/s)")]
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
    if np.allclose(g[:2], case.expected[:2]) and np.isclose(g[2], u / np.cos(phi)) and not np.isclose(np.cos(phi), np.cos(theta)):
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
    cases = [Case({"x": np.zeros(3), "field_n": np.array(MAG_FIELD_LONDON)},
                  attitude_measurement(np.zeros(3), MAG_FIELD_LONDON), "measurement(level, facing north, London)")]
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
        parts = [part for part, rows in (("accelerometer rows", slice(0, 3)), ("magnetometer rows", slice(3, 6)))
                 if bad[rows, j].any()]
        where.append(f"∂h/∂{'φθψ'[j]} ({', '.join(parts)})")
    first = int(np.flatnonzero(bad.any(axis=0))[0])
    return (f"columns {'; '.join(where)} differ from finite differences of h: "
            f"expected {fmt(fd[:, first])}, got {fmt(H[:, first])}")


# --- 04.numerical_jacobian --------------------------------------------------------------------

def _numerical_jacobian_cases(rng):
    cases = []
    for i in range(4):
        A, b = rng.normal(0.0, 3.0, (4, 3)), rng.normal(0.0, 1.0, 4)
        x = rng.normal(0.0, 1.0, 3)
        cases.append(Case({"h": (lambda v, A=A, b=b: A @ v + b), "x": x}, A, f"a linear h(x) = A x + b (4×3, case {i + 1})"))
    for i in range(8):
        x, m = _random_state(rng), _random_field(rng)
        cases.append(Case({"h": (lambda v, m=m: attitude_measurement(v, m)), "x": x}, attitude_jacobian(x, m),
                          f"kfkit's attitude h(x) at x = {fmt(x)}"))
    return cases


def _judge_numerical_jacobian(case, got):
    problem = compare(case.expected, got, rtol=1e-5, atol=1e-5)
    if problem is not None and "shape" in problem:
        return problem + " — one row per output of h, one column per state"
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
        R = np.diag([sa ** 2] * 3 + [sm ** 2] * 3)
        if i < 2:
            z = attitude_measurement(x_true, m) + noise
            step = wrap_angle(euler_ekf_update(x, P, z, R, m)[0][2] - x[2])
            turn = np.sign(step) * np.pi - step / 2 - x[2]
            x[2], x_true[2], m = wrap_angle(x[2] + turn), x_true[2] + turn, _about_down(turn) @ m
        z = attitude_measurement(x_true, m) + noise
        if i % 3 == 2:
            z[3:] = np.nan  # no new magnetometer sample
        args = {"x": x, "P": P, "z": z, "R": R, "field_n": m}
        label = (f"a{' magnetometer-less (NaN)' if i % 3 == 2 else ''} update at x = {fmt(x)}"
                 + (" (the yaw crosses ±180°)" if i < 2 else ""))
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

def bundled_inputs():
    """Lab 04's inputs: the bundled recording corrected with the calibration that belongs to it, the
    bundled unit's (:func:`kfkit.calibration.calibration_for`; the student's own file is not used, so
    every grader agrees).

    Returns (recording, gyr rad/s, acc m/s², mag µT), body frame.
    """
    rec = datasets.load(RECORDING)
    gyr, acc, mag = calibration_for(rec).apply(rec)
    return rec, gyr, acc, mag


#: The gated run: the recording with BURSTS horizontal accelerations of BURST_ACCEL m/s² for BURST_SECONDS each
#: (random start and direction), judged at the plain limits with ``accel_gate`` = ACCEL_GATE. A horizontal a
#: tilts the measured specific force by atan(a/g) = 31° and lengthens it by √(g² + a²) − g = 1.7 m/s² > the gate,
#: so a gated filter rides the bursts on the gyro (kfkit: ≤ 0.3° RMSE on every angle), while a filter that ignores
#: ``accel_gate`` follows the tilted force (1.5–4° roll/pitch, 5–8° yaw RMSE over 50 seeds).
BURSTS, BURST_ACCEL, BURST_SECONDS, ACCEL_GATE = 4, 6.0, 2.0, 1.0


def accelerated(acc, truth, t, rng):
    """``acc`` plus the specific force R_bn·a_n of BURSTS horizontal accelerations a_n (NED), and their mask."""
    a_n, during = np.zeros_like(acc), np.zeros(len(t), bool)
    slots = np.linspace(t[0] + 3.0, t[-1] - 3.0 - BURST_SECONDS, BURSTS + 1)
    for t0, t1 in zip(slots[:-1], slots[1:]):
        start = rng.uniform(t0, t1 - BURST_SECONDS)
        w = (t >= start) & (t < start + BURST_SECONDS)
        heading = rng.uniform(-np.pi, np.pi)
        a_n[w] = BURST_ACCEL * np.array([np.cos(heading), np.sin(heading), 0.0])
        during |= w
    R_bn = np.swapaxes(euler_to_dcm(truth), -1, -2)
    return acc + np.einsum("nij,nj->ni", R_bn, a_n), during


def _rmse_cases(rng):
    rec, gyr, acc, mag = bundled_inputs()
    tuning = EulerAttitudeEKFSettings()  # the lab's defaults
    args = {"gyr": gyr, "acc": acc, "mag": mag, "rate_hz": rec.rate_hz, "gyro_noise": tuning.gyro_noise,
            "accel_noise": tuning.accel_noise, "mag_noise": tuning.mag_noise, "field_n": np.array(MAG_FIELD_LONDON)}
    biased = dict(args, gyr=gyr + EXTRA_GYRO_BIAS)
    bias = ", ".join(f"{v:+.1f}" for v in np.degrees(EXTRA_GYRO_BIAS))
    pushed, _ = accelerated(acc, rec.truth(), rec.t, rng)
    return [Case(args, (rec.truth(), RMSE_LIMITS), f"the bundled recording {RECORDING} (calibrated)"),
            Case(biased, (rec.truth(), BIASED_RMSE_LIMITS),
                 f"{RECORDING} with an extra gyro bias of ({bias}) °/s the filter does not know about"),
            Case(dict(args, acc=pushed, accel_gate=ACCEL_GATE), (rec.truth(), RMSE_LIMITS),
                 f"{RECORDING} with {BURSTS} bursts of {BURST_ACCEL:g} m/s² linear acceleration and accel_gate = "
                 f"{ACCEL_GATE:g} m/s²")]


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
    truth, limits = case.expected
    x, problem = _estimate(got, len(truth))
    if x is None:
        return problem
    err = rmse(angle_error(x, truth), 0.0)
    over = [f"{name} RMSE {np.degrees(e):.2f}° (limit {np.degrees(lim):.0f}°)"
            for name, e, lim in zip(ANGLES, err, limits) if not e < lim]
    if over and limits is BIASED_RMSE_LIMITS:
        over.append("the gyro alone drifts like this: are the accelerometer and magnetometer updates applied?")
    if over and case.args.get("accel_gate") is not None:
        over.append("the filter follows the accelerated specific force: where |‖f‖ − g| > accel_gate, is R's "
                    "accelerometer block inflated?")
    return None if not over else "; ".join(over)


# --- 04.real_ekf ------------------------------------------------------------------------------

#: the real recording judged (BROAD trial 06) and how much of it: the whole first rest (where the gyro bias and the
#: field are learned), then the first REAL_MOVING_SECONDS of rotations by hand, up to 7 rad/s and 77° of pitch (the
#: fast part after them, up to 16 rad/s, breaks every Euler EKF at 100 Hz and is shown, not judged)
REAL_RECORDING, REAL_MOVING_SECONDS = "04_broad_fast_rotation", 30.0
#: the part of the first rest the truth's own error is measured on (s): before anything moves
TRUTH_CHECK_SECONDS = 10.0


def rest_calibration(rec) -> Calibration:
    """A BROAD recording's calibration: the dataset comes calibrated by its authors, but its gyro keeps a
    bias, measured as in lab 02: the mean rate over the first rest (rad/s); nothing else is corrected."""
    first_rest = rec.phase("rest") & (rec.t < rec.phases[0]["end"])
    return Calibration(board=rec.meta["board"], rate_hz=rec.rate_hz, gyro_bias=gyro_bias(rec.body("gyr")[first_rest]),
                       source=f"{rec.meta['source']}: calibrated by its authors; gyro bias = mean of the first rest")


def movement_start(rec) -> float:
    """When the recording's first movement phase starts (s from its first sample)."""
    moving = rec.phase("movement")
    if not moving.any():
        raise ValueError(f"recording {rec.path or ''}: its 'movement' phase holds no sample")
    return float(rec.t[np.argmax(moving)] - rec.t[0])


def real_inputs(name=REAL_RECORDING, seconds=None, moving_seconds=None):
    """A bundled BROAD excerpt as lab 04 uses it: (recording, gyr rad/s, acc m/s², mag µT, field_n µT NED
    learned at the start (magnetic north, as the truth's), truth quaternions body → NED (NaN where the
    markers were not seen), BROAD's movement mask); only the first ``seconds`` if given, or only up to
    ``moving_seconds`` after the first movement starts (the whole first rest kept)."""
    rec = datasets.load(name)
    if moving_seconds is not None:
        seconds = movement_start(rec) + moving_seconds
    rec = rec if seconds is None else rec.head(seconds)
    gyr, acc, mag = rest_calibration(rec).apply(rec)
    return rec, gyr, acc, mag, learn_field(acc, mag), euler_to_quat(rec.truth()), rec.phase("movement")


def truth_error_at_rest(rec, acc, mag, seconds=TRUTH_CHECK_SECONDS):
    """How far the optical truth itself is from what the IMU senses, before anything moves (rad): the angle
    between the accelerometer's "down" and the truth's (the sensor-to-marker alignment, the accelerometer's
    bias) and the heading of the measured field in the truth's frame (the truth's north against the
    magnetometer's, which is the filter's), combined as √(inclination² + heading²)."""
    still = (rec.t - rec.t[0] < seconds) & rec.phase("rest") & ~np.isnan(rec["true_roll"])
    R_nb = euler_to_dcm(rec.truth()[still])
    f_n = np.einsum("nij,nj->ni", R_nb, acc[still]).mean(axis=0)
    m_n = np.einsum("nij,nj->ni", R_nb, mag[still]).mean(axis=0)
    return float(np.hypot(np.arccos(-f_n[2] / np.linalg.norm(f_n)), np.arctan2(m_n[1], m_n[0])))


def _real_cases(rng):
    """One case: the real recording's first rest and REAL_MOVING_SECONDS of movement, with the lab's tuning and gate.
    The bar is kfkit's Euler EKF (the same equations, settings and start) on the same samples, plus the truth's own
    error at rest: a filter that is right reproduces the reference, so its error against this truth can exceed the
    reference's only by what the truth cannot resolve."""
    rec, gyr, acc, mag, field_n, q_true, moving = real_inputs(moving_seconds=REAL_MOVING_SECONDS)
    tuning = EulerAttitudeEKFSettings()
    args = {"gyr": gyr, "acc": acc, "mag": mag, "rate_hz": rec.rate_hz, "gyro_noise": tuning.gyro_noise,
            "accel_noise": tuning.accel_noise, "mag_noise": tuning.mag_noise, "field_n": field_n,
            "accel_gate": ACCEL_GATE}
    reference = FastEulerAttitudeEKF(rate_hz=rec.rate_hz, settings=tuning, field_n=field_n, accel_gate=ACCEL_GATE).run(gyr, acc, mag)
    ref_rmse = attitude_rmse(euler_to_quat(reference.euler), q_true, moving)["total"]
    return [Case(args, (q_true, moving, ref_rmse, truth_error_at_rest(rec, acc, mag)),
                 f"the real recording {REAL_RECORDING} (BROAD trial 06): its {movement_start(rec):.0f} s at rest and "
                 f"the first {REAL_MOVING_SECONDS:g} s of movement")]


def _judge_real(case, got):
    """BROAD's total error over the movement phases within the reference's plus the truth's own error."""
    q_true, moving, ref_rmse, truth_error = case.expected
    x, problem = _estimate(got, len(q_true))
    if x is None:
        return problem
    errors = {k: np.degrees(v) for k, v in attitude_rmse(euler_to_quat(x), q_true, moving).items()}
    limit = np.degrees(ref_rmse + truth_error)
    if errors["total"] <= limit:
        return None
    return (f"total rotation error RMSE {errors['total']:.2f}° over the movement (heading {errors['heading']:.2f}°, "
            f"inclination {errors['inclination']:.2f}°), limit {limit:.2f}° = kfkit's {np.degrees(ref_rmse):.2f}° + "
            f"the truth's own {np.degrees(truth_error):.2f}°")


register(
    Checkpoint("04.euler_rates", "euler_rates", _euler_rates_cases, _judge_euler_rates, points=1,
               hint="φ̇ = p + (q sin φ + r cos φ) tan θ, θ̇ = q cos φ − r sin φ, ψ̇ = (q sin φ + r cos φ)/cos θ: "
                    "it is the pitch θ that makes Euler angles singular."),
    Checkpoint("04.predict", "ekf_predict", _predict_cases, _judge_predict, points=2,
               hint="x⁻ = x + f(x, ω)·dt with ψ wrapped to (−π, π]; P⁻ = F P Fᵀ + Q with F = I + dt·A and A the "
                    "Jacobian ∂f/∂x given above (its third column is zero). Return (x, P)."),
    Checkpoint("04.measurement", "measurement", _measurement_cases, matches(), points=1,
               hint="h = [R_bn·(0, 0, −g); R_bn·m_n] with R_bn = R_nbᵀ and R_nb = Rz(ψ) Ry(θ) Rx(φ) "
                    "(frames.euler_to_dcm); level and facing north it is [0, 0, −g, m_N, m_E, m_D]."),
    Checkpoint("04.jacobian", "jacobian", _jacobian_cases, _judge_jacobian, points=2, what="random states",
               hint="column j is ∂h/∂xⱼ; the accelerometer rows do not depend on ψ (gravity is vertical), and "
                    "∂R_bn/∂ψ = (∂R_nb/∂ψ)ᵀ — compare your columns one by one with numerical_jacobian."),
    Checkpoint("04.numerical_jacobian", "numerical_jacobian", _numerical_jacobian_cases, _judge_numerical_jacobian,
               points=1, hint="column j is (h(x + ε eⱼ) − h(x − ε eⱼ)) / 2ε; with ε around 1e-6 both rounding "
                              "and truncation errors stay below 1e-8."),
    Checkpoint("04.update", "ekf_update", _update_cases, _judge_update,
               points=2, hint="y = z − h(x), S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x + K y (ψ wrapped), P = (I − K H) P; "
                              "with NaN in z[3:] keep only the first three rows of z, h, H and R. Return (x, P, y, S)."),
    Checkpoint("04.ekf_rmse", "run_ekf", _rmse_cases, _judge_rmse, points=2, what="runs on the bundled recording",
               hint="initialise from the first accelerometer and magnetometer samples, then predict with every gyro "
                    "sample and update with every accelerometer sample, adding the magnetometer rows only when a new "
                    "magnetometer sample arrived; if 04.predict and 04.update pass, look at dt, Q and R."),
    Checkpoint("04.real_ekf", "run_ekf", _real_cases, _judge_real, points=1, what="runs on a bundled real recording",
               hint="if 04.ekf_rmse passes, the real recording differs: every row has a magnetometer sample, the "
                    "truth has gaps (NaN), the rotations are fast; run_ekf must take them as they come."),
)
