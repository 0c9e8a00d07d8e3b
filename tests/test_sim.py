"""kfkit.sim and the motions it plays (kfkit.motions, attitude_motions, calibration_motions): simulated sensors
against physics (scipy rotations) and noise statistics."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit import attitude_motions, motions, sensors
from kfkit.frames import accel_tilt
from kfkit.motions import Motion, sample_times, sine_roll, stationary
from kfkit.sim import simulate_imu

g = 9.80665
deg = math.pi / 180
FIELD_N = np.array([19.5, 0.3, 45.0])  # µT, NED
Z_UP = np.diag([1.0, -1.0, -1.0])  # acc/gyr mounting on both boards (design doc)
NUCLEO_MAG = np.diag([-1.0, -1.0, 1.0])  # Z_UP · (180° about y)

# independent datasheet figures: SI per LSB and noise density (SI/√Hz)
LSB = {
    ("nucleo-iks02a1", "acc"): 0.122e-3 * g,
    ("nucleo-iks02a1", "gyr"): 17.5e-3 * deg,
    ("nucleo-iks02a1", "mag"): 0.15,
    ("mpu6050", "acc"): g / 16384,
    ("mpu6050", "gyr"): deg / 131,
}
DENSITY = {
    ("nucleo-iks02a1", "acc"): 60e-6 * g,
    ("nucleo-iks02a1", "gyr"): 5e-3 * deg,
    ("mpu6050", "acc"): 400e-6 * g,
    ("mpu6050", "gyr"): 0.005 * deg,
}
RATE = {"nucleo-iks02a1": 104.0, "mpu6050": 100.0}
MAG_RMS = 0.3  # IIS2MDC, 3 mgauss


def R_bn(roll, pitch, yaw):
    """NED → body, from scipy (R_nbᵀ with R_nb = from_euler('ZYX', [ψ, θ, φ]))."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix().T


def simulate_still(roll=0.0, pitch=0.0, yaw=0.0, board="nucleo-iks02a1", seconds=20.0, seed=0, **kw):
    """A stationary board with no bias and no bias walk (only white noise and quantisation)."""
    kw = {"gyro_bias": [0.0, 0.0, 0.0], "accel_bias": [0.0, 0.0, 0.0], "gyro_bias_rw": 0.0, "accel_bias_rw": 0.0, **kw}
    return simulate_imu(stationary(seconds, RATE[board], roll, pitch, yaw), board=board, seed=seed, **kw)


def mean_bound(board, sensor, n):
    """|mean − truth| bound: 4σ/√n for white noise plus half an LSB for quantisation."""
    sigma = MAG_RMS if sensor == "mag" else DENSITY[board, sensor] * math.sqrt(RATE[board])
    return 4 * sigma / math.sqrt(n) + 0.5 * LSB[board, sensor]


def assert_mean_close(samples, want, board, sensor):
    samples = samples[~np.isnan(samples).any(axis=1)]
    np.testing.assert_allclose(samples.mean(axis=0), want, rtol=0, atol=mean_bound(board, sensor, len(samples)))


# --- stationary physics -------------------------------------------------------------------


@pytest.mark.parametrize("board", ["nucleo-iks02a1", "mpu6050"])
def test_level_board_at_rest(board):
    rec = simulate_still(board=board)
    assert_mean_close(rec.body("acc"), [0.0, 0.0, -g], board, "acc")
    assert_mean_close(rec.body("gyr"), [0.0, 0.0, 0.0], board, "gyr")


@pytest.mark.parametrize("board", ["nucleo-iks02a1", "mpu6050"])
def test_flat_board_reads_plus_one_g_on_sensor_z(board):
    az = simulate_still(board=board)["az"]
    assert abs(az.mean() * LSB[board, "acc"] - g) < mean_bound(board, "acc", len(az))


def test_tilted_board_at_rest_accel_and_mag():
    angles = (20 * deg, -10 * deg, 30 * deg)
    rec = simulate_still(*angles)
    assert_mean_close(rec.body("acc"), R_bn(*angles) @ [0.0, 0.0, -g], "nucleo-iks02a1", "acc")
    assert_mean_close(rec.body("mag"), R_bn(*angles) @ FIELD_N, "nucleo-iks02a1", "mag")
    assert_mean_close(rec.body("gyr"), [0.0, 0.0, 0.0], "nucleo-iks02a1", "gyr")


