"""Every checkpoint of every lab, judged with the solutions' own exercise functions as the right answers:
they pass on many seeds; NaN or inf in an answer never scores; each classic mistake (a small edit of the
model answer) fails on every seed, with a message that names it."""

import ast
import contextlib
import dataclasses
import functools
from pathlib import Path

import nbformat
import numpy as np
import pytest

from kfkit.checkpoints import LABS, REGISTRY, get, run_checkpoint, wrap_message

SOLUTIONS = Path(__file__).resolve().parents[1] / "solutions"


def solution_namespace(nn, mutate=None):
    """The imports, constant assignments and functions of solutions/NN_*.ipynb, executed in a fresh namespace
    (nothing that loads data or draws); ``mutate`` = (function, old, new) replaces text in that def first."""
    path = next(SOLUTIONS.glob(f"{nn}_*.ipynb"))
    ns, mutated = {}, False
    for cell in nbformat.read(path, as_version=4).cells:
        if cell.cell_type != "code":
            continue
        src = "\n".join(line for line in cell.source.splitlines() if not line.lstrip().startswith(("%", "!")))
        for node in ast.parse(src).body:
            constant = isinstance(node, ast.Assign) and not any(isinstance(n, ast.Call) for n in ast.walk(node.value))
            if not (constant or isinstance(node, (ast.Import, ast.ImportFrom, ast.FunctionDef))):
                continue
            text = ast.get_source_segment(src, node)
            if mutate and isinstance(node, ast.FunctionDef) and node.name == mutate[0]:
                assert mutate[1] in text, f"{mutate[1]!r} is not in {node.name} of {path.name}"
                text, mutated = text.replace(mutate[1], mutate[2]), True
            with contextlib.suppress(NameError, AttributeError):  # a helper whose default needs the notebook's data
                exec(compile(text, str(path), "exec"), ns)
    assert mutate is None or mutated, f"no function {mutate[0]} in {path.name}"
    return ns


def lab_of(name):
    """The lab a checkpoint belongs to: '04b' for '04b.quat_exp'."""
    return name.split(".")[0]


@functools.cache
def reference(name):
    """The solution notebook's function that checkpoint ``name`` judges."""
    return solution_namespace(lab_of(name))[get(name).function]


def all_checkpoints():
    get("00.checksum")  # imports every lab's module
    return sorted(REGISTRY)


def is_heavy(name):
    """Checkpoints that run a whole filter on bundled recordings (a few seconds each)."""
    return "bundled" in get(name).what or "runs" in get(name).what


@pytest.mark.slow
def test_every_lab_registers_checkpoints_and_each_has_a_model_answer():
    names = all_checkpoints()
    assert {lab_of(n) for n in names} == {lab[3:] for lab in LABS}
    for name in names:
        assert callable(reference(name)), name


@pytest.mark.slow
@pytest.mark.parametrize("name", all_checkpoints())
def test_the_model_answer_passes_on_many_seeds(name):
    for seed in range(2 if is_heavy(name) else 20):
        result = run_checkpoint(get(name), reference(name), seed)
        assert result.ok, (seed, result.message)
        assert result.points == result.max_points > 0


# --- NaN and inf never score ----------------------------------------------------------------------------------


def _poison(value, how, state):
    """``value`` with its numbers made non-finite: 'nan' / 'inf' all of them, 'nan_after_first' all but the first."""
    if isinstance(value, (tuple, list)):
        return type(value)(_poison(v, how, state) for v in value)
    if isinstance(value, dict):
        return {k: _poison(v, how, state) for k, v in value.items()}
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return value
    flat = a.reshape(-1)
    keep = 1 if how == "nan_after_first" and not state["kept"] else 0
    state["kept"] = state["kept"] or keep > 0 and flat.size > 0
    flat[keep:] = np.inf if how == "inf" else np.nan
    state["poisoned"] += flat.size - keep
    return a if a.ndim else float(a)


@functools.cache
def _reference_outputs(name):
    cp = get(name)
    cases = cp.cases(np.random.default_rng(0))
    return cases, [reference(name)(**case.args) for case in cases]


