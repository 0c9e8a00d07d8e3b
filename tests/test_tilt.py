"""Lab 05's [angle, gyro bias] filter against filterpy, its gates, bias convergence, bad input; the tilt protocol."""
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from kfkit import datasets, sim
from kfkit.filters import TiltBiasKF, TiltRun, accel_static_ok
from kfkit.frames import accel_tilt

g = 9.80665
deg = math.pi / 180
DT = 0.01


def filterpy_oracle(dt, q_angle, q_bias, r, x0, P0):
    """The textbook model in filterpy's general KalmanFilter (Joseph-form update)."""
    kf = FilterpyKF(dim_x=2, dim_z=1, dim_u=1)
    kf.F = np.array([[1.0, -dt], [0.0, 1.0]])
    kf.B = np.array([[dt], [0.0]])
    kf.H = np.array([[1.0, 0.0]])
    kf.Q = np.diag([q_angle, q_bias])
    kf.R = np.array([[r]])
    kf.x = np.array([[x0[0]], [x0[1]]])
    kf.P = np.array(P0, dtype=float)
    return kf


def random_inputs(rng, n=400):
    return rng.normal(0.0, 0.5, n), rng.normal(0.0, 0.3, n), rng.random(n) > 0.3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ungated_filter_matches_filterpy(seed):
    rng = np.random.default_rng(seed)
    w, z, _ = random_inputs(rng)
    q_angle, q_bias, r = 10 ** rng.uniform(-7, -3), 10 ** rng.uniform(-12, -6), 10 ** rng.uniform(-5, -1)
    x0, P0 = (0.1, -0.02), np.array([[0.03, 0.001], [0.001, 0.01]])
    run = TiltBiasKF(DT, q_angle, q_bias, r, gate="none").run(w, z, rng.random(len(z)) > 0.5, x0=x0, P0=P0)
    oracle = filterpy_oracle(DT, q_angle, q_bias, r, x0, P0)
    for k in range(len(z)):
        oracle.predict(u=np.array([[w[k]]]))
        oracle.update(np.array([[z[k]]]))
        np.testing.assert_allclose(run.x[k], oracle.x[:, 0], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(run.P[k], oracle.P, rtol=1e-8, atol=1e-15)
        np.testing.assert_allclose([run.y[k], run.S[k]], [oracle.y[0, 0], oracle.S[0, 0]], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("gate", ["skip", "inflate"])
def test_gates_match_filterpy_with_no_update_or_an_inflated_r(gate):
    rng = np.random.default_rng(7)
    w, z, ok = random_inputs(rng)
    q_angle, q_bias, r, inflation = 1e-5, 1e-9, 1e-3, 50.0
    x0, P0 = (0.0, 0.0), np.diag([r, 0.01])
    run = TiltBiasKF(DT, q_angle, q_bias, r, gate=gate, inflation=inflation).run(w, z, ok, x0=x0, P0=P0)
    oracle = filterpy_oracle(DT, q_angle, q_bias, r, x0, P0)
    for k in range(len(z)):
        oracle.predict(u=np.array([[w[k]]]))
        if ok[k]:
            oracle.update(np.array([[z[k]]]))
        elif gate == "inflate":
            oracle.update(np.array([[z[k]]]), R=np.array([[r * inflation]]))
        np.testing.assert_allclose(run.x[k], oracle.x[:, 0], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(run.P[k], oracle.P, rtol=1e-8, atol=1e-15)
    skipped = np.isnan(run.y)
    assert np.array_equal(skipped, ~ok if gate == "skip" else np.zeros_like(ok))
    assert np.array_equal(run.gated, ~ok)


def test_a_gated_sample_coasts_on_the_gyro():
    kf = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3, gate="skip", x0=(0.2, 0.05))
    angle, bias, y, S = kf.step(1.0, 5.0, static_ok=False)  # a wild accel angle, but gated
    assert angle == pytest.approx(0.2 + (1.0 - 0.05) * DT) and bias == 0.05
    assert math.isnan(y) and math.isnan(S)


def test_nan_accel_angle_skips_the_update_in_every_gate_mode():
    for gate in ("none", "skip", "inflate"):
        kf = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3, gate=gate)
        angle, bias, y, _ = kf.step(0.5, float("nan"), True)
        assert angle == pytest.approx(0.005) and bias == 0.0 and math.isnan(y)


def test_inflated_update_moves_less_than_a_full_one():
    full = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3, gate="inflate").step(0.0, 0.1, True)[0]
    weak = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3, gate="inflate").step(0.0, 0.1, False)[0]
    assert 0 < weak < full