def test_mag_sensor_frame_uses_the_rotated_mounting():
    angles = (-25 * deg, 15 * deg, -120 * deg)
    rec = simulate_still(*angles)
    want_s = NUCLEO_MAG.T @ R_bn(*angles) @ FIELD_N
    assert_mean_close(rec.sensor_si("mag"), want_s, "nucleo-iks02a1", "mag")


def test_non_symmetric_mounting_is_applied_both_ways():
    """A board whose sensors are turned 90° about z (M_bs ≠ M_bsᵀ) still gives body-frame physics."""
    M = Rotation.from_euler("z", 90, degrees=True).as_matrix()  # x_b = M x_s
    mount = {k: M.round(12).tolist() for k in ("acc", "gyr", "mag")}
    turned = dataclasses.replace(sensors.NUCLEO_IKS02A1, mount=mount)
    angles = (25 * deg, -15 * deg, 40 * deg)
    rec = simulate_imu(
        stationary(20.0, 104.0, *angles),
        board=turned,
        seed=2,
        gyro_bias=[0, 0, 0],
        accel_bias=[0, 0, 0],
        gyro_bias_rw=0,
        accel_bias_rw=0,
    )
    f_b = R_bn(*angles) @ [0.0, 0.0, -g]
    assert_mean_close(rec.sensor_si("acc"), M.T @ f_b, "nucleo-iks02a1", "acc")
    assert_mean_close(rec.body("acc"), f_b, "nucleo-iks02a1", "acc")
    assert_mean_close(rec.body("mag"), R_bn(*angles) @ FIELD_N, "nucleo-iks02a1", "mag")


def test_custom_field_is_used():
    field = np.array([10.0, -5.0, 30.0])
    rec = simulate_still(field_n=field)
    assert_mean_close(rec.body("mag"), field, "nucleo-iks02a1", "mag")
    assert rec.meta["sim"]["field_n"] == field.tolist()


@pytest.mark.parametrize("roll, pitch", [(30.0, 0.0), (-30.0, 0.0), (0.0, 20.0), (150.0, -40.0)])
def test_body_accel_gives_the_true_tilt(roll, pitch):
    rec = simulate_still(roll * deg, pitch * deg, 0.7)
    got_roll, got_pitch = accel_tilt(rec.body("acc").mean(axis=0))
    assert got_roll == pytest.approx(roll * deg, abs=0.1 * deg)
    assert got_pitch == pytest.approx(pitch * deg, abs=0.1 * deg)


def test_body_gyro_reproduces_a_constant_body_rate():
    omega_b = np.array([0.5, -0.3, 0.2])
    t = sample_times(20.0, 104.0)
    n = len(t)
    motion = Motion(t, 104.0, np.zeros((n, 3)), np.tile(omega_b, (n, 1)), np.zeros((n, 3)))
    rec = simulate_imu(motion, seed=1, gyro_bias=[0, 0, 0], accel_bias=[0, 0, 0], gyro_bias_rw=0, accel_bias_rw=0)
    assert_mean_close(rec.body("gyr"), omega_b, "nucleo-iks02a1", "gyr")
    assert_mean_close(rec.sensor_si("gyr"), Z_UP.T @ omega_b, "nucleo-iks02a1", "gyr")


def test_given_biases_are_recovered_in_the_sensor_frame():
    gyro_bias, accel_bias = np.array([0.01, -0.02, 0.03]), np.array([0.05, -0.1, 0.2])
    angles = (10 * deg, 5 * deg, 0.0)
    rec = simulate_still(*angles, gyro_bias=gyro_bias, accel_bias=accel_bias)
    physics_s = Z_UP.T @ R_bn(*angles) @ [0.0, 0.0, -g]
    assert_mean_close(rec.sensor_si("acc") - physics_s, accel_bias, "nucleo-iks02a1", "acc")
    assert_mean_close(rec.sensor_si("gyr"), gyro_bias, "nucleo-iks02a1", "gyr")
    assert rec.meta["sim"]["gyro_bias"] == gyro_bias.tolist()
    assert rec.meta["sim"]["accel_bias"] == accel_bias.tolist()


def test_default_biases_are_drawn_and_recorded():
    rec = simulate_imu(stationary(1.0, 104.0), seed=3)
    gb = np.array(rec.meta["sim"]["gyro_bias"])
    assert gb.shape == (3,) and np.all(gb != 0) and np.all(np.abs(gb) < 5 * deg)  # typ. ±1 dps


