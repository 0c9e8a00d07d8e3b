"""Checkpoints of lab 01 (1D roll Kalman filter)."""

from __future__ import annotations

import numpy as np

from ..filters import integrate_rate, roll_kf, roll_kf_predict, roll_kf_steady_state, roll_kf_update
from ..frames import G, wrap_angle
from ..labs.lab01 import bundled_inputs
from ..metrics import angle_error, rmse
from . import Case, Checkpoint, compare, fmt_pair, matches, register, structural


def _accel_roll_cases(rng):
    """Level first, then a generic roll (where a sign flip, a half turn and swapped arguments all differ),
    the quarter and near-half turns, and random rolls; last, an array."""
    cases = []
    generic = rng.uniform(0.3, 1.2) * rng.choice([-1, 1])
    for roll in np.concatenate([[0.0, generic, np.pi / 2, -np.pi / 2, 3.0, -3.0], rng.uniform(-np.pi, np.pi, 6)]):
        f = np.array([0.0, -G * np.sin(roll), -G * np.cos(roll)]) * rng.uniform(0.8, 1.2)
        cases.append(Case({"ay": f[1], "az": f[2]}, roll))
    rolls = rng.uniform(-np.pi, np.pi, 20)
    cases.append(Case({"ay": -G * np.sin(rolls), "az": -G * np.cos(rolls)}, rolls, "an array of 20 samples"))
    return cases


def _judge_accel_roll(case, got):
    problem = compare(case.expected, got, atol=1e-9)
    if problem is None or structural(problem):
        return problem
    got, want = np.asarray(got, dtype=float), case.expected
    if np.allclose(wrap_angle(got + want), 0.0, atol=1e-9):  # before 180°: at ±90° a flip is also a half turn
        return problem + " — the sign is flipped: roll to the right makes f_y negative, so use −f_y"
    if np.allclose(np.abs(wrap_angle(got - want)), np.pi, atol=1e-6):
        return problem + " — exactly 180° off: level (f_z = −g) must give 0, so atan2 needs −f_z as its second argument"
    if np.allclose(wrap_angle(got + want - np.pi / 2), 0.0, atol=1e-9):
        return problem + " — the atan2 arguments are swapped: atan2(y, x) takes the sine-like component first"
    return problem


def _fuse_cases(rng):
    """A prior and a measurement of one roll (rad, rad²), each variance 1.6 to 20 times the other (either the more
    certain) and the means 0.5 to 3 of the wider σ apart, so that every classic mistake moves the answer; last,
    arrays of 20 (the fusion is elementwise, as the filter's update is). Expected: kfkit's scalar update."""

    def draw(n=None):
        var_prior = 10 ** rng.uniform(-5, -2, n)
        r = var_prior * 10 ** (rng.choice([-1, 1], n) * rng.uniform(0.2, 1.3, n))
        mu = rng.uniform(-0.5, 0.5, n)
        z = mu + rng.choice([-1, 1], n) * rng.uniform(0.5, 3.0, n) * np.sqrt(np.maximum(var_prior, r))
        args = {"mu_prior": mu, "var_prior": var_prior, "z": z, "r": r}
        return Case(args, roll_kf_update(mu, var_prior, z, r)[:2], "" if n is None else f"arrays of {n} (elementwise)")

    return [draw() for _ in range(10)] + [draw(20)]


def _judge_fuse(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-15)
    if problem is None or structural(problem):
        return problem
    mu, P, z, r = (case.args[k] for k in ("mu_prior", "var_prior", "z", "r"))
    mean, var = (np.asarray(v, dtype=float) for v in got)
    if np.allclose(var, P + r):
        return problem + (
            " — the variances were added: that is what a prediction does; fusing two measurements of "
            "one roll leaves less uncertainty than either"
        )
    if np.allclose(var, np.sqrt(case.expected[1])):
        return problem + " — that is the posterior's standard deviation: return its variance"
    if np.allclose(mean, (mu + z) / 2):
        return problem + " — the plain average of the two means: the more certain one must pull harder"
    if np.allclose(mean, (mu * P + z * r) / (P + r)):
        return problem + (
            " — each mean is weighted by its own variance, so the less certain one pulls harder: "
            "weight each by its precision, 1/variance"
        )
    return problem


