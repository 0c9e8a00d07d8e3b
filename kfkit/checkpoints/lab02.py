"""Checkpoints of lab 02 (bias and noise)."""

from __future__ import annotations

import numpy as np

from .. import allan, calibration, datasets, rest_calibration
from ..discrete import angle_bias_process_noise
from ..frames import G
from ..labs.lab02 import NOISE_CHECK_S, gyro_bias_truth, noise_truth, six_face_truth
from . import Case, Checkpoint, compare, fmt, matches, register, structural

N_SIGMA = 4.0  # estimates on the bundled recording must lie within 4 standard uncertainties of the truth


def _rest(rng, n, bias, sigma):
    return bias + rng.normal(0.0, sigma, (n, 3))


def _gyro_bias_cases(rng):
    cases = []
    for _ in range(8):
        gyr = _rest(rng, int(rng.integers(5, 400)), rng.normal(0, 0.02, 3), 10 ** rng.uniform(-4, -2))
        cases.append(Case({"gyr": gyr}, rest_calibration.gyro_bias(gyr), f"a rest of {len(gyr)} samples"))
    return cases


def _judge_bias(case, got):
    """The per-axis mean at rest; names the spread (std) and the mean over every axis at once."""
    problem = compare(case.expected, got, atol=1e-12)
    if problem is None:
        return problem
    x = case.args["gyr"]
    if np.ndim(got) == 0 and np.isclose(float(np.asarray(got, float)), x.mean(), rtol=1e-9):
        return problem + " — that is the mean of all three axes together: average each axis (axis=0)"
    spread = (x.std(axis=0, ddof=1), x.std(axis=0))
    if not structural(problem) and any(np.allclose(np.asarray(got, float), sd, rtol=1e-6) for sd in spread):
        return problem + " — that is the spread (std) of each axis; the bias is its average"
    return problem


def _noise_cases(rng):
    cases = []
    for _ in range(8):
        x = _rest(rng, int(rng.integers(5, 400)), rng.normal(0, 1, 3), 10 ** rng.uniform(-4, -1))
        cases.append(Case({"x": x}, rest_calibration.noise_std(x), f"a rest of {len(x)} samples"))
    return cases


def _judge_noise(case, got):
    problem = compare(case.expected, got, rtol=1e-6)
    if problem is None or structural(problem):
        return problem
    x = case.args["x"]
    if np.allclose(np.asarray(got, float), x.std(axis=0, ddof=0), rtol=1e-9):
        return problem + " — that is the population std (ddof=0); use the sample std (ddof=1)"
    return problem


def _accel_bias_cases(rng):
    cases = []
    for _ in range(8):
        expected = G * np.eye(3)[rng.integers(3)] * rng.choice([-1, 1])
        acc = _rest(rng, int(rng.integers(5, 300)), expected + rng.normal(0, 0.1, 3), 0.01)
        cases.append(
            Case(
                {"acc": acc, "expected": expected},
                rest_calibration.accel_bias(acc, expected),
                f"a rest of {len(acc)} samples with expected specific force {np.round(expected, 3).tolist()}",
            )
        )
    return cases


def _judge_accel_bias(case, got):
    problem = compare(case.expected, got, atol=1e-9)
    if problem is None or structural(problem):
        return problem
    if np.allclose(np.asarray(got, float), case.args["acc"].mean(axis=0), atol=1e-9):
        return problem + " — you returned the whole mean: gravity is still in it"
    if np.allclose(np.asarray(got, float), -case.expected, atol=1e-9):
        return problem + " — the sign is flipped: bias = reading − expected, not expected − reading"
    return problem


def random_faces(rng, bias, scale, n=50, sigma=0.01):
    """Six labelled rests of an accelerometer with per-axis ``bias`` (m/s²) and ``scale``."""
    faces = {}
    for i, axis in enumerate("xyz"):
        for sign, word in ((1, "up"), (-1, "down")):
            f = np.zeros(3)
            f[i] = sign * G
            faces[f"{axis}_{word}"] = _rest(rng, n, scale * f + bias, sigma)
    return faces


