"""kfkit.calibration against known simulated parameters, random ellipsoids, an independent Allan
deviation (allantools, and a non-overlapping estimator written here), and the saved JSON."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit import calibration as C
from kfkit import datasets, sim
from kfkit.checkpoints import get, run_checkpoint
from kfkit.checkpoints.lab03 import random_ellipsoid
from kfkit.frames import G, MAG_FIELD_LONDON, mount_matrix
from kfkit.io import load_recording, save_recording

B_LONDON = np.linalg.norm(MAG_FIELD_LONDON)


# --- bias and noise on a simulated board with known parameters --------------------------------

def test_gyro_bias_and_noise_match_simulated_truth():
    bias_s = np.radians([0.5, -0.3, 0.8])
    rec = sim.simulate_imu(sim.stationary(60.0, 104.0), seed=3, gyro_bias=bias_s, gyro_bias_rw=0.0)
    gyr = rec.body("gyr")
    sigma = rec_sigma = 5e-3 * np.pi / 180 * np.sqrt(104.0)  # datasheet density · √rate
    truth = mount_matrix(rec.meta["mount"]["gyr"]) @ bias_s
    assert np.all(np.abs(C.gyro_bias(gyr) - truth) < 4 * sigma / np.sqrt(len(gyr)))
    lsb = rec.meta["sensors"]["gyr"]["sensitivity"]
    expected = np.sqrt(rec_sigma**2 + lsb**2 / 12)  # white noise plus quantisation
    np.testing.assert_allclose(C.noise_std(gyr), expected, rtol=0.05)


def test_noise_std_windows_leave_out_a_slow_drift():
    rng = np.random.default_rng(1)
    t = np.arange(20000)
    x = rng.normal(0, 0.1, (20000, 3)) + (t / 20000 * 5.0)[:, None]  # drift of 5 over the record
    assert C.noise_std(x)[0] > 1.0
    np.testing.assert_allclose(C.noise_std(x, window=100), 0.1, rtol=0.03)


def test_accel_bias_keeps_gravity_out():
    rec = sim.simulate_imu(sim.stationary(30.0, 104.0), seed=4, accel_bias=[0.05, -0.02, 0.03], accel_bias_rw=0.0)
    b = C.accel_bias(rec.body("acc"), [0.0, 0.0, -G])
    truth = mount_matrix(rec.meta["mount"]["acc"]) @ [0.05, -0.02, 0.03]
    np.testing.assert_allclose(b, truth, atol=5e-4)


def test_six_face_recovers_simulated_bias_and_scale():
    bias_s, scale = np.array([0.06, -0.04, 0.09]), np.array([1.01, 0.994, 1.003])
    rec = sim.simulate_imu(sim.six_faces(seed=5), seed=6, accel_bias=bias_s, accel_scale=scale, accel_bias_rw=0.0)
    faces = {f: rec.body("acc")[rec.phase(f)] for f in C.FACES}
    b, s = C.accel_six_face(faces)
    np.testing.assert_allclose(b, mount_matrix(rec.meta["mount"]["acc"]) @ bias_s, atol=2e-3)
    np.testing.assert_allclose(s, scale, atol=3e-4)
    # a bias-only calibration (level rest) mixes the z scale error into the z bias
    level = C.accel_bias(faces["z_down"], [0.0, 0.0, -G])
    z_true = (mount_matrix(rec.meta["mount"]["acc"]) @ bias_s)[2]
    assert abs(level[2] - (z_true - (scale[2] - 1) * G)) < 2e-3


def test_six_face_errors_name_the_problem():
    rng = np.random.default_rng(0)
    faces = {f: rng.normal(0, 0.01, (20, 3)) for f in C.FACES}
    with pytest.raises(C.CalibrationError, match="axis x reads"):
        C.accel_six_face(faces)
    with pytest.raises(C.CalibrationError, match="missing z_down"):
        C.accel_six_face({f: v for f, v in faces.items() if f != "z_down"})


@pytest.mark.parametrize("func", [C.gyro_bias, C.noise_std, lambda x: C.accel_bias(x, [0, 0, -G])])
@pytest.mark.parametrize("bad, match", [
    (np.zeros((1, 3)), "1 samples, at least 2"),
    (np.zeros((10, 2)), r"expected shape \(N, 3\), got \(10, 2\)"),
    (np.zeros(3), "one vector"),
    (np.vstack([np.zeros((5, 3)), [[0.0, np.nan, 0.0]]]), "1 of 6 samples hold NaN or inf .first at row 5"),
])
def test_bad_input_raises_clear_errors(func, bad, match):
    with pytest.raises(C.CalibrationError, match=match):
        func(bad)


def test_accel_bias_expected_must_be_a_vector():
    with pytest.raises(C.CalibrationError, match=r"shape \(3,\)"):
        C.accel_bias(np.zeros((5, 3)), -G)


# --- Allan deviation ----------------------------------------------------------------------------

def allan_nonoverlapping(x, rate_hz, m):
    """Independent estimator: averages of consecutive clusters of m samples, σ² = ½⟨(ȳ_{k+1} − ȳ_k)²⟩."""
    y = x[: len(x) // m * m].reshape(-1, m).mean(axis=1)
    return np.sqrt(0.5 * np.mean(np.diff(y) ** 2))


def slope(taus, adev):
    return np.polyfit(np.log(taus), np.log(adev), 1)[0]


def test_allan_matches_allantools():
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(7)
    rate = 50.0
    x = rng.normal(0, 1e-3, 20000) + np.cumsum(rng.normal(0, 2e-6, 20000))
    taus = np.array([0.02, 0.1, 0.5, 2.0, 10.0, 50.0])
    ours = C.allan_deviation(x, rate, taus)[1]
    t2, ad, _, _ = allantools.oadev(x, rate=rate, data_type="freq", taus=taus)
    np.testing.assert_allclose(t2, taus)
    np.testing.assert_allclose(ours, ad, rtol=1e-9)


def test_allan_agrees_with_nonoverlapping_estimator():
    rng = np.random.default_rng(8)
    x = rng.normal(0, 1.0, 100000)
    for m in (1, 10, 100):
        taus, ours = C.allan_deviation(x, 10.0, [m / 10.0])
        ref = allan_nonoverlapping(x, 10.0, m)
        clusters = len(x) // m
        assert abs(ours[0] - ref) < 4 * ref / np.sqrt(clusters)  # both within sampling error of each other


def test_allan_slopes_of_white_noise_and_random_walk():
    rng = np.random.default_rng(9)
    rate, n = 100.0, 200000
    white = rng.normal(0, 0.01, n)  # σ per sample → N = σ/√rate
    taus, ad = C.allan_deviation(white, rate)
    keep = taus < 50
    assert abs(slope(taus[keep], ad[keep]) + 0.5) < 0.03
    assert abs(C.angle_random_walk(taus, ad) - 0.01 / np.sqrt(rate)) < 0.03 * 0.01 / np.sqrt(rate)
    K = 1e-4
    walk = np.cumsum(rng.normal(0, K / np.sqrt(rate), n))  # rate random walk of density K
    taus, ad = C.allan_deviation(walk, rate)
    keep = (taus > 1) & (taus < 100)
    assert abs(slope(taus[keep], ad[keep]) - 0.5) < 0.1
    # σ(τ) = K √(τ/3) for a rate random walk (IEEE 952)
    np.testing.assert_allclose(ad[keep] / (K * np.sqrt(taus[keep] / 3)), 1.0, atol=0.35)


def test_bias_instability_reads_the_minimum():
    taus = np.logspace(-1, 3, 41)
    adev = 1e-3 / np.sqrt(taus) + 1e-5 * np.sqrt(taus)
    B, tau_min = C.bias_instability(taus, adev)
    assert tau_min == pytest.approx(100.0, rel=0.15)
    assert B == pytest.approx(2e-4 / 0.664, rel=0.01)
    assert C.BIAS_INSTABILITY_FACTOR == pytest.approx(0.664, abs=5e-4)


def test_allan_bad_input():
    with pytest.raises(C.CalibrationError, match="at least 9"):
        C.allan_deviation(np.zeros(5), 10.0)
    with pytest.raises(C.CalibrationError, match="under half the record"):
        C.allan_deviation(np.zeros(100), 10.0, taus=[6.0])
    with pytest.raises(C.CalibrationError, match="span τ = 1 s"):
        C.angle_random_walk([2.0, 4.0], [1.0, 0.5])


# --- magnetometer calibration ------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_random_ellipsoids(seed):
    rng = np.random.default_rng(seed)
    mag, h, W = random_ellipsoid(rng, n=600, noise=0.05)
    h_fit, S = C.fit_mag_calibration(mag)
    np.testing.assert_allclose(h_fit, h, atol=0.05)
    np.testing.assert_allclose(S, np.linalg.inv(W), atol=2e-3)  # W symmetric: S = W⁻¹ exactly
    np.testing.assert_allclose(S, S.T)
    norms = np.linalg.norm((mag - h_fit) @ S.T, axis=1)
    assert abs(norms.mean() - B_LONDON) < 0.02 and norms.std() < 0.1


def test_fit_scales_to_the_given_field_norm():
    mag, h, W = random_ellipsoid(np.random.default_rng(11), field_norm=30.0, noise=0.0)
    _, S = C.fit_mag_calibration(mag, field_norm=30.0)
    np.testing.assert_allclose(S, np.linalg.inv(W), atol=1e-9)


def test_fit_on_simulated_board_recovers_body_frame_iron():
    rec = datasets.load("03_mag_rotations")
    h, S = C.fit_mag_calibration(rec.body("mag"))
    M = mount_matrix(rec.meta["mount"]["mag"])
    W = np.asarray(rec.meta["sim"]["mag_soft_iron"])
    np.testing.assert_allclose(h, M @ rec.meta["sim"]["mag_hard_iron"], atol=0.1)
    np.testing.assert_allclose(S, np.linalg.inv(M @ W @ M.T), atol=5e-3)


def test_fit_rejects_poor_coverage_and_says_what_to_do():
    rec = sim.simulate_imu(sim.heading_steps(tilt=(0.0, 0.0)), seed=1, mag_hard_iron=[10.0, 0.0, 0.0])
    with pytest.raises(C.CalibrationError, match="cover too little of the sphere.*every orientation"):
        C.fit_mag_calibration(rec.body("mag"))


@pytest.mark.parametrize("bad, match", [
    (np.zeros((10, 3)), "10 samples, at least 50"),
    (np.ones((60, 3)), "all readings are equal"),
    (np.zeros((60, 4)), r"expected shape \(N, 3\)"),
])
def test_fit_bad_input(bad, match):
    with pytest.raises(C.CalibrationError, match=match):
        C.fit_mag_calibration(bad)


def test_fit_drops_rows_without_a_sample_but_rejects_partial_nan():
    mag, _, _ = random_ellipsoid(np.random.default_rng(2))
    with_gaps = np.vstack([mag, np.full((5, 3), np.nan)])
    np.testing.assert_allclose(C.fit_mag_calibration(with_gaps)[0], C.fit_mag_calibration(mag)[0])
    mag[3, 1] = np.nan
    with pytest.raises(C.CalibrationError, match="NaN"):
        C.fit_mag_calibration(mag)


# --- the saved calibration ----------------------------------------------------------------------------

def test_calibration_json_round_trip_and_apply(tmp_path):
    cal = C.Calibration(board="nucleo-iks02a1", gyro_bias=[0.01, -0.02, 0.03], accel_bias=[0.1, 0.2, 0.3],
                        accel_scale=[1.01, 0.99, 1.0], mag_hard_iron=[1.0, 2.0, 3.0],
                        mag_soft_iron=np.diag([2.0, 1.0, 0.5]), source="test")
    path = cal.save(tmp_path / "c.json")
    assert C.Calibration.load(path) == cal
    assert set(json.loads(path.read_text())) == {"board", "rate_hz", "gyro_bias", "gyro_noise", "accel_bias", "accel_scale",
                                                 "accel_noise", "mag_hard_iron", "mag_soft_iron", "mag_noise", "source"}
    gyr, acc, mag = cal.apply((np.zeros((2, 3)), np.ones((2, 3)), np.array([[2.0, 3.0, 4.0], [np.nan] * 3])))
    np.testing.assert_allclose(gyr, -np.array([[0.01, -0.02, 0.03]] * 2))
    np.testing.assert_allclose(acc[0], (1 - np.array([0.1, 0.2, 0.3])) / [1.01, 0.99, 1.0])
    np.testing.assert_allclose(mag[0], [2.0, 1.0, 0.5])
    assert np.isnan(mag[1]).all()


def test_calibration_apply_on_recording_corrects_the_simulated_board():
    cal = C.load_calibration(path=datasets.data_dir() / "calibration_nucleo-iks02a1.json")
    rec = datasets.load("02_six_faces")
    _, acc, _ = cal.apply(rec)
    for face in C.FACES:  # the corrected up axis reads g within the noise and table tilt
        i = "xyz".index(face[0])
        sign = 1 if face.endswith("up") else -1
        assert abs(acc[rec.phase(face), i].mean() - sign * G) < 5e-3
    with pytest.raises(C.CalibrationError, match="for board 'mpu6050'.*load_calibration\\(board='nucleo-iks02a1'\\)"):
        C.load_calibration("mpu6050", path=datasets.data_dir() / "calibration_mpu6050.json").apply(rec)


def test_load_calibration_prefers_path_then_user_then_bundled(tmp_path, monkeypatch):
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    bundled = C.load_calibration("nucleo-iks02a1")
    assert bundled.source.startswith("kfkit default")
    mine = C.Calibration(board="nucleo-iks02a1", source="mine")
    assert mine.save() == tmp_path / "home" / "calibration_nucleo-iks02a1.json"
    assert C.load_calibration("nucleo-iks02a1").source == "mine"
    other = C.Calibration(board="nucleo-iks02a1", source="explicit").save(tmp_path / "x.json")
    assert C.load_calibration(path=other).source == "explicit"
    assert C.load_calibration("mpu6050").board == "mpu6050"
    with pytest.raises(ValueError, match="unknown board 'uno'"):
        C.load_calibration("uno")


def test_bundled_default_is_the_reference_analysis_of_the_bundled_recordings():
    made = C.calibrate(datasets.load("02_stationary"), datasets.load("02_six_faces"), datasets.load("03_mag_rotations"),
                       source=datasets.load("calibration_nucleo-iks02a1").source)
    assert made == datasets.load("calibration_nucleo-iks02a1")


@pytest.mark.parametrize("text, match", [
    ("{", "not valid JSON"),
    ("[1, 2]", "JSON object"),
    ('{"gyro_bias": [1, 2]}', r"gyro_bias: expected shape \(3,\), got \(2,\)"),
    ('{"colour": "red"}', "unknown fields colour"),
    ('{"accel_scale": [1, 0, 1]}', "must be positive"),
])
def test_calibration_file_errors_name_the_file(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(C.CalibrationError, match=match) as e:
        C.Calibration.load(path)
    assert str(path) in str(e.value)


def test_user_recording_round_trips_through_the_kit_format(tmp_path):
    """A lab 00 capture is a kit-format file with the same phase labels; the analysis reads it the same way."""
    rec = datasets.build("02_six_faces")
    path = save_recording(rec, tmp_path / "mine.csv")
    again = load_recording(path)
    faces = {f: again.body("acc")[again.phase(f)] for f in C.FACES}
    np.testing.assert_allclose(C.accel_six_face(faces)[1], C.accel_six_face(
        {f: rec.body("acc")[rec.phase(f)] for f in C.FACES})[1])


# --- checkpoint judges catch the classic mistakes -----------------------------------------------------------

def test_heading_checkpoint_catches_the_half_turn_atan2():
    from kfkit.frames import tilt_compensated_heading, wrap_angle

    def off_by_pi(m_b, roll, pitch, declination=0.0):  # atan2(m_y', −m_x'): both arguments negated
        return wrap_angle(tilt_compensated_heading(m_b, roll, pitch, declination) + np.pi)

    result = run_checkpoint(get("03.tilt_heading"), off_by_pi, seed=0)
    assert not result.ok and "exactly 180° off" in result.message


def test_lab02_judges_name_gravity_and_ddof():
    assert "gravity is still in it" in run_checkpoint(get("02.accel_bias"), lambda acc, expected: acc.mean(0)).message
    assert "ddof=0" in run_checkpoint(get("02.noise_std"), lambda x: x.std(axis=0)).message


def test_alignment_checkpoint_against_scipy_rotation():
    # 180° about y negates x and z: the sign matrix the checkpoint expects for the IIS2MDC
    D = Rotation.from_euler("y", np.pi).as_matrix()
    np.testing.assert_allclose(D, np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    result = run_checkpoint(get("03.alignment"), lambda turns: np.diag(
        [np.sign(np.sum(g * m)) for g, m in (turns[a] for a in "xyz")]), seed=1)
    assert result.ok, result.message


RIGHT = {
    "02.gyro_bias": C.gyro_bias, "02.noise_std": C.noise_std, "02.accel_bias": C.accel_bias,
    "02.six_face": C.accel_six_face, "02.six_face_recording": C.accel_six_face, "02.gyro_bias_recording": C.gyro_bias,
    "02.allan_deviation": lambda x, rate_hz, taus: C.allan_deviation(x, rate_hz, taus)[1],
    "02.sigma_at_rate": C.noise_at_rate,
    "03.counts_to_ut": lambda counts: counts * 0.15,
    "03.alignment": lambda turns: np.diag([np.sign(np.sum(g * m)) for g, m in (turns[a] for a in "xyz")]),
    "03.mag_calibration": C.fit_mag_calibration, "03.heading_error": C.fit_mag_calibration,
    "03.flat_heading": __import__("kfkit.frames", fromlist=["mag_heading"]).mag_heading,
    "03.tilt_heading": __import__("kfkit.frames", fromlist=["x"]).tilt_compensated_heading,
}


def test_every_lab02_and_lab03_checkpoint_has_a_right_answer_here():
    get("02.gyro_bias")
    from kfkit.checkpoints import REGISTRY
    assert {n for n in REGISTRY if n[:3] in ("02.", "03.")} == set(RIGHT)


@pytest.mark.parametrize("name", sorted(RIGHT))
@pytest.mark.parametrize("seed", [0, 1])
def test_reference_answers_pass_lab02_lab03(name, seed):
    result = run_checkpoint(get(name), RIGHT[name], seed)
    assert result.ok, result.message


def test_uncalibrated_magnetometer_fails_the_heading_checkpoint():
    result = run_checkpoint(get("03.heading_error"), lambda mag: (np.zeros(3), np.eye(3)))
    assert not result.ok and "uncalibrated" in result.message


def test_allan_checkpoint_names_a_normalisation_factor():
    result = run_checkpoint(get("02.allan_deviation"), lambda x, rate_hz, taus: 2 * C.allan_deviation(x, rate_hz, taus)[1])
    assert "constant factor 2" in result.message
