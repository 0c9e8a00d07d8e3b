"""Lab 02's Q from the noise it measures (issue 26 §3): the claims its text and answers make, each against an oracle
outside the lab's code (Van Loan's matrix exponential, scipy's unit constants, Monte Carlo rests of the simulator's
noise model), and the calibration it saves for labs 04 and 05 carrying the gyro's N and K."""

import numpy as np
import pytest
from scipy import constants
from test_checkpoints_every import solution_namespace

from kfkit import allan, datasets, discrete, motions, rest_calibration, sim
from kfkit import calibration as C
from kfkit.io import save_recording
from kfkit.labs import lab02
from kfkit.unit_errors import NUCLEO_UNIT

ANGLE_BIAS_A = [[0.0, -1.0], [0.0, 0.0]]  # θ̇ = ω_m − b − n_g, ḃ = n_b


@pytest.fixture(scope="module")
def lab():
    return solution_namespace("02")


def van_loan(N, K, dt):
    return discrete.discretize(ANGLE_BIAS_A, np.zeros(2), dt, np.diag([N**2, K**2]))[2]


def test_a_minute_of_filter_steps_builds_the_minutes_q(lab):
    """Section 6's (c): P ← F P Fᵀ + Q(Δt) from P = 0, 6240 times at 104 Hz, is Van Loan's Q over 60 s: Q is exact,
    so F carries the bias's walk into the angle step by step."""
    q = lab["q_from_noise_density"]
    N, K, dt = 9.05e-5, 4.05e-6, 1 / 104
    F, P = np.array([[1.0, -dt], [0.0, 1.0]]), np.zeros((2, 2))
    for _ in range(6240):
        P = F @ P @ F.T + q(N, K, dt)
    np.testing.assert_allclose(P, van_loan(N, K, 60.0), rtol=1e-9)
    # (a) and (b): over one 104 Hz step the walk's share of the angle's variance is a few 1e-8; equal at √3·N/K
    assert 1e-8 < K**2 * dt**2 / 3 / N**2 < 1e-7
    T = np.sqrt(3) * N / K
    Q = van_loan(N, K, T)
    assert Q[0, 0] == pytest.approx(2 * N**2 * T, rel=1e-9)


def test_the_datasheet_question_converts_with_scipys_units_and_leaves_b_out(lab):
    """Question 3: 0.15 °/√h and 20 °/h/√h in SI by scipy.constants; B changes nothing; the walk takes over at
    √3·N/K ≈ 47 s, as the model answer says."""
    N = 0.15 * constants.degree / np.sqrt(constants.hour)
    K = 20.0 * constants.degree / constants.hour / np.sqrt(constants.hour)
    got = lab["q_from_datasheet"](0.15, 2.0, 20.0, 1 / 104)
    np.testing.assert_allclose(got, van_loan(N, K, 1 / 104), rtol=1e-9)
    np.testing.assert_array_equal(got, lab["q_from_datasheet"](0.15, 50.0, 20.0, 1 / 104))
    assert N == pytest.approx(4.4e-5, rel=0.01) and K == pytest.approx(1.6e-6, rel=0.02)
    assert round(np.sqrt(3) * N / K) == 47


def simulated_rests(seconds, seeds, rate=datasets.STATIONARY_RATE_HZ):
    """The simulator's gyro at rest, one axis (sim.simulate_imu's model: white noise of density N, a bias that walks
    with K), N with the rounding to counts as the bundled rest has it: the fit's N and K for each seed."""
    N, K = lab02.noise_model_truth(datasets.load("02_stationary"))
    n, fits = int(seconds * rate), []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        x = N * np.sqrt(rate) * rng.normal(size=n) + np.cumsum(K / np.sqrt(rate) * rng.normal(size=n))
        n_fit, _, k_fit = allan.allan_noise_fit(*allan.allan_deviation(x, rate))
        fits.append((n_fit / N, k_fit / K))
    return np.array(fits)