def _six_face_cases(rng):
    cases = []
    for _ in range(6):
        faces = random_faces(rng, rng.normal(0, 0.1, 3), 1 + rng.normal(0, 0.01, 3), n=int(rng.integers(10, 100)))
        cases.append(Case({"faces": faces}, rest_calibration.accel_six_face(faces), "six random faces"))
    return cases


def _allan_cases(rng):
    cases = []
    for _ in range(5):
        n, rate = int(rng.integers(200, 2000)), float(rng.choice([12.5, 100.0, 104.0]))
        x = rng.normal(0, 1e-3, n) + np.cumsum(rng.normal(0, 1e-5, n))
        taus = np.unique(np.round(np.logspace(0, np.log10(n / 4), 8))) / rate
        cases.append(
            Case(
                {"x": x, "rate_hz": rate, "taus": taus},
                allan.allan_deviation(x, rate, taus)[1],
                f"{n} samples at {rate:g} Hz, {len(taus)} values of τ",
            )
        )
    return cases


def _judge_allan(case, got):
    """Against the overlapping estimator; a wrong answer is described by its ratio to the right one, which
    tells a missing 1/rate (θ in samples, not seconds) or a missing 2 apart from a wrong count of terms."""
    problem = compare(case.expected, got, rtol=1e-6, atol=0)
    if problem is None or structural(problem):
        return problem
    ratio, rate = np.asarray(got, float) / case.expected, case.args["rate_hz"]
    if np.allclose(ratio, 0.0, atol=1e-12):
        return problem + " — every σ is 0: is θ integrated (cumsum), and the squared differences summed?"
    if not np.allclose(ratio, ratio[0], rtol=1e-3):
        return (
            problem
            + f" — the ratio to the right values changes with τ (from {fmt(ratio.min())} to {fmt(ratio.max())}): "
            "a count of terms or a sum range that depends on m is off; N + 1 − 2m differences, k = 0 … N − 2m"
        )
    causes = {
        rate: "θ is not divided by rate_hz: θ = cumsum(x)/rate_hz is in (unit of x)·s",
        1 / rate: "θ is divided by rate_hz once too often",
        np.sqrt(2.0): "the 2 in 1/(2τ²…) is missing",
        1 / np.sqrt(2.0): "the 2 in 1/(2τ²…) is there twice",
        rate**2: "τ looks counted in samples (m), not seconds",
    }
    for factor, cause in causes.items():
        if np.isclose(ratio[0], factor, rtol=1e-3):
            return problem + f" — off by a constant factor {fmt(ratio[0])}: {cause}"
    if np.isclose(ratio[0], 1.0, rtol=1e-2):
        return (
            problem + f" — off by a constant factor {fmt(ratio[0], 7)}: nearly right, check the sum range and its count"
        )
    return problem + f" — off by a constant factor {fmt(ratio[0])}: check the 1/(2τ²(N + 1 − 2m)) normalisation"


def _rate_cases(rng):
    return [
        Case(args, calibration.noise_at_rate(**args))
        for args in (
            {
                "sigma": 10 ** rng.uniform(-5, -1, 3),
                "rate_from": float(rng.choice([12.5, 26.0, 52.0])),
                "rate_to": float(rng.choice([100.0, 104.0, 208.0])),
            }
            for _ in range(6)
        )
    ]


# --- Q from the noise measured -----------------------------------------------------------------------------------


def _q_cases(rng):
    """Δt from a sample to long gaps: in the long ones (Δt of a third to three times √3·N/K, where the bias's walk
    gives the angle as much variance as the white noise does) every term of Q shows."""
    cases = [Case({"N": 9.1e-5, "K": 4.4e-6, "dt": 1 / 104}, None, "the Nucleo's gyro at 104 Hz")]
    for _ in range(7):
        N, K = 10 ** rng.uniform(-4.5, -2.5), 10 ** rng.uniform(-6.5, -4.0)
        cases.append(Case({"N": N, "K": K, "dt": float(np.sqrt(3) * N / K * 10 ** rng.uniform(-0.5, 0.5))}, None))
    for case in cases:
        case.expected = angle_bias_process_noise(case.args["N"], case.args["K"], case.args["dt"])
    return cases