@pytest.mark.slow
@pytest.mark.parametrize("how", ["nan", "inf", "nan_after_first"])
@pytest.mark.parametrize("name", all_checkpoints())
def test_non_finite_answers_never_score(name, how):
    cases, outputs = _reference_outputs(name)
    poisoned = []
    for out in outputs:
        state = {"kept": False, "poisoned": 0}
        poisoned.append((_poison(out, how, state), state["poisoned"]))
    if not any(n for _, n in poisoned):
        pytest.skip("a single number: nothing after the first")  # 'nan' and 'inf' cover it
    answers = iter(p for p, _ in poisoned)
    result = run_checkpoint(dataclasses.replace(get(name), cases=lambda rng: cases), lambda **_: next(answers))
    assert result.status == "failed" and result.points == 0, result.message
    assert ("NaN" if how != "inf" else "inf") in result.message, result.message
    assert "finite" in result.message, result.message


def test_the_non_finite_message_counts_and_locates():
    from kfkit.checkpoints import nonfinite_problem

    x = np.zeros(24_000)
    x[1000:] = np.nan
    assert nonfinite_problem((x, 1.0), (np.zeros(24_000), 1.0)) == (
        "output 1 of 2: 23,000 of 24,000 values are NaN (the first at index 1000): every value must be a finite number"
    )
    assert "inf" in nonfinite_problem(np.array([[1.0, np.inf]]))
    assert nonfinite_problem(np.array([np.nan, 1.0]), np.array([np.nan, 2.0])) is None  # NaN where NaN is expected
    assert nonfinite_problem("2D") is None and nonfinite_problem(None) is None


# --- each classic mistake fails on every seed, and is named ---------------------------------------------------