def simulated_tilt(bias_b, seconds=40.0, seed=3):
    """A board at rest, tilted 20° in pitch, with a known constant gyro bias (body y, rad/s)."""
    motion = sim.stationary(seconds, 100.0, pitch=20 * deg)
    # MPU6050 mounting flips y and z: body y bias b ↔ sensor y bias −b
    return sim.simulate_imu(motion, board="mpu6050", seed=seed, gyro_bias=[0.0, -bias_b, 0.0],
                            accel_bias=[0.0, 0.0, 0.0], gyro_bias_rw=0.0)


@pytest.mark.parametrize("bias_deg", [-3.0, 1.5, 6.0])
def test_bias_converges_to_the_simulated_bias(bias_deg):
    rec = simulated_tilt(bias_deg * deg)
    _, pitch = accel_tilt(rec.body("acc"))
    sigma_w = 0.005 * deg * 10  # MPU6050 rate noise density × √100 Hz
    run = TiltBiasKF(0.01, (sigma_w * 0.01) ** 2 * 100, 1e-12, np.var(pitch)).run(rec.body("gyr")[:, 1], pitch)
    settled = rec.t > 30.0
    # within 2 % of the bias and the angle within 0.1° of the truth once settled
    np.testing.assert_allclose(run.bias[settled], bias_deg * deg, rtol=0.02)
    assert np.max(np.abs(run.angle[settled] - 20 * deg)) < 0.1 * deg
    # the filter's own σ_b has shrunk below the 2 % it achieved
    assert np.sqrt(run.P[-1, 1, 1]) < 0.02 * abs(bias_deg) * deg


def test_skip_gate_rejects_a_linear_acceleration():
    """Sideways shove while level: the accel roll lies; the gated filter does not follow it."""
    motion = sim.stationary(20.0, 100.0)
    inside = (motion.t >= 10.0) & (motion.t < 11.0)
    motion.acc_n[inside, 1] = 3.0  # m/s² east for one second
    rec = sim.simulate_imu(motion, board="mpu6050", seed=4, gyro_bias=[0.0, 0.0, 0.0], accel_bias=[0.0, 0.0, 0.0])
    f = rec.body("acc")
    roll, _ = accel_tilt(f)
    # a push ⊥ gravity changes ‖f‖ only by ≈ a²/2g (0.45 m/s² here): the default 0.05 g lets it through
    assert accel_static_ok(f)[inside].mean() > 0.5
    ok = accel_static_ok(f, eps=0.02 * g)
    assert not ok[inside].any() and ok[~inside].mean() > 0.99
    runs = {gate: TiltBiasKF(0.01, 1e-6, 1e-10, 1.6e-5, gate=gate).run(rec.body("gyr")[:, 0], roll, ok)
            for gate in ("none", "skip", "inflate")}
    peak = {gate: np.max(np.abs(run.angle[inside])) for gate, run in runs.items()}
    assert peak["none"] > 5 * deg          # the ungated filter follows the shove's false tilt (17°)
    assert peak["skip"] < 0.3 * deg
    assert peak["skip"] < peak["inflate"] < peak["none"]


def test_accel_static_ok():
    assert accel_static_ok([0.0, 0.0, -g]) is True
    assert accel_static_ok([0.0, 0.0, -g - 0.2], eps=0.1) is False
    assert accel_static_ok([0.0, 0.5, -g], eps=0.1) is True  # tilted a little: the norm is still ≈ g
    f = np.array([[0.0, 0.0, -g], [0.0, 0.0, -1.05 * g], [g, 0.0, 0.0]])
    assert accel_static_ok(f, eps=0.02 * g).tolist() == [True, False, True]


def test_run_returns_a_tilt_run_with_named_views():
    rng = np.random.default_rng(0)
    w, z, ok = random_inputs(rng, 50)
    run = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3).run(w, z, ok)
    assert isinstance(run, TiltRun)
    assert run.x.shape == (50, 2) and run.P.shape == (50, 2, 2) and run.y.shape == run.S.shape == (50,)
    assert np.array_equal(run.angle, run.x[:, 0]) and np.array_equal(run.bias, run.x[:, 1])
    assert np.allclose(run.P, np.swapaxes(run.P, 1, 2))