def _q_mistakes(N, K, dt):
    """What each classic mistake makes of one entry of Q: {(row, col): {what it is: value}}."""
    return {
        (0, 0): {
            "K²·Δt³/3, the bias's walk integrated into the angle, is missing from Q[0,0]": N**2 * dt,
            "(N·Δt)² treats the density N as a per-sample σ: a sample's σ is N·√rate = N/√Δt, so the "
            "angle's variance over Δt is (σ·Δt)² = N²·Δt": (N * dt) ** 2 + K**2 * dt**3 / 3,
            "N² leaves out Δt: a white-noise density's variance grows with time, N²·Δt": N**2 + K**2 * dt**3 / 3,
        },
        (0, 1): {
            "Q[0,1] = 0: no cross term, but the bias's walk during the step has already turned the angle: "
            "−K²·Δt²/2": 0.0,
            "the off-diagonal has the wrong sign: θ̇ = ω_m − b, so a bias that grew during the step has "
            "turned the angle the other way": K**2 * dt**2 / 2,
        },
        (1, 1): {
            "(K·Δt)² treats the density K as a per-sample step: the bias's variance over Δt is K²·Δt": (K * dt) ** 2
        },
    }


def _judge_q(case, got):
    """Against kfkit.discrete.angle_bias_process_noise, each wrong entry named by the mistake that makes it."""
    problem = compare(case.expected, got, rtol=1e-6, atol=0)
    if problem is None or structural(problem):
        return problem
    g = np.asarray(got, float)
    if not np.isclose(g[0, 1], g[1, 0], rtol=1e-9, atol=0):
        return problem + " — Q is a covariance: Q[0,1] and Q[1,0] are the same number"
    named = [
        what
        for (i, j), mistakes in _q_mistakes(**case.args).items()
        if not np.isclose(g[i, j], case.expected[i, j], rtol=1e-6, atol=0)
        for what, value in mistakes.items()
        if np.isclose(g[i, j], value, rtol=1e-6, atol=0)
    ]
    return problem + "".join(f" — {what}" for what in named)


ARW_SI = np.pi / 180 / 60  # rad/√s per °/√h: 1 h = 3600 s, so √h = 60 √s
RRW_SI = np.pi / 180 / 3600 / 60  # rad/s/√s per °/h/√h


def _datasheet_cases(rng):
    """Figures as an Allan report or a datasheet gives them: ARW °/√h, bias instability °/h, RRW °/h/√h (the Nucleo's
    simulated gyro: 0.31 °/√h, 6.2 °/h, 54 °/h/√h). The bias instability is drawn a tenth to a thirtieth of the RRW's
    number, so that a Q built from it is never the right one."""
    cases = []
    for _ in range(6):
        rrw = 10 ** rng.uniform(0.5, 2.0)
        args = {
            "arw": 10 ** rng.uniform(-1.5, 0.5),
            "bias_instability": rrw * 10 ** rng.uniform(-1.5, -1.0),
            "rrw": rrw,
            "dt": float(rng.choice([1 / 416, 0.01, 1 / 104, 0.1, 1.0])),
        }
        cases.append(Case(args, angle_bias_process_noise(args["arw"] * ARW_SI, args["rrw"] * RRW_SI, args["dt"])))
    return cases