MISTAKES = [  # (checkpoint, (function, text of the model answer, mistaken text), words in the message, seeds)
    ("00.board_time", ("board_time", "% 2**32", ""), "t_us went", 20),
    (
        "00.board_time",
        ("board_time", "np.concatenate([[0.0], np.cumsum(steps) * 1e-6])", "np.cumsum(steps) * 1e-6"),
        "shape mismatch",
        20,
    ),
    ("01.accel_roll", ("accel_roll", "np.arctan2(-ay, -az)", "np.arctan2(ay, az)"), "exactly 180° off", 20),
    ("01.accel_roll", ("accel_roll", "np.arctan2(-ay, -az)", "np.arctan2(ay, -az)"), "the sign is flipped", 20),
    ("01.accel_roll", ("accel_roll", "np.arctan2(-ay, -az)", "np.arctan2(-az, -ay)"), "arguments are swapped", 20),
    ("01.accel_roll", ("accel_roll", "np.arctan2(-ay, -az)", "np.degrees(np.arctan2(-ay, -az))"), "in degrees", 20),
    ("01.kf_predict", ("kf_predict", "P + q", "P"), "expected", 20),
    (
        "01.fuse_gaussians",
        ("fuse_gaussians", "var = 1.0 / (1.0 / var_prior + 1.0 / r)", "var = var_prior + r"),
        "variances were added",
        20,
    ),
    (
        "01.fuse_gaussians",
        ("fuse_gaussians", "var * (mu_prior / var_prior + z / r)", "(mu_prior + z) / 2"),
        "plain average",
        20,
    ),
    (
        "01.fuse_gaussians",
        ("fuse_gaussians", "var * (mu_prior / var_prior + z / r)", "var * (mu_prior / r + z / var_prior)"),
        "weighted by its own variance",
        20,
    ),
    ("01.fuse_gaussians", ("fuse_gaussians", "z / r), var", "z / r), np.sqrt(var)"), "standard deviation", 20),
    (
        "01.q_for_time_constant",
        ("q_for_time_constant", "return P_prior**2 / (P_prior + r)", "return r * K**2"),
        "small-gain approximation",
        20,
    ),
    (
        "01.q_for_time_constant",
        ("q_for_time_constant", "return P_prior**2 / (P_prior + r)", "return P_prior"),
        "steady prior variance",
        20,
    ),
    (
        "01.q_for_time_constant",
        ("q_for_time_constant", "return P_prior**2 / (P_prior + r)", "return K**2 / (1 - K)"),
        "r is missing",
        20,
    ),
    ("01.q_for_time_constant", ("q_for_time_constant", "K = dt / tau", "K = tau / dt"), "gain between 0 and 1", 20),
    ("01.run_kf", ("run_kf", "roll_acc[k], r)", "roll_acc[k - 1], r)"), "first differs at sample", 20),
    ("01.run_kf", ("run_kf", "xs[k], Ps[k] = x, P", "xs[k], Ps[k] = x, P0"), "P first differs at sample", 20),
    ("01.kf_beats_sensors", ("kf_predict", "P + q", "P"), "is not below a quarter", 1),
    ("02.gyro_bias", ("gyro_bias", "np.mean(gyr, axis=0)", "np.std(gyr, axis=0)"), "spread (std)", 20),
    ("02.gyro_bias", ("gyro_bias", "np.mean(gyr, axis=0)", "np.mean(gyr)"), "all three axes together", 20),
    ("02.noise_std", ("noise_std", "ddof=1", "ddof=0"), "ddof=0", 20),
    (
        "02.accel_bias",
        ("accel_bias", "np.mean(acc, axis=0) - np.asarray(expected)", "np.asarray(expected) - np.mean(acc, axis=0)"),
        "sign is flipped",
        20,
    ),
    ("02.accel_bias", ("accel_bias", " - np.asarray(expected)", ""), "gravity is still in it", 20),
    ("02.allan_deviation", ("allan_deviation", "/ rate_hz\n", "\n"), "θ is not divided by rate_hz", 20),
    ("02.allan_deviation", ("allan_deviation", "(2 * tau**2", "(tau**2"), "the 2 in 1/(2τ²…) is missing", 20),
    ("02.allan_deviation", ("allan_deviation", "(len(theta) - 2 * m)", "(len(theta))"), "changes with τ", 20),
    ("02.allan_deviation", ("allan_deviation", "np.sqrt(np.sum(d**2)", "0 * np.sqrt(np.sum(d**2)"), "every σ is 0", 20),
    (
        "02.sigma_at_rate",
        ("sigma_at_rate", "np.sqrt(rate_to / rate_from)", "np.sqrt(rate_from / rate_to)"),
        "expected",
        20,
    ),
    ("02.q_from_noise_density", ("q_from_noise_density", "N**2 * dt + K**2 * dt**3 / 3", "N**2 * dt"), "K²·Δt³/3", 20),
    ("02.q_from_noise_density", ("q_from_noise_density", "cross = -K**2", "cross = K**2"), "wrong sign", 20),
    (
        "02.q_from_noise_density",
        (
            "q_from_noise_density",
            "return np.array([[angle, cross], [cross, bias]])",
            "return np.diag([N**2 * dt, K**2 * dt])",
        ),
        "no cross term",
        20,
    ),
    ("02.q_from_noise_density", ("q_from_noise_density", "N**2 * dt +", "(N * dt)**2 +"), "per-sample σ", 20),
    ("02.q_from_datasheet", ("q_from_datasheet", "N = arw * DEG / 60", "N = arw"), "used in °/√h", 20),
    ("02.q_from_datasheet", ("q_from_datasheet", "N = arw * DEG / 60", "N = arw * DEG / 3600"), "√h = 60 √s", 20),
    (
        "02.q_from_datasheet",
        ("q_from_datasheet", "K = rrw * DEG / 3600 / 60", "K = bias_instability * DEG / 3600"),
        "bias instability",
        20,
    ),
    (
        "02.q_from_datasheet",
        ("q_from_datasheet", "K = rrw * DEG / 3600 / 60", "K = bias_instability * DEG / 3600 / 60"),
        "bias instability",
        20,
    ),
    (
        "02.q_from_datasheet",
        ("q_from_datasheet", "K = rrw * DEG / 3600 / 60", "K = rrw * DEG / 3600"),
        "not from /√h",
        20,
    ),
    (
        "02.gyro_bias_recording",
        ("gyro_bias", "np.mean(gyr, axis=0)", "np.mean(gyr[:100], axis=0)"),
        "use the whole rest",
        1,
    ),
    (
        "02.gyro_bias_recording",
        ("gyro_bias", "np.mean(gyr, axis=0)", "np.mean(gyr[-1000:], axis=0)"),
        "use the whole rest",
        1,
    ),
    ("03.counts_to_ut", ("counts_to_ut", "* 100.0", ""), "1 gauss = 100 µT", 20),
    (
        "03.alignment",
        ("alignment_from_turns", "np.sign(np.sum(g * m))", "np.round(np.sum(m) / np.sum(g))"),
        "expected",
        100,
    ),
    ("03.alignment", ("alignment_from_turns", "np.sign(np.sum(g * m))", "np.sign(np.sum(m))"), "expected", 100),
    (
        "03.mag_calibration",
        ("mag_calibration", "(V * np.sqrt(w))", "(V / np.sqrt(w))"),
        "inverse of the correction",
        10,
    ),
    ("03.mag_calibration", ("mag_calibration", "S = field_norm / scale *", "S = 1 / scale *"), "scale S by B", 10),
    ("03.flat_heading", ("flat_heading", "np.arctan2(-m_b[1], m_b[0])", "np.arctan2(m_b[1], m_b[0])"), "wrong way", 20),
    ("03.flat_heading", ("flat_heading", "np.arctan2(-m_b[1], m_b[0])", "np.arctan2(m_b[0], -m_b[1])"), "swapped", 20),
    ("03.tilt_heading", ("tilt_heading", "np.arctan2(-my_h, mx_h)", "np.arctan2(my_h, -mx_h)"), "exactly 180° off", 20),
    (
        "03.tilt_heading",
        (
            "tilt_heading",
            "frames.wrap_angle(np.arctan2(-my_h, mx_h) + declination)",
            "np.arctan2(-my_h, mx_h) + declination",
        ),
        "not wrapped",
        100,
    ),
    (
        "03.tilt_heading",
        ("tilt_heading", "mx, my, mz = m_b[..., 0], m_b[..., 1], m_b[..., 2]", "mx, my, mz = m_b"),
        "(25, 3)",
        20,
    ),
    (
        "03.hard_iron_budget",
        ("hard_iron_budget_ut", "np.hypot(field_ned[0], field_ned[1])", "np.linalg.norm(field_ned)"),
        "not the whole field",
        20,
    ),
    (
        "03.hard_iron_budget",
        ("hard_iron_budget_ut", "np.hypot(field_ned[0], field_ned[1])", "abs(field_ned[0])"),
        "the east component",
        20,
    ),
    ("03.hard_iron_budget", ("hard_iron_budget_ut", "np.sin(np.radians(", "np.tan(np.radians("), "not tan ε", 20),
    (
        "03.hard_iron_budget",
        ("hard_iron_budget_ut", "np.sin(np.radians(max_error_deg))", "np.sin(max_error_deg)"),
        "convert it to radians",
        20,
    ),
    ("04.euler_rates", ("euler_rates", "u / np.cos(theta)])", "u / np.cos(phi)])"), "divided by cos φ", 20),
    (
        "04.euler_rates",
        ("euler_rates", "return np.array([p + u * np.tan(theta)", "return np.array(omega_b)\n    ([p"),
        "body rates p, q, r unchanged",
        20,
    ),
    ("04.predict", ("ekf_predict", "x_new[2] = frames.wrap_angle(x_new[2])", ""), "not wrapped", 100),
    ("04.predict", ("ekf_predict", "F @ P @ F.T + Q", "F.T @ P @ F + Q"), "expected", 20),
    ("04.measurement", ("measurement", "frames.euler_to_dcm(x).T", "frames.euler_to_dcm(x)"), "expected", 20),
    ("04.jacobian", ("jacobian", "return H", "return H.T"), "expected shape (6, 3), got shape (3, 6)", 20),
    ("04.update", ("ekf_update", "x_new[2] = frames.wrap_angle(x_new[2])", ""), "not wrapped", 100),
    ("04.update", ("ekf_update", "if np.isnan(z[3:]).any() else slice(0, 6)", "if False else slice(0, 6)"), "NaN", 20),
    ("04.ekf_rmse", ("run_ekf", "if accel_gate is not None and", "if False and"), "accel_gate", 2),
    (
        "04b.quat_exp",
        (
            "quat_exp",
            "np.concatenate([[np.cos(theta / 2)], np.sin(theta / 2) * rotvec / theta])",
            "np.concatenate([np.sin(theta / 2) * rotvec / theta, [np.cos(theta / 2)]])",
        ),
        "scalar is last",
        20,
    ),
    (
        "04b.quat_exp",
        (
            "quat_exp",
            "np.concatenate([[np.cos(theta / 2)], np.sin(theta / 2) * rotvec / theta])",
            "np.concatenate([[1.0], rotvec / 2])",
        ),
        "not a unit quaternion",
        20,
    ),
    (
        "04b.quat_exp",
        ("quat_exp", "0.5 * (np.asarray(omega_prev) + np.asarray(omega)) * dt", "np.asarray(omega) * dt"),
        "use the midpoint rate",
        20,
    ),
    ("04b.mekf_predict", ("mekf_predict", "frames.quat_multiply(q, dq)", "frames.quat_multiply(dq, q)"), "δq ⊗ q", 20),
    ("04b.mekf_predict", ("mekf_predict", "F[:3, 3:] = -np.eye(3) * dt", ""), "the bias is left out of F", 20),
    (
        "04b.mekf_predict",
        (
            "mekf_predict",
            "F[:3, :3] = frames.quat_to_dcm(dq).T\n    F[:3, 3:] = -np.eye(3) * dt",
            "F[:3, 3:] = -frames.quat_to_dcm(q) * dt",
        ),
        "global (NED) frame",
        20,
    ),
    (
        "04b.accel_jacobian",
        ("accel_jacobian", "frames.cross_matrix(f_b)", "frames.quat_to_dcm(q).T @ frames.cross_matrix(UP_N)"),
        "global (NED) frame",
        20,
    ),
    (
        "04b.accel_jacobian",
        ("accel_jacobian", "frames.cross_matrix(f_b)", "-frames.cross_matrix(f_b)"),
        "sign is flipped",
        20,
    ),
    (
        "04b.mekf_reset",
        (
            "mekf_reset",
            "frames.quat_multiply(q, dq / np.linalg.norm(dq))",
            "frames.quat_multiply(dq / np.linalg.norm(dq), q)",
        ),
        "δq ⊗ q",
        20,
    ),
    ("04b.mekf_reset", ("mekf_reset", "dq / np.linalg.norm(dq)", "dq"), "not a unit quaternion", 20),
    ("04b.mekf_reset", ("mekf_reset", "J @ P @ J.T", "P"), "not turned by the reset", 20),
    (
        "04b.mekf_update",
        (
            "mekf_update",
            "return mekf_reset(q, b, (np.eye(6) - K @ H) @ P, K @ y)",
            "return q, b, (np.eye(6) - K @ H) @ P",
        ),
        "(the reset)",
        20,
    ),
    (
        "04b.mekf_update",
        ("accel_jacobian", "frames.cross_matrix(f_b)", "frames.quat_to_dcm(q).T @ frames.cross_matrix(UP_N)"),
        "expected",
        20,
    ),
    (
        "04.ekf_rmse",
        (
            "run_ekf",
            "np.concatenate([acc[k], mag[k]])",
            "np.concatenate([acc[k], mag[k] if k < 2 else np.nan * mag[k]])",
        ),
        "every new magnetometer sample must be used",
        2,
    ),  # issue 26 §7: only the first magnetometer sample
    (
        "04.ekf_rmse",
        ("run_ekf", "omega = gyr[0] if k == 0 else 0.5 * (gyr[k - 1] + gyr[k])", "omega = gyr[k]"),
        "½(ω_{k−1} + ω_k)",
        2,
    ),  # issue 25 §1: the sample at the step's end
    (
        "04.numerical_jacobian",
        (
            "numerical_jacobian",
            "(np.asarray(h(x + step)) - np.asarray(h(x - step))) / (2 * eps)",
            "(np.asarray(h(x + step)) - np.asarray(h(x))) / eps",
        ),
        "a one-sided difference",
        20,
    ),
    (
        "04.numerical_jacobian",
        (
            "numerical_jacobian",
            "(np.asarray(h(x + step)) - np.asarray(h(x - step))) / (2 * eps)",
            "(np.asarray(h(x)) - np.asarray(h(x - step))) / eps",
        ),
        "a one-sided difference",
        20,
    ),
    ("04.nis_per_row", ("nis_per_row", ".mean() / len(rows)", ".mean()"), "not divided by the number of rows", 20),
    (
        "04.nis_per_row",
        (
            "nis_per_row",
            "return metrics.nis(y_r, S_r).mean() / len(rows)",
            "return np.mean(np.sum(y_r**2 / np.diagonal(S_r, axis1=1, axis2=2), axis=1)) / len(rows)",
        ),
        "only the diagonal of S",
        20,
    ),
    (
        "04.nis_per_row",
        ("nis_per_row", "used = samples & ~np.isnan", "used = ~np.isnan"),
        "not only those in `samples`",
        20,
    ),
    (
        "04.coast_seconds",
        ("coast_seconds", "/ (gyro_noise * dt) ** 2 * dt", "/ (gyro_noise * dt) ** 2"),
        "that is the number of steps",
        20,
    ),
    ("04.coast_seconds", ("coast_seconds", "(sigma**2 - sigma0**2)", "(sigma**2)"), "the start σ0 is left out", 20),
    (
        "04.coast_seconds",
        (
            "coast_seconds",
            "(sigma**2 - sigma0**2) / (gyro_noise * dt) ** 2 * dt",
            "(sigma - sigma0) / (gyro_noise * dt) * dt",
        ),
        "the variances that add",
        20,
    ),
    ("05.to_body", ("to_body", "* flip\n    w_b", "\n    w_b"), "expected", 20),
    (
        "05.to_body",
        ("to_body", "np.radians(np.asarray(gyr_counts) / 131.0)", "np.asarray(gyr_counts) / 131.0"),
        "in degrees",
        20,
    ),
    ("05.accel_tilt", ("accel_tilt", "np.arctan2(-f[:, 1], -f[:, 2])", "np.arctan2(f[:, 1], f[:, 2])"), "180° off", 20),
    ("05.accel_tilt", ("accel_tilt", "np.arctan2(f[:, 0],", "np.arctan2(-f[:, 0],"), "wrong sign", 20),
    ("05.kf_predict", ("kf_predict", "A @ P @ A.T + Q", "A @ P @ A.T + np.diag(np.diag(Q))"), "off-diagonal", 20),
    ("05.kf_predict", ("kf_predict", "A @ x + B * omega", "A @ x - B * omega"), "expected", 20),
    ("05.kf_update", ("kf_update", "S = H @ P @ H + r", "S = H @ P @ H"), "expected", 20),
    ("05.run_kf", ("run_kf", "100.0 * r", "r"), "where static_ok is False", 20),
    (
        "05.run_kf",
        ("run_kf", "x, P = kf_predict(x, P, gyro_rate[k], dt, Q)", "x, P = kf_predict(x, P, gyro_rate[k], dt, 0 * Q)"),
        "first differs at sample",
        20,
    ),
    ("05.time_constant", ("q_for_time_constant", "return r * K ** 2", "return r * K"), "expected", 20),
    ("05.time_constant", ("q_for_time_constant", "return r * K ** 2", "return K ** 2"), "expected", 20),
    ("05.final", ("estimate_tilt", "ok_t & (np.hypot(f_t[:, 1], f_t[:, 2]) >= 0.5 * G)", "ok_t"), "nose-up", 1),
    (
        "06.bicycle_model",
        ("bicycle_model", "[(b * Cr - a * Cf) / Iz,", "[(b * Cr - a * Cf) / (Iz * vx),"),
        "A[1,0]",
        20,
    ),
    ("06.discretize", ("discretize", "E = expm(M * dt)", "E = np.eye(n + p) + M * dt"), "Euler", 20),
    ("06.kf_step", ("kf_step", "- D[:, 0] * delta", ""), "misses the D-term", 20),
    ("06.slalom_rmse", ("discretize", "E = expm(M * dt)", "E = np.eye(n + p) + M * dt"), "leans on its model", 1),
    (
        "06.slalom_rmse",
        ("bicycle_model", "[(b * Cr - a * Cf) / Iz,", "[(b * Cr - a * Cf) / (Iz * vx),"),
        "leans on its model",
        1,
    ),
    ("06.kf_step", ("kf_step", "Bd[:, 0] * delta_prev", "Bd[:, 0] * delta"), "δ_{k−1}", 20),
    ("06.slalom_rmse", ("kf_step", "Bd[:, 0] * delta_prev", "Bd[:, 0] * delta"), "leans on its model", 1),
    (
        "06.tyre_force",
        (
            "tyre_force",
            "front.force(delta - beta - params.a * r / vx), rear.force(-beta + params.b * r / vx)",
            "params.Cf * (delta - beta - params.a * r / vx), params.Cr * (-beta + params.b * r / vx)",
        ),
        "linear tyres",
        20,
    ),
    (
        "06.tyre_force",
        (
            "tyre_force",
            "front.force(delta - beta - params.a * r / vx), rear.force(-beta + params.b * r / vx)",
            "front.force(beta + params.a * r / vx - delta), rear.force(beta - params.b * r / vx)",
        ),
        "wrong sign",
        20,
    ),
    (
        "06.tyre_force",
        (
            "tyre_force",
            "front.force(delta - beta - params.a * r / vx), rear.force(-beta + params.b * r / vx)",
            "rear.force(-beta + params.b * r / vx), front.force(delta - beta - params.a * r / vx)",
        ),
        "front and rear are swapped",
        20,
    ),
    (
        "06.tyre_force",
        (
            "tyre_force",
            "front.force(delta - beta - params.a * r / vx), rear.force(-beta + params.b * r / vx)",
            "rear.force(delta - beta - params.a * r / vx), front.force(-beta + params.b * r / vx)",
        ),
        "its own curve",
        20,
    ),
    (
        "06.tyre_force",
        (
            "tyre_force",
            "G * params.b / L, params.mu)\n    rear = vehicle.MagicFormula.for_axle(params.Cr, "
            "params.m * G * params.a / L",
            "G * params.a / L, params.mu)\n    rear = vehicle.MagicFormula."
            "for_axle(params.Cr, params.m * G * params.b / L",
        ),
        "loads are swapped",
        20,
    ),
    ("06.tyre_force", ("tyre_force", "/ L, params.mu)", "/ L, 1.0)"), "params.mu is missing", 20),
    (
        "06.tyre_jacobian",
        (
            "tyre_jacobian",
            "kf, kr = front.slope(delta - beta - a * r / vx), rear.slope(-beta + b * r / vx)",
            "kf, kr = params.Cf, params.Cr",
        ),
        "local slope",
        20,
    ),
    ("06.tyre_jacobian", ("tyre_jacobian", "kf, kr = front.slope(", "kr, kf = front.slope("), "slopes are swapped", 20),
    (
        "06.tyre_jacobian",
        (
            "tyre_jacobian",
            "    return J, H",  # J by forward differences with a 1e-3 rad step
            "    f = lambda v: lab06.tyre_rates(params, tyre_force(params, v, delta, vx), v[1], vx)[0]\n"
            "    J = np.column_stack([(f(x + e) - f(x)) / 1e-3 for e in 1e-3 * np.eye(2)])\n    return J, H",
        ),
        "finite difference",
        20,
    ),
    (
        "06.banked_road",
        ("banked_road", "-rear / params.Cr", "-side * params.b / (params.a + params.b) / params.Cf"),
        "front axle",
        20,
    ),
    ("06.banked_road", ("banked_road", "return G * np.sin(bank),", "return -G * np.sin(bank),"), "low side", 20),
    ("06.banked_road", ("banked_road", "-rear / params.Cr", "0.0"), "β = 0", 20),
    ("06.banked_road", ("banked_road", "-rear / params.Cr", "rear / params.Cr"), "wrong sign", 20),
    ("06.banked_road", ("banked_road", "-rear / params.Cr", "np.degrees(-rear / params.Cr)"), "in degrees", 20),
]