def q_for_tau(tau, dt, r):
    """The q (rad²) whose steady-state filter has τ = Δt/K∞ with r (rad²): K∞ = Δt/τ, P⁻∞ = K∞r/(1 − K∞) (from
    K∞ = P⁻∞/(P⁻∞ + r)), q = P⁻∞²/(P⁻∞ + r) (from P⁻∞² − qP⁻∞ − qr = 0), that is q = r·K∞²/(1 − K∞)."""
    K = dt / tau
    return r * K**2 / (1.0 - K)


def _tau_cases(rng):
    """Time constants of 2 to 500 steps (K∞ from 0.5 to 0.002: the large gains tell the exact answer from the
    small-gain r·K∞² by far, the small ones still by more than the tolerance) at 50–1000 Hz, accelerometer roll σ
    of 0.1° to 5°. Each expected q is checked against :func:`kfkit.filters.roll_kf_steady_state`."""
    cases = []
    for steps in np.concatenate([[rng.uniform(2, 4)], 10 ** rng.uniform(np.log10(2), np.log10(500), 9)]):
        dt = 1.0 / float(rng.choice([50.0, 100.0, 104.0, 200.0, 1000.0]))
        args = {"tau": steps * dt, "dt": dt, "r": np.radians(10 ** rng.uniform(-1, 0.7)) ** 2}
        q = q_for_tau(**args)
        assert np.isclose(dt / roll_kf_steady_state(q, args["r"])[1], args["tau"], rtol=1e-9)
        cases.append(Case(args, q))
    return cases


def _judge_tau(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=0.0)
    if problem is None or structural(problem):
        return problem
    tau, dt, r = case.args["tau"], case.args["dt"], case.args["r"]
    K = dt / tau
    P_prior = K * r / (1.0 - K)
    g = float(np.asarray(got, dtype=float))
    if np.isclose(g, r * K**2, rtol=1e-6):
        return problem + (
            " — that is r·K∞², the small-gain approximation (P⁻∞ ≈ √(q r)), off by a factor 1 − K∞: "
            "solve section 8's equations exactly"
        )
    if np.isclose(g, P_prior, rtol=1e-6):
        return problem + " — that is P⁻∞, the steady prior variance; q is what each prediction adds to the variance"
    if np.isclose(g, K**2 / (1.0 - K), rtol=1e-6):
        return problem + " — r is missing: K∞ depends on q/r only, so q must scale with r"
    if g <= 0 or np.isclose(g, r * (tau / dt) ** 2 / (1.0 - tau / dt), rtol=1e-6):
        return problem + " — K∞ = Δt/τ is a gain between 0 and 1, and q a variance, which cannot be negative"
    return problem


def _predict_cases(rng):
    return [
        Case(args, roll_kf_predict(**args))
        for args in (
            {
                "x": rng.uniform(-1, 1),
                "P": rng.uniform(1e-6, 1e-2),
                "omega": rng.normal(0, 1),
                "dt": rng.choice([0.01, 1 / 104, 0.005]),
                "q": 10 ** rng.uniform(-9, -3),
            }
            for _ in range(12)
        )
    ]


def _update_cases(rng):
    return [
        Case(args, roll_kf_update(**args))
        for args in (
            {
                "x": rng.uniform(-1, 1),
                "P": 10 ** rng.uniform(-6, -1),
                "z": rng.uniform(-1, 1),
                "r": 10 ** rng.uniform(-6, -1),
            }
            for _ in range(12)
        )
    ]


def _run_cases(rng):
    cases = []
    for _ in range(6):
        n = int(rng.integers(5, 60))
        args = {
            "gyro_rate": rng.normal(0, 0.5, n),
            "roll_acc": rng.normal(0, 0.3, n),
            "dt": 1 / 104,
            "q": 10 ** rng.uniform(-8, -3),
            "r": 10 ** rng.uniform(-5, -1),
            "x0": rng.uniform(-0.5, 0.5),
            "P0": 10 ** rng.uniform(-3, 0),
        }
        ref = roll_kf(**args)
        cases.append(Case(args, (ref.x, ref.P, ref.y, ref.S), f"a random sequence of {n} samples"))
    return cases


def _judge_run(case, got):
    """(x, P, y, S) against the reference, naming the first sample where x, P, y or S differ."""
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-9)
    if problem is None or structural(problem):
        return problem
    for name, e, g in zip("xPyS", case.expected, got):
        g = np.asarray(g, dtype=float)
        bad = ~np.isclose(g, e, rtol=1e-6, atol=1e-9)
        if bad.any():
            k = int(np.argmax(bad))
            want, have = fmt_pair(e[k], g[k])
            return f"{name} first differs at sample {k}: expected {want}, got {have}" + (
                " (sample 0 already: start from x0, P0 and predict before the first update)" if k == 0 else ""
            )
    return problem