def _judge_datasheet(case, got):
    """Against kfkit.discrete.angle_bias_process_noise in SI; the N and K a wrong Q was built with (read back from its
    diagonal) are compared with the figures converted wrongly, and the one that fits is named."""
    problem = compare(case.expected, got, rtol=1e-6, atol=0)
    if problem is None or structural(problem):
        return problem
    g, a, dt = np.asarray(got, float), case.args, case.args["dt"]
    K = np.sqrt(max(g[1, 1], 0.0) / dt)
    N = np.sqrt(max(g[0, 0] - K**2 * dt**3 / 3, 0.0) / dt)
    arw_wrong = {
        a["arw"]: "the ARW is used in °/√h: 1 °/√h = (π/180)/60 rad/√s",
        a["arw"] * np.pi / 180 / 3600: "the ARW is converted as if it were °/h: √h = 60 √s, not 3600",
        a["arw"] * np.pi / 180: "the ARW is converted to rad but not from √h to √s (÷60)",
    }
    B = a["bias_instability"]
    rrw_wrong = {
        B * RRW_SI: "that is the bias instability, not the rate random walk: B is the Allan curve's floor, "
        "K its +½ slope",
        B * np.pi / 180 / 3600: "that is the bias instability (in rad/s), not the rate random walk: B is the "
        "Allan curve's floor, K its +½ slope",
        B: "that is the bias instability, not the rate random walk",
        a["rrw"]: "the RRW is used in °/h/√h: 1 °/h/√h = (π/180)/3600/60 rad/s/√s",
        a["rrw"] * np.pi / 180 / 3600: "the RRW is converted from °/h but not from /√h to /√s (÷60 more)",
    }
    named = [what for value, what in arw_wrong.items() if np.isclose(N, value, rtol=1e-4, atol=0)]
    named += [what for value, what in rrw_wrong.items() if np.isclose(K, value, rtol=1e-4, atol=0)]
    return problem + "".join(f" — {what}" for what in named)


# --- estimates on the bundled recordings ----------------------------------------------------------


def _bias_recording_cases(rng):
    rec = datasets.load("02_stationary")
    truth, u = gyro_bias_truth(rec)
    return [Case({"gyr": rec.body("gyr")}, (truth, u), "the bundled recording 02_stationary")]


def _judge_bias_recording(case, got):
    """Within N_SIGMA uncertainties of the simulation's bias, and an estimate from the whole rest: the bias over
    this rest is its average, and an estimate that uses all N samples lies within N_SIGMA·σ/√N (white noise) of
    it. The bias's own wander (K√(T/3), which sets the first bar) is common to both, so this second bar is ~60×
    tighter here and fails an estimate from part of the rest (the first 100 samples are 5–90 σ/√N away)."""
    problem = _judge_within(case, got, " rad/s")
    if problem:
        return problem
    gyr = case.args["gyr"]
    u_white = gyr.std(axis=0, ddof=1) / np.sqrt(len(gyr))
    z = np.abs(np.asarray(got, float) - gyr.mean(axis=0)) / u_white
    if np.all(z <= N_SIGMA):
        return None
    return (
        f"your bias is {z.max():.0f} white-noise uncertainties σ/√N = {fmt(u_white.max())} rad/s from the average "
        f"of all {len(gyr):,} samples (allowed {N_SIGMA:g}): use the whole rest"
    )


def _judge_within(case, got, unit=""):
    truth, u = case.expected
    try:
        g = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return f"expected an array of 3 values, got {type(got).__name__}"
    if g.shape != truth.shape:
        return f"expected shape {truth.shape}, got {g.shape}"
    z = np.abs(g - truth) / u
    if np.all(z <= N_SIGMA):
        return None
    return (
        f"the true value is {np.round(truth, 6).tolist()}{unit}, yours {np.round(g, 6).tolist()}: "
        f"{z.max():.0f} standard uncertainties away (allowed {N_SIGMA:g})"
    )


def _noise_recording_cases(rng):
    rec = datasets.load("02_stationary")
    cases = []
    for sensor, name in (("gyr", "gyro"), ("acc", "accelerometer")):
        sigma, u, n = noise_truth(rec, sensor)
        cases.append(
            Case(
                {"x": rec.body(sensor)[:n]},
                (sigma, u),
                f"the {name} over the first {NOISE_CHECK_S:g} s of the bundled recording 02_stationary",
            )
        )
    return cases