@pytest.mark.slow
@pytest.mark.parametrize("name, mutate, words, seeds", MISTAKES, ids=[f"{m[0]}:{m[1][2][:30]}" for m in MISTAKES])
def test_each_classic_mistake_fails_on_every_seed_and_is_named(name, mutate, words, seeds):
    mistaken = solution_namespace(lab_of(name), mutate)[get(name).function]
    for seed in range(seeds):
        result = run_checkpoint(get(name), mistaken, seed)
        assert not result.ok and result.points == 0, (seed, result.message)
        assert words in result.message, (seed, result.message)


# --- messages show the difference -----------------------------------------------------------------------------


def test_messages_show_enough_digits_no_numpy_reprs_and_the_first_differing_element():
    from kfkit.checkpoints import compare, fmt

    assert fmt(np.int64(1)) == "1" and fmt(np.bool_(True)) == "True" and fmt(np.float64(-0.0)) == "0"
    problem = compare(np.array([0.061188, 1.0, 2.0, 3.0, 4.0]), np.array([0.061188, 1.0, 2.0, 3.0, 4.0001]))
    assert "first difference at index 4: expected 4, got 4.0001" in problem
    assert compare(0.0611880, 0.0611881) == "expected 0.061188, got 0.0611881"
    assert (
        compare((1.0, np.zeros(3)), (1.0, np.zeros(4)))
        == "value 2 of 2: shape mismatch: expected shape (3,), got shape (4,)"
    )
    assert "np." not in compare(np.eye(3, dtype=int), np.zeros((3, 3), dtype=np.int64))