# --- noise --------------------------------------------------------------------------------


@pytest.mark.parametrize("board", ["nucleo-iks02a1", "mpu6050"])
@pytest.mark.parametrize("sensor", ["gyr", "acc"])
def test_white_noise_std_is_density_times_sqrt_rate(board, sensor):
    x = simulate_still(board=board).sensor_si(sensor)
    want = DENSITY[board, sensor] * math.sqrt(RATE[board])
    np.testing.assert_allclose(x.std(axis=0), want, rtol=0.1)


def test_mag_noise_is_the_datasheet_rms():
    m = simulate_still().sensor_si("mag")
    np.testing.assert_allclose(np.nanstd(m, axis=0), MAG_RMS, rtol=0.1)


def test_gyro_bias_random_walk_scale():
    """Brownian bias: consecutive B-second block means differ with variance rw²·2B/3."""
    rw, block, rate = 0.01, 10.0, 104.0
    rec = simulate_imu(stationary(1000.0, rate), seed=4, gyro_bias=[0, 0, 0], gyro_bias_rw=rw)
    per = int(block * rate)
    x = rec.sensor_si("gyr")
    means = x[: len(x) // per * per].reshape(-1, per, 3).mean(axis=1)
    var = np.var(np.diff(means, axis=0))
    assert 0.7 < var / (rw**2 * 2 * block / 3) < 1.4


# --- seeds --------------------------------------------------------------------------------


def test_same_seed_same_data():
    a = simulate_imu(sine_roll(duration=5.0, vibration_rms=0.2), seed=7)
    b = simulate_imu(sine_roll(duration=5.0, vibration_rms=0.2), seed=7)
    assert a.columns == b.columns and a.meta == b.meta
    for c in a.columns:
        np.testing.assert_array_equal(a[c], b[c])


def test_different_seed_different_data():
    a = simulate_imu(stationary(5.0, 104.0), seed=7)
    b = simulate_imu(stationary(5.0, 104.0), seed=8)
    for c in ("ax", "gx", "mx"):
        assert not np.array_equal(a[c], b[c], equal_nan=True)


# --- saturation ---------------------------------------------------------------------------


def constant_motion(omega_b=(0, 0, 0), acc_n=(0, 0, 0), seconds=1.0, rate=104.0):
    t = sample_times(seconds, rate)
    n = len(t)
    return Motion(
        t, rate, np.zeros((n, 3)), np.tile(omega_b, (n, 1)).astype(float), np.tile(acc_n, (n, 1)).astype(float)
    )


def test_gyro_saturates_at_full_scale():
    rec = simulate_imu(constant_motion(omega_b=(20.0, 20.0, 0.0)), seed=0)  # ±500 dps ≈ ±8.7 rad/s
    top = math.floor(500 / 17.5e-3)  # 28571 counts
    assert np.all(rec["gx"] == top)
    assert np.all(rec["gy"] == -top)  # body y = − sensor y
    assert np.all(np.abs(rec.sensor_si("gyr")[:, :2]) <= 500 * deg)


def test_mpu_accel_saturates_at_int16():
    rec = simulate_imu(
        constant_motion(acc_n=(50.0, 0.0, 0.0), rate=100.0),
        board="mpu6050",
        seed=0,
        accel_bias=[0, 0, 0],
        accel_bias_rw=0,
    )
    # f_b = a − g_n = [50, 0, −g]; sensor x = body x; ±2 g = 32768 LSB → register limit
    assert np.all(rec["ax"] == 32767)
    assert_mean_close(rec.body("acc")[:, 1:], [0.0, -g], "mpu6050", "acc")  # the other axes are fine


# --- sine_roll ----------------------------------------------------------------------------


def test_sine_roll_body_rate_is_the_roll_derivative():
    m = sine_roll(duration=40.0, rate_hz=104.0, shakes=())
    fine = sine_roll(duration=40.0, rate_hz=104.0 * 100, shakes=())  # oracle: np.gradient at 100× the rate
    roll_dot = np.gradient(fine.euler[:, 0], fine.t)[::100]
    np.testing.assert_allclose(m.omega_b[:, 0], roll_dot, atol=1e-4)
    np.testing.assert_array_equal(m.euler[:, 1:], 0.0)
    np.testing.assert_allclose(m.omega_b[:, 1:], 0.0, atol=1e-15)


def test_sine_roll_amplitude_and_frequency():
    m = sine_roll(duration=60.0, amplitude=np.radians(30.0), freq_hz=0.1, still=5.0)
    later = m.t > 6.0  # after the 1 s envelope
    np.testing.assert_allclose(
        m.euler[later, 0], np.radians(30.0) * np.sin(2 * np.pi * 0.1 * (m.t[later] - 5.0)), atol=1e-12
    )


def test_sine_roll_starts_at_rest():
    m = sine_roll(still=5.0, vibration_rms=0.0)
    rest = m.t <= 5.0
    assert rest.sum() == pytest.approx(5.0 * 104.0, abs=1)
    assert np.all(m.euler[rest] == 0) and np.all(m.omega_b[rest] == 0) and np.all(m.acc_n[rest] == 0)
    assert np.abs(m.euler[m.t > 6.0, 0]).max() > np.radians(29.0)


def test_sine_roll_shakes_only_in_their_windows():
    m = sine_roll(duration=60.0, shakes=(22.0, 42.0), shake_duration=3.0, shake_accel=3.0, vibration_rms=0.0)
    inside = ((m.t >= 22.0) & (m.t < 25.0)) | ((m.t >= 42.0) & (m.t < 45.0))
    assert np.all(m.acc_n[~inside] == 0)
    assert np.all(m.acc_n[:, [0, 2]] == 0)  # east only
    assert np.abs(m.acc_n[inside, 1]).max() == pytest.approx(3.0)
    assert abs(m.acc_n[inside, 1].mean()) < 0.05  # whole cycles


def test_sine_roll_vibration_is_seeded_white_noise():
    a = sine_roll(duration=30.0, shakes=(), vibration_rms=0.3, seed=1)
    b = sine_roll(duration=30.0, shakes=(), vibration_rms=0.3, seed=1)
    np.testing.assert_array_equal(a.acc_n, b.acc_n)
    np.testing.assert_allclose(a.acc_n.std(axis=0), 0.3, rtol=0.1)


# --- magnetometer rate --------------------------------------------------------------------


def test_mag_rows_at_a_lower_rate():
    rec = simulate_still(seconds=20.0)  # board default: mag 50 Hz, IMU 104 Hz
    fresh = ~np.isnan(rec["mx"])
    assert fresh[0]
    assert abs(fresh.sum() - 50 * 20) <= 1
    assert np.array_equal(fresh, ~np.isnan(rec["my"])) and np.array_equal(fresh, ~np.isnan(rec["mz"]))
    gaps = np.diff(rec.t[fresh])
    assert gaps.max() <= 1 / 50 + 1 / 104 and gaps.min() >= 1 / 50 - 1 / 104


@pytest.mark.parametrize("mag_rate", [10.0, 20.0])
def test_mag_rate_override(mag_rate):
    rec = simulate_still(seconds=10.0, mag_rate_hz=mag_rate)
    assert abs((~np.isnan(rec["mx"])).sum() - mag_rate * 10) <= 1


def test_mag_at_imu_rate_fills_every_row():
    assert not np.isnan(simulate_still(seconds=2.0, mag_rate_hz=104.0)["mx"]).any()


def test_board_without_mag_has_no_mag_columns():
    rec = simulate_still(board="mpu6050", seconds=1.0)
    assert not {"mx", "my", "mz"} & set(rec.columns)
    assert "mag" not in rec.meta["sensors"] and "mag" not in rec.meta["mount"]


# --- recording layout ---------------------------------------------------------------------


def test_recording_columns_times_and_truth():
    m = sine_roll(duration=3.0)
    rec = simulate_imu(m, seed=0)
    assert rec.columns[:2] == ["t", "seq"]
    np.testing.assert_allclose(rec.t, np.arange(len(rec)) / 104.0)
    np.testing.assert_array_equal(rec.truth(), m.euler)
    assert rec.meta["rate_hz"] == 104.0 and rec.meta["board"] == "nucleo-iks02a1"
    for c in ("ax", "gy", "seq"):
        assert np.issubdtype(rec[c].dtype, np.integer)


def test_seq_wraps_at_16_bits():
    rec = simulate_imu(stationary(70.0, 1000.0), seed=0)
    seq = rec["seq"]
    assert seq[65535] == 65535 and seq[65536] == 0 and seq.max() == 65535


def test_sample_times():
    np.testing.assert_array_equal(sample_times(1.0, 4.0), [0.0, 0.25, 0.5, 0.75])
    assert len(sample_times(60.0, 104.0)) == 6240


# --- attitude motions (lab 04) --------------------------------------------------------------

ATTITUDE_MOTIONS = {
    "attitude_tour": lambda: attitude_motions.attitude_tour(vibration_rms=0.1, seed=1),
    "pitch_over": attitude_motions.pitch_over,
    "yaw_sweeps": attitude_motions.yaw_sweeps,
}


def scipy_attitude(euler):
    """R_nb as scipy Rotations from [roll, pitch, yaw] rows."""
    return Rotation.from_euler("ZYX", np.asarray(euler)[:, ::-1])


@pytest.mark.parametrize("name", ATTITUDE_MOTIONS)
def test_integrating_the_body_rate_reproduces_the_attitude(name):
    """Oracle: scipy rotations, R_{k+1} = R_k · exp([ω̄ Δt]×) with the mid-interval rate."""
    m = ATTITUDE_MOTIONS[name]()
    dt = 1.0 / m.rate_hz
    steps = Rotation.from_rotvec(0.5 * (m.omega_b[1:] + m.omega_b[:-1]) * dt)
    R = scipy_attitude(m.euler[:1])[0]
    worst = 0.0
    truth = scipy_attitude(m.euler)
    for k, step in enumerate(steps, start=1):
        R = R * step
        worst = max(worst, (truth[k].inv() * R).magnitude())
    assert worst < 0.01 * deg  # second-order integration error over the whole motion


@pytest.mark.parametrize("name", ATTITUDE_MOTIONS)
def test_body_rate_matches_finite_differences_of_the_attitude(name):
    """ω_b ≈ log(R_kᵀ R_{k+1}) / Δt between neighbouring samples (central, so O(Δt²))."""
    m = ATTITUDE_MOTIONS[name]()
    R = scipy_attitude(m.euler)
    dt = 1.0 / m.rate_hz
    fd = (R[1:-1].inv() * R[2:]).as_rotvec() / (2 * dt) + (R[:-2].inv() * R[1:-1]).as_rotvec() / (2 * dt)
    np.testing.assert_allclose(fd, m.omega_b[1:-1], atol=2e-3)  # rad/s; peak rates reach ~1 rad/s


@pytest.mark.parametrize("name", ATTITUDE_MOTIONS)
def test_attitude_motion_truth_is_canonical_and_rests_are_still(name):
    m = ATTITUDE_MOTIONS[name]()
    assert np.all(np.abs(m.euler[:, 1]) <= np.pi / 2 + 1e-12)
    assert np.all(np.abs(m.euler[:, [0, 2]]) <= np.pi + 1e-12)
    labels = {p[2] for p in m.phases}
    assert "stationary" in labels
    rec = simulate_imu(m, seed=0)
    rest = rec.phase("stationary")
    assert rest.sum() > 2 * m.rate_hz
    np.testing.assert_array_equal(m.omega_b[rest], 0.0)
    np.testing.assert_array_equal(m.acc_n[rest], 0.0)


def test_attitude_tour_phases_and_motions():
    m = attitude_motions.attitude_tour()
    rec = simulate_imu(m, seed=0)
    assert {p["label"] for p in rec.phases} == {"stationary", "roll", "pitch", "yaw", "linear_acceleration", "tumble"}
    spans = {label: np.ptp(m.euler[rec.phase(label)], axis=0) for label in ("roll", "pitch")}
    assert spans["roll"][0] == pytest.approx(80 * deg) and spans["roll"][1:].max() < 1e-9
    assert spans["pitch"][1] == pytest.approx(72 * deg) and spans["pitch"][[0, 2]].max() < 1e-9
    yaw = m.euler[rec.phase("yaw"), 2]
    assert np.any(np.abs(np.diff(yaw)) > np.pi), "the yaw turn should cross ±180°"
    slide = rec.phase("linear_acceleration")
    assert np.abs(m.acc_n[slide]).max() > 3.5 and np.all(m.acc_n[~slide] == 0.0)
    np.testing.assert_array_equal(m.omega_b[slide], 0.0)  # sliding at constant attitude
    dt = 1.0 / m.rate_hz  # integrate twice (trapezoid): the board ends at rest where it started
    v = np.cumsum(m.acc_n[slide], axis=0) * dt
    assert np.abs(v[-1]).max() < 1e-9 and np.abs(v.sum(axis=0) * dt).max() < 1e-3 and np.abs(v).max() < 1.0
    # ‖f‖ = ‖a_n − g_n‖: a horizontal push changes the norm only to second order
    f = np.linalg.norm(rec.body("acc"), axis=1)
    assert np.abs(f[rec.phase("stationary")] - g).max() < 0.05
    want = np.linalg.norm(m.acc_n - [0.0, 0.0, g], axis=1)
    np.testing.assert_allclose(f[slide], want[slide], atol=0.05)
    assert np.abs(f[slide] - g).max() > 0.4


def test_pitch_over_goes_through_vertical():
    m = attitude_motions.pitch_over(peak=110 * deg, wobble=0.0, yaw0=30 * deg)
    nose = scipy_attitude(m.euler).apply([1.0, 0.0, 0.0])  # body x in NED
    assert nose[:, 2].min() < -np.cos(1 * deg) and nose[:, 2].max() > np.cos(1 * deg)  # straight up, straight down
    hold = (m.t > 9.2) & (m.t < 10.8)  # held at 110° nose up: past vertical, the nose points backwards
    want = Rotation.from_euler("ZYX", [30, 110, 0], degrees=True).as_euler(
        "ZYX", degrees=True
    )  # scipy's canonical triple
    got = np.degrees(m.euler[hold].mean(axis=0))[::-1]
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert got[1] == pytest.approx(70.0) and abs(got[2]) == pytest.approx(180.0)
    near = simulate_imu(m, seed=0).phase("near_vertical")
    np.testing.assert_array_equal(near, np.abs(nose[:, 2]) > np.cos(10 * deg))


def test_mag_disturbance_field_and_its_effect():
    m = stationary(20.0, 104.0, 10 * deg, -5 * deg, 40 * deg)
    m.phases = [(5.0, 15.0, "mag_disturbance")]
    field = np.array([-4.0, 6.0, -3.0])
    d = attitude_motions.mag_disturbance(m, field=field)
    assert np.all(d[(m.t < 5.0) | (m.t >= 15.0)] == 0.0)
    middle = (m.t >= 6.0) & (m.t < 14.0)  # after the 1 s fade-in, before the fade-out
    np.testing.assert_allclose(d[middle], np.tile(field, (middle.sum(), 1)))
    assert np.all(np.linalg.norm(d, axis=1) <= np.linalg.norm(field) + 1e-12)
    rec = simulate_imu(m, seed=5, gyro_bias=[0, 0, 0], accel_bias=[0, 0, 0], mag_disturbance=d)
    mag = rec.body("mag")
    assert_mean_close(mag[middle], R_bn(10 * deg, -5 * deg, 40 * deg) @ (FIELD_N + field), "nucleo-iks02a1", "mag")
    assert_mean_close(mag[m.t < 5.0], R_bn(10 * deg, -5 * deg, 40 * deg) @ FIELD_N, "nucleo-iks02a1", "mag")


def test_no_mag_disturbance_draws_nothing_extra():
    m = stationary(2.0, 104.0, 0.1, 0.2, 0.3)
    plain = simulate_imu(m, seed=9)
    zero = simulate_imu(m, seed=9, mag_disturbance=np.zeros((len(m.t), 3)))
    for c in plain.columns:
        np.testing.assert_array_equal(plain[c], zero[c])


def test_bad_mag_disturbance_inputs_are_named():
    m = stationary(2.0, 104.0)
    with pytest.raises(
        ValueError, match="mag_disturbance must be one NED vector per sample, shape \\(208, 3\\); got \\(3,\\)"
    ):
        simulate_imu(m, mag_disturbance=np.ones(3))
    with pytest.raises(ValueError, match="no phase 'mag_disturbance'"):
        attitude_motions.mag_disturbance(m)


def test_euler_moves_are_smooth_steps():
    t = sample_times(4.0, 1000.0)
    euler, rate = motions.euler_moves(t, [0.1, 0.0, 0.0], [(1.0, 3.0, 0, 0.5)])
    assert euler[0, 0] == 0.1 and euler[-1, 0] == pytest.approx(0.6)
    assert euler[t == 2.0, 0] == pytest.approx(0.35)  # halfway in time is halfway in angle (symmetric step)
    np.testing.assert_allclose(rate[1:-1, 0], np.gradient(euler[:, 0], t)[1:-1], atol=1e-5)
    assert rate[0, 0] == 0.0 and rate[-1, 0] == 0.0 and rate[:, 1:].max() == 0.0


# --- calibration motions and imperfections (calibration helper) ------------------------------


def test_imperfections_default_to_nothing_and_are_recorded():
    plain = simulate_imu(stationary(2.0, 104.0), seed=5)
    same = simulate_imu(stationary(2.0, 104.0), seed=5, accel_scale=None, mag_hard_iron=None)
    assert plain.meta == same.meta and all(
        np.array_equal(plain.data[k], same.data[k], equal_nan=True) for k in plain.data
    )
    iron = simulate_imu(
        stationary(2.0, 104.0),
        seed=5,
        accel_scale=[1.0, 1.0, 1.1],
        mag_hard_iron=[30.0, 0.0, 0.0],
        mag_soft_iron=2 * np.eye(3),
    )
    assert iron.meta["sim"]["mag_hard_iron"] == [30.0, 0.0, 0.0] and iron.meta["sim"]["accel_scale"][2] == 1.1
    # soft iron doubles the field, hard iron adds 30 µT on sensor x (the same random draws otherwise)
    fresh = ~np.isnan(plain["mx"])
    m0, m1 = plain.sensor_si("mag")[fresh], iron.sensor_si("mag")[fresh]
    np.testing.assert_allclose(m1.mean(0), 2 * m0.mean(0) + [30.0, 0, 0], atol=1.0)
    # accel z reads g·1.1 (sensor z up reads +g when flat)
    assert iron.sensor_si("acc")[:, 2].mean() == pytest.approx(1.1 * plain.sensor_si("acc")[:, 2].mean(), rel=1e-3)


def test_six_faces_labels_the_axis_that_reads_plus_g():
    from kfkit.calibration_motions import six_faces
    from kfkit.frames import G

    m = six_faces(seed=2)
    assert sorted(p[2] for p in m.phases) == sorted(["x_up", "x_down", "y_up", "y_down", "z_up", "z_down"])
    rec = simulate_imu(m, seed=0, accel_bias=np.zeros(3), gyro_bias=np.zeros(3))
    for label in ("x_up", "x_down", "y_up", "y_down", "z_up", "z_down"):
        mask = rec.phase(label)
        assert np.abs(rec.body("gyr")[mask]).max() < 0.02  # resting, not moving
        f = rec.body("acc")[mask].mean(axis=0)
        i = "xyz".index(label[0])
        assert f[i] == pytest.approx(G if label.endswith("up") else -G, abs=0.02)


def test_calibration_motions_rates_match_their_attitudes():
    from scipy.spatial.transform import Rotation

    from kfkit.calibration_motions import axis_turns, heading_steps, mag_rotations, six_faces

    for m in (six_faces(), mag_rotations(duration=30.0), axis_turns(), heading_steps()):
        R = Rotation.from_euler("ZYX", m.euler[:, ::-1])
        step = (R[:-1].inv() * R[1:]).as_rotvec() * m.rate_hz  # body rate between samples, finite difference
        np.testing.assert_allclose(step, (m.omega_b[1:] + m.omega_b[:-1]) / 2, atol=2e-3)


def test_mag_rotations_cover_the_sphere_and_axis_turns_label_each_axis():
    from scipy.spatial.transform import Rotation

    from kfkit.calibration_motions import axis_turns, mag_rotations

    m = mag_rotations()
    u = Rotation.from_euler("ZYX", m.euler[:, ::-1]).inv().apply([19.5, 0.3, 45.0])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    assert np.linalg.eigvalsh(np.cov(u.T)).min() > 0.15  # the field seen from all directions
    assert m.phases == [(0.0, 60.0, "mag_rotations")]
    turns = axis_turns()
    for t0, t1, label in turns.phases:
        inside = (turns.t >= t0) & (turns.t < t1)
        axis = "xyz".index(label[-1])
        others = [i for i in range(3) if i != axis]
        assert (
            np.abs(turns.omega_b[inside][:, axis]).max() > 0.3 and np.abs(turns.omega_b[inside][:, others]).max() < 1e-9
        )