def _six_face_recording_cases(rng):
    rec = datasets.load("02_six_faces")
    faces = {f: rec.body("acc")[rec.phase(f)] for f in rest_calibration.FACES}
    return [Case({"faces": faces}, six_face_truth(rec), "the bundled recording 02_six_faces")]


def _judge_six_face_recording(case, got):
    bias, scale, u_b, u_s = case.expected
    if not isinstance(got, (tuple, list)) or len(got) != 2:
        return f"expected (bias, scale), got {type(got).__name__}"
    return _judge_within(Case({}, (bias, u_b)), got[0], " m/s² (bias)") or _judge_within(
        Case({}, (scale, u_s)), got[1], " (scale)"
    )


register(
    Checkpoint(
        "02.gyro_bias",
        "gyro_bias",
        _gyro_bias_cases,
        _judge_bias,
        points=1,
        hint="at rest the true rate is zero, so what is left on average, per axis, is the bias.",
    ),
    Checkpoint(
        "02.noise_std",
        "noise_std",
        _noise_cases,
        _judge_noise,
        points=1,
        hint="the spread about the mean, per axis (axis=0), with the N − 1 of a sample standard deviation.",
    ),
    Checkpoint(
        "02.accel_bias",
        "accel_bias",
        _accel_bias_cases,
        _judge_accel_bias,
        points=1,
        hint="at rest the accelerometer reads the specific force of the pose plus the bias.",
    ),
    Checkpoint(
        "02.six_face",
        "six_face",
        _six_face_cases,
        matches(rtol=1e-9, atol=1e-12),
        points=2,
        hint="axis i reads s·g + b pointing up and −s·g + b pointing down: add and subtract the two means "
        "of that axis's component. Return (bias, scale), each of shape (3,).",
    ),
    Checkpoint(
        "02.allan_deviation",
        "allan_deviation",
        _allan_cases,
        _judge_allan,
        points=2,
        hint="integrate to θ = cumsum(x)/rate with θ₀ = 0 in front (N + 1 values), then for each τ = m/rate use "
        "every overlapping difference θ[k+2m] − 2θ[k+m] + θ[k], k = 0 … N − 2m, and divide by their count.",
    ),
    Checkpoint(
        "02.sigma_at_rate",
        "sigma_at_rate",
        _rate_cases,
        matches(),
        points=1,
        hint="the density N = σ/√rate is the sensor's; the per-sample σ at another rate follows from it.",
    ),
    Checkpoint(
        "02.q_from_noise_density",
        "q_from_noise_density",
        _q_cases,
        _judge_q,
        points=2,
        hint="θ̇ = ω_m − b − n_g and ḃ = n_b: over Δt the angle collects the white noise (∫n_g) and the bias's walk "
        "since the step began, integrated once more (−∫∫n_b); take the variances and the covariance of the two.",
    ),
    Checkpoint(
        "02.q_from_datasheet",
        "q_from_datasheet",
        _datasheet_cases,
        _judge_datasheet,
        points=1,
        hint="convert each figure to SI first (1 h = 3600 s, so √h = 60 √s), then ask which of the three the "
        "[angle, bias] model has a place for.",
    ),
    Checkpoint(
        "02.gyro_bias_recording",
        "gyro_bias",
        _bias_recording_cases,
        _judge_bias_recording,
        points=1,
        what="bundled recording",
        hint="use the whole rest: the uncertainty of a mean shrinks as σ/√N, until the bias's own wander dominates.",
    ),
    Checkpoint(
        "02.noise_recording",
        "noise_std",
        _noise_recording_cases,
        _judge_within,
        points=1,
        what="bundled recording checks",
        hint="if 02.noise_std passes, check that you pass the samples at rest in the body frame, all three axes.",
    ),
    Checkpoint(
        "02.six_face_recording",
        "six_face",
        _six_face_recording_cases,
        _judge_six_face_recording,
        points=1,
        what="bundled recording",
        hint="if 02.six_face passes, check that each face's samples come from its own phase.",
    ),
)