@pytest.mark.slow
def test_forty_minutes_read_k_to_about_twenty_percent_and_n_to_a_percent():
    """Section 5's text: K from one 40-minute rest is known to about ±20 %, N to a percent (200 simulated rests); the
    bundled rest's three axes lie within 2 standard deviations of the truth."""
    ratios = simulated_rests(2400.0, range(200))
    assert 0.15 < ratios[:, 1].std() < 0.25 and ratios[:, 0].std() < 0.01
    N, K = lab02.noise_model_truth(rest := datasets.load("02_stationary"))
    n_fit, _, k_fit = allan.allan_noise_fit(*allan.allan_deviation(rest.body("gyr"), rest.rate_hz))
    assert np.all(np.abs(k_fit / K - 1) < 2 * ratios[:, 1].std())
    assert np.all(np.abs(n_fit / N - 1) < 0.02)


@pytest.mark.slow
def test_two_minutes_give_no_k_more_often_than_not():
    """Question 2's answer: two-minute rests give K = 0 in more than half of 200 simulated rests, and the bundled
    rest's first two minutes give 5.9 µrad/s/√s on x and 0 on y and z."""
    assert np.mean(simulated_rests(120.0, range(200))[:, 1] == 0) > 0.5
    rest = datasets.load("02_stationary")
    gyr = rest.body("gyr")[: int(120 * rest.rate_hz)]
    _, _, k_fit = allan.allan_noise_fit(*allan.allan_deviation(gyr, rest.rate_hz))
    assert k_fit[0] == pytest.approx(5.9e-6, abs=0.05e-6) and k_fit[1] == k_fit[2] == 0.0


def test_the_bundled_default_carries_the_gyros_n_and_k():
    """What labs 04 and 05 load for the Nucleo: N ≈ the datasheet's density with the rounding, K within ±40 % of the
    simulated unit's (2 standard deviations of a 40-minute fit)."""
    cal = C.Calibration.load(C.bundled_calibration_path("nucleo-iks02a1"))
    N, K = lab02.noise_model_truth(datasets.load("02_stationary"))
    np.testing.assert_allclose(cal.gyro_density, N, rtol=0.02)
    assert np.all(np.abs(np.array(cal.gyro_bias_walk) / NUCLEO_UNIT["gyro_bias_rw"] - 1) < 0.4)


@pytest.mark.slow
def test_the_calibration_lab_02_saves_from_your_own_rest_carries_n_and_k(tmp_path, monkeypatch):
    """A student's own 20-minute rest (the bundled unit, another seed) through the solution: the saved file holds the
    K the Allan fit reads on that rest, not 0, and N as σ at the filter's rate; lab 04 loads both."""
    from test_calibration_labs import run_solution_on

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    unit = {k: (np.asarray(v) if k == "mag_soft_iron" else v) for k, v in NUCLEO_UNIT.items()}
    motion = motions.stationary(1200.0, datasets.STATIONARY_RATE_HZ)
    motion.phases = [(0.0, 1200.0, "stationary")]
    rec = sim.simulate_imu(motion, board="nucleo-iks02a1", seed=77, **unit)
    rec.meta.pop("sim")  # a recording of one's own knows no truth
    path = save_recording(rec, tmp_path / "my_rest.csv")
    errors, text = run_solution_on("02_bias_and_noise.ipynb", {"STATIONARY": str(path)})
    assert errors == [] and "Warning" not in text and "saved to" in text
    saved = C.load_calibration("nucleo-iks02a1")
    gyr = rec.body("gyr")
    _, _, k_fit = allan.allan_noise_fit(*allan.allan_deviation(gyr, rec.rate_hz))
    assert np.all(k_fit > 0)
    np.testing.assert_allclose(saved.gyro_bias_walk, k_fit, rtol=1e-6)
    window = int(C.NOISE_WINDOW_S * rec.rate_hz)
    np.testing.assert_allclose(
        saved.gyro_density, rest_calibration.noise_std(gyr, window) / np.sqrt(rec.rate_hz), rtol=1e-6
    )