# --- bad input ----------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, match", [
    ({"dt": 0.0}, "dt must be a positive"),
    ({"q_angle": -1e-6}, "q_angle must be a positive"),
    ({"q_bias": float("nan")}, "q_bias must be a number ≥ 0"),
    ({"r": float("inf")}, "r must be a positive"),
    ({"gate": "sometimes"}, "gate must be one of none, skip, inflate, got 'sometimes'"),
    ({"x0": (0.0,)}, "x0 must have 2 values"),
])
def test_bad_settings_are_named(kwargs, match):
    args = {"dt": DT, "q_angle": 1e-5, "q_bias": 1e-9, "r": 1e-3, **kwargs}
    with pytest.raises(ValueError, match=match):
        TiltBiasKF(**args)


def test_bad_run_inputs_are_named():
    kf = TiltBiasKF(DT, 1e-5, 1e-9, 1e-3)
    with pytest.raises(ValueError, match=r"equal length, got shapes \(3,\), \(2,\)"):
        kf.run([0.0, 0.0, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="no samples"):
        kf.run([], [])
    with pytest.raises(ValueError, match=r"gyro_rate\[1\] is nan"):
        kf.run([0.0, float("nan")], [0.0, 0.0])
    with pytest.raises(ValueError, match="3 components"):
        accel_static_ok([1.0, 2.0])
    with pytest.raises(ValueError, match="eps must be a positive"):
        accel_static_ok([0.0, 0.0, -g], eps=0.0)


# --- the tilt protocol --------------------------------------------------------------------

def test_tilt_protocol_phases_and_angles():
    m = sim.tilt_protocol(axes=("pitch", "roll"), hold=2.0, move=1.5, rate_hz=100.0, seed=0)
    assert len(m.t) == 1800 and m.t[1] == pytest.approx(0.01)
    assert [p[2] for p in m.phases] == ["pitch_0", "pitch_90", "pitch_0", "roll_0", "roll_90", "roll_0"]
    assert m.phases[1][:2] == (3.5, 5.5) and m.phases[4][:2] == (12.5, 14.5)
    for t0, t1, label in m.phases:
        inside = (m.t >= t0) & (m.t < t1)
        want = np.zeros(3)
        want[("roll", "pitch").index(label.split("_")[0])] = 90 * deg if label.endswith("_90") else 0.0
        np.testing.assert_allclose(m.euler[inside], np.tile(want, (inside.sum(), 1)), atol=1e-12)
        assert np.all(m.omega_b[inside] == 0) and np.all(m.acc_n[inside] == 0)  # holds are still


def test_tilt_protocol_rates_integrate_to_the_angles():
    m = sim.tilt_protocol(axes=("roll", "pitch"), rate_hz=1000.0)
    # single-axis turns from level: body rate = Euler rate of that axis (p = φ̇ at θ = 0; q = θ̇ at φ = 0)
    for col in (0, 1):
        integrated = np.concatenate([[0.0], np.cumsum(0.5 * (m.omega_b[1:, col] + m.omega_b[:-1, col]) / 1000.0)])
        np.testing.assert_allclose(integrated, m.euler[:, col], atol=1e-5)


def test_tilt_protocol_bad_axis():
    with pytest.raises(ValueError, match=r"axes must be 'roll' or 'pitch', got \['yaw'\]"):
        sim.tilt_protocol(axes=("yaw",))


def test_bundled_tilt_recording_accel_agrees_with_the_labels():
    rec = datasets.load("05_tilt_protocol")
    assert rec.meta["board"] == "mpu6050" and rec.rate_hz == 100.0 and rec.t[-1] > 30.0
    roll, pitch = accel_tilt(rec.body("acc"))
    # uncorrected accelerometer: within 3° (biases of 15–25 mg) of each hold's label
    assert abs(np.degrees(np.median(pitch[rec.phase("pitch_90")])) - 90) < 3
    assert abs(np.degrees(np.median(roll[rec.phase("roll_90")])) - 90) < 3
    assert abs(np.degrees(np.median(pitch[rec.phase("roll_0")]))) < 3