def test_printed_lines_never_break_a_number_or_a_word():
    message = "❌ 00.board_time: " + " ".join(f"t = {x:.9f} s," for x in np.linspace(0, 1, 40)) + " Hint: 4294967290"
    lines = wrap_message(message).splitlines()
    assert len(lines) > 3 and all(len(line) <= 100 for line in lines)
    assert wrap_message(message).split() == message.split()  # only spaces became line breaks


# --- lab 02's Allan formula, as printed, passes its checkpoint -------------------------------------------------


def printed_allan_formula():
    """The notebook's formula written out literally: N samples, θ_j = (1/f_s) Σ_{i<j} x_i for j = 0 … N, m = τ f_s,
    σ²(τ) = 1/(2τ²(N − 2m + 1)) Σ_{k=0}^{N−2m} (θ_{k+2m} − 2θ_{k+m} + θ_k)²."""

    def allan_deviation(x, rate_hz, taus):
        N = len(x)
        theta = [sum(x[:j]) / rate_hz for j in range(N + 1)]
        out = []
        for tau in taus:
            m = int(round(tau * rate_hz))
            total = sum((theta[k + 2 * m] - 2 * theta[k + m] + theta[k]) ** 2 for k in range(N - 2 * m + 1))
            out.append((total / (2 * tau**2 * (N - 2 * m + 1))) ** 0.5)
        return np.array(out)

    return allan_deviation