TUNED_Q = 1e-7  # rad², near the best q the lab's sweep finds on the bundled recording (5.6e-8)


def _beats_cases(rng):
    t, gyro, roll_acc, truth, still = bundled_inputs()
    dt = float(t[1] - t[0])
    x0, r = float(np.mean(roll_acc[still])), float(np.var(roll_acc[still]))
    args = {"gyro_rate": gyro, "roll_acc": roll_acc, "dt": dt, "q": TUNED_Q, "r": r, "x0": x0, "P0": r}
    single = {
        "accel only": rmse(angle_error(roll_acc, truth), 0.0),
        "gyro only": rmse(angle_error(integrate_rate(gyro, dt, x0), truth), 0.0),
    }
    return [Case(args, {"truth": truth, "single": single}, "the bundled recording 01_roll_sine")]


#: The fused RMSE must be below this fraction of each single sensor's. With the tuned q ≪ r the steady-state
#: variance is P ≈ √(q r), so the filter averages the accelerometer's noise down by (q/r)^¼ ≈ 0.1; a quarter
#: leaves a factor 2.5 for the motion and the gyro bias (kfkit: 0.37° against 4.21° and 9.14°), while a filter
#: that never adds q (a running mean of the accelerometer, 4.20°) or drops an update is far above it.
BEATS_FRACTION = 0.25


def _judge_beats(case, got):
    try:
        x = np.asarray(got[0], dtype=float)
    except (TypeError, ValueError, IndexError):
        return f"expected (x, P, y, S) arrays, got {type(got).__name__}"
    if x.shape != case.expected["truth"].shape:
        return f"expected {case.expected['truth'].size} roll estimates, got shape {x.shape}"
    ours = rmse(angle_error(x, case.expected["truth"]), 0.0)
    worse = {k: v for k, v in case.expected["single"].items() if not ours < BEATS_FRACTION * v}
    if worse:
        return f"KF RMSE {np.degrees(ours):.2f}° is not below a quarter of " + " and ".join(
            f"{k} ({np.degrees(v):.2f}°, a quarter {np.degrees(BEATS_FRACTION * v):.2f}°)" for k, v in worse.items()
        )
    return None


register(
    Checkpoint(
        "01.accel_roll",
        "accel_roll",
        _accel_roll_cases,
        _judge_accel_roll,
        points=1,
        hint="at rest f_y = −g·sin φ and f_z = −g·cos φ; which two numbers does atan2 need so that "
        "level (f_z = −g) gives 0, not 180°?",
    ),
    Checkpoint(
        "01.fuse_gaussians",
        "fuse_gaussians",
        _fuse_cases,
        _judge_fuse,
        points=2,
        hint="multiply the two densities: their exponents add, so the precisions (1/variance) add, and each "
        "mean counts in proportion to its precision.",
    ),
    Checkpoint(
        "01.kf_predict",
        "kf_predict",
        _predict_cases,
        matches(),
        points=1,
        hint="the gyro rate moves the roll forward by ω·dt, and the uncertainty only grows (by q).",
    ),
    Checkpoint(
        "01.kf_update",
        "kf_update",
        _update_cases,
        matches(),
        points=2,
        hint="y = z − x, S = P + r, K = P/S; the new P is smaller than both P and r. Return (x, P, y, S).",
    ),
    Checkpoint(
        "01.run_kf",
        "run_kf",
        _run_cases,
        _judge_run,
        points=2,
        hint="start from x0, P0; at every sample predict with gyro_rate[k], then update with roll_acc[k]; "
        "store x, P, y, S after each update and return four arrays.",
    ),
    Checkpoint(
        "01.kf_beats_sensors",
        "run_kf",
        _beats_cases,
        _judge_beats,
        points=2,
        what="bundled recording",
        hint="with a tuned q and r from the accel-roll noise at rest the fused estimate is several times better "
        "than each sensor alone; if 01.run_kf passes, look at how x0, P0 and q are used.",
    ),
    Checkpoint(
        "01.q_for_time_constant",
        "q_for_time_constant",
        _tau_cases,
        _judge_tau,
        points=2,
        hint="walk section 8 backwards: τ gives K∞, K∞ = P⁻∞/(P⁻∞ + r) gives P⁻∞, and P⁻∞'s equation "
        "(P⁻)² − q·P⁻ − q·r = 0 gives q.",
    ),
)