def test_the_printed_allan_formula_is_the_checkpoints_and_allantools():
    allantools = pytest.importorskip("allantools")
    nb = nbformat.read(next(SOLUTIONS.glob("02_*.ipynb")), as_version=4)
    text = next(
        c.source for c in nb.cells if c.cell_type == "markdown" and "Allan deviation" in c.source and "sum_" in c.source
    )
    assert r"\frac{1}{2\tau^2 (N - 2m + 1)} \sum_{k=0}^{N-2m}" in text and "N$ samples" in text
    result = run_checkpoint(get("02.allan_deviation"), printed_allan_formula(), seed=0)
    assert result.ok, result.message
    x, rate = np.random.default_rng(1).normal(0, 1, 300), 12.5
    taus = np.array([1, 2, 5, 20, 70]) / rate
    theirs = allantools.oadev(x, rate=rate, data_type="freq", taus=taus)[1]
    np.testing.assert_allclose(printed_allan_formula()(x - x.mean(), rate, taus), theirs, rtol=1e-9)


@pytest.mark.parametrize("judge", ["_judge_rmse", "_judge_real"])
@pytest.mark.parametrize(
    "answer, words",
    [
        ("a string", "expected (x, P, nis) with x of shape (N, 3), got str"),
        ((np.zeros((3, 5)), None, None), "expected 5 rows of [roll, pitch, yaw] (shape (5, 3)), got shape (3, 5)"),
        (np.zeros(5), "got shape (5,)"),
    ],
)
def test_a_whole_run_answer_of_the_wrong_kind_is_named_not_crashed_on(judge, answer, words):
    """04.ekf_rmse and 04.real_ekf judge run_ekf's (x, P, nis): a wrong type or shape says what was expected."""
    from kfkit.checkpoints import Case, ekf_attitude_core, ekf_attitude_optional

    truth = np.zeros((5, 3))
    expected = (
        (truth, ekf_attitude_core.RMSE_LIMITS, "")
        if judge == "_judge_rmse"
        else (np.tile([1.0, 0, 0, 0], (5, 1)), None, 0.0, 0.0)
    )
    module = ekf_attitude_core if judge == "_judge_rmse" else ekf_attitude_optional
    assert words in getattr(module, judge)(Case({}, expected), answer)
