"""kfkit.calibration's estimators against known simulated parameters, random ellipsoids, an independent Allan
deviation (allantools, and a non-overlapping estimator written here), and the saved JSON.
(Labs 02 and 03 end to end: test_calibration_labs.py; their checkpoints: test_checkpoints.py.)"""

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit import allan, calibration_motions, datasets, mag_calibration, motions, rest_calibration, sim
from kfkit import calibration as C
from kfkit.checkpoints.lab03 import random_ellipsoid
from kfkit.frames import MAG_FIELD_LONDON, G, mount_matrix
from kfkit.io import load_recording, save_recording

B_LONDON = np.linalg.norm(MAG_FIELD_LONDON)


# --- bias and noise on a simulated board with known parameters --------------------------------


def test_gyro_bias_and_noise_match_simulated_truth():
    bias_s = np.radians([0.5, -0.3, 0.8])
    rec = sim.simulate_imu(motions.stationary(60.0, 104.0), seed=3, gyro_bias=bias_s, gyro_bias_rw=0.0)
    gyr = rec.body("gyr")
    sigma = rec_sigma = 5e-3 * np.pi / 180 * np.sqrt(104.0)  # datasheet density · √rate
    truth = mount_matrix(rec.meta["mount"]["gyr"]) @ bias_s
    assert np.all(np.abs(rest_calibration.gyro_bias(gyr) - truth) < 4 * sigma / np.sqrt(len(gyr)))
    lsb = rec.meta["sensors"]["gyr"]["sensitivity"]
    expected = np.sqrt(rec_sigma**2 + lsb**2 / 12)  # white noise plus quantisation
    np.testing.assert_allclose(rest_calibration.noise_std(gyr), expected, rtol=0.05)


def test_noise_std_windows_leave_out_a_slow_drift():
    rng = np.random.default_rng(1)
    t = np.arange(20000)
    x = rng.normal(0, 0.1, (20000, 3)) + (t / 20000 * 5.0)[:, None]  # drift of 5 over the record
    assert rest_calibration.noise_std(x)[0] > 1.0
    np.testing.assert_allclose(rest_calibration.noise_std(x, window=100), 0.1, rtol=0.03)


def test_accel_bias_keeps_gravity_out():
    rec = sim.simulate_imu(motions.stationary(30.0, 104.0), seed=4, accel_bias=[0.05, -0.02, 0.03], accel_bias_rw=0.0)
    acc = rec.body("acc")
    b = rest_calibration.accel_bias(acc, [0.0, 0.0, -G])
    truth = mount_matrix(rec.meta["mount"]["acc"]) @ [0.05, -0.02, 0.03]
    assert np.all(np.abs(b - truth) < 4 * acc.std(axis=0) / np.sqrt(len(acc)))


# the six faces as exact poses (roll, pitch), FRD: the named body axis points up and reads +g of specific force
FACE_POSES = {
    "z_down": (0.0, 0.0),
    "z_up": (np.pi, 0.0),
    "y_down": (np.pi / 2, 0.0),
    "y_up": (-np.pi / 2, 0.0),
    "x_up": (0.0, np.pi / 2),
    "x_down": (0.0, -np.pi / 2),
}


def test_six_face_signs_and_values_on_exact_poses():
    bias_s, scale = np.array([0.06, -0.04, 0.09]), np.array([1.01, 0.994, 1.003])
    faces = {}
    for k, (face, (roll, pitch)) in enumerate(FACE_POSES.items()):
        rec = sim.simulate_imu(
            motions.stationary(5.0, 104.0, roll=roll, pitch=pitch),
            seed=30 + k,
            accel_bias=bias_s,
            accel_scale=scale,
            accel_bias_rw=0.0,
        )
        faces[face] = rec.body("acc")
        axis = "xyz".index(face[0])
        assert np.sign(faces[face][:, axis].mean()) == (1 if face.endswith("up") else -1)  # DESIGN: up reads +g
    M = mount_matrix(rec.meta["mount"]["acc"])
    b, s = rest_calibration.accel_six_face(faces)
    n, sigma = len(faces["x_up"]), np.mean([f.std(axis=0) for f in faces.values()], axis=0)
    u_b = sigma / np.sqrt(2 * n)  # each axis: the mean of two faces' means
    assert np.all(np.abs(b - M @ bias_s) < 4 * u_b)
    assert np.all(np.abs(s - np.abs(M) @ scale) < 4 * u_b / G)
    corrected = (faces["y_down"] - b) / s  # (raw − b)/s: the pose's specific force, R_bn·[0, 0, −g]
    np.testing.assert_allclose(corrected.mean(axis=0), [0.0, -G, 0.0], atol=4 * sigma.max() / np.sqrt(n))


def test_six_face_recovers_simulated_bias_and_scale():
    bias_s, scale = np.array([0.06, -0.04, 0.09]), np.array([1.01, 0.994, 1.003])
    rec = sim.simulate_imu(
        calibration_motions.six_faces(seed=5), seed=6, accel_bias=bias_s, accel_scale=scale, accel_bias_rw=0.0
    )
    faces = {f: rec.body("acc")[rec.phase(f)] for f in rest_calibration.FACES}
    b, s = rest_calibration.accel_six_face(faces)
    np.testing.assert_allclose(b, mount_matrix(rec.meta["mount"]["acc"]) @ bias_s, atol=2e-3)
    np.testing.assert_allclose(s, scale, atol=3e-4)
    # a bias-only calibration (level rest) mixes the z scale error into the z bias
    level = rest_calibration.accel_bias(faces["z_down"], [0.0, 0.0, -G])
    z_true = (mount_matrix(rec.meta["mount"]["acc"]) @ bias_s)[2]
    assert abs(level[2] - (z_true - (scale[2] - 1) * G)) < 2e-3


def test_six_face_errors_name_the_problem():
    rng = np.random.default_rng(0)
    faces = {f: rng.normal(0, 0.01, (20, 3)) for f in rest_calibration.FACES}
    with pytest.raises(rest_calibration.CalibrationError, match="axis x reads"):
        rest_calibration.accel_six_face(faces)
    with pytest.raises(rest_calibration.CalibrationError, match="missing z_down"):
        rest_calibration.accel_six_face({f: v for f, v in faces.items() if f != "z_down"})


@pytest.mark.parametrize(
    "func",
    [rest_calibration.gyro_bias, rest_calibration.noise_std, lambda x: rest_calibration.accel_bias(x, [0, 0, -G])],
)
@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((1, 3)), "1 samples, at least 2"),
        (np.zeros((10, 2)), r"expected shape \(N, 3\), got \(10, 2\)"),
        (np.zeros(3), "one vector"),
        (np.vstack([np.zeros((5, 3)), [[0.0, np.nan, 0.0]]]), "1 of 6 samples hold NaN or inf .first at row 5"),
    ],
)
def test_bad_input_raises_clear_errors(func, bad, match):
    with pytest.raises(rest_calibration.CalibrationError, match=match):
        func(bad)


def test_accel_bias_expected_must_be_a_vector():
    with pytest.raises(rest_calibration.CalibrationError, match=r"shape \(3,\)"):
        rest_calibration.accel_bias(np.zeros((5, 3)), -G)


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
    ours = allan.allan_deviation(x, rate, taus)[1]
    t2, ad, _, _ = allantools.oadev(x, rate=rate, data_type="freq", taus=taus)
    np.testing.assert_allclose(t2, taus)
    np.testing.assert_allclose(ours, ad, rtol=1e-9)


def test_allan_agrees_with_nonoverlapping_estimator():
    rng = np.random.default_rng(8)
    x = rng.normal(0, 1.0, 100000)
    for m in (1, 10, 100):
        taus, ours = allan.allan_deviation(x, 10.0, [m / 10.0])
        ref = allan_nonoverlapping(x, 10.0, m)
        clusters = len(x) // m
        assert abs(ours[0] - ref) < 4 * ref / np.sqrt(clusters)  # both within sampling error of each other


def test_allan_slopes_of_white_noise_and_random_walk():
    rng = np.random.default_rng(9)
    rate, n = 100.0, 200000
    white = rng.normal(0, 0.01, n)  # σ per sample → N = σ/√rate
    taus, ad = allan.allan_deviation(white, rate)
    keep = taus < 50
    assert abs(slope(taus[keep], ad[keep]) + 0.5) < 0.03
    assert abs(allan.angle_random_walk(taus, ad) - 0.01 / np.sqrt(rate)) < 0.03 * 0.01 / np.sqrt(rate)
    K = 1e-4
    walk = np.cumsum(rng.normal(0, K / np.sqrt(rate), n))  # rate random walk of density K
    taus, ad = allan.allan_deviation(walk, rate)
    keep = (taus > 1) & (taus < 100)
    assert abs(slope(taus[keep], ad[keep]) - 0.5) < 0.1
    # σ(τ) = K √(τ/3) for a rate random walk (IEEE 952)
    np.testing.assert_allclose(ad[keep] / (K * np.sqrt(taus[keep] / 3)), 1.0, atol=0.35)


def test_bias_instability_reads_the_minimum():
    taus = np.logspace(-1, 3, 41)
    adev = 1e-3 / np.sqrt(taus) + 1e-5 * np.sqrt(taus)
    B, tau_min = allan.bias_instability(taus, adev)
    assert tau_min == pytest.approx(100.0, rel=0.15)
    assert B == pytest.approx(2e-4 / 0.664, rel=0.01)
    assert allan.BIAS_INSTABILITY_FACTOR == pytest.approx(0.664, abs=5e-4)


def noise_with_psd(rng, n, rate, two_sided_psd):
    """Gaussian noise of a given two-sided PSD S(f) (unit²/Hz) by spectral synthesis: the oracle for the
    IEEE 952 read-outs, whose PSDs are two-sided (white N² gives σ(τ) = N/√τ, σ per sample N·√rate)."""
    f = np.fft.rfftfreq(n, 1 / rate)
    one_sided = np.zeros_like(f)
    one_sided[1:] = 2 * two_sided_psd(f[1:])
    return np.fft.irfft(np.sqrt(one_sided * n * rate / 4) * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size)), n)


def test_allan_read_outs_on_synthesised_white_and_flicker_noise():
    rng = np.random.default_rng(12)
    rate, n, N, B = 100.0, 2**19, 1e-3, 2e-3
    white = noise_with_psd(rng, n, rate, lambda f: N**2 + 0 * f)
    assert white.std() == pytest.approx(N * np.sqrt(rate), rel=0.01)  # the synthesis itself: σ = N·√rate
    taus, ad = allan.allan_deviation(white, rate)
    assert allan.angle_random_walk(taus, ad) == pytest.approx(N, rel=0.02)
    # flicker (bias instability) S(f) = B²/(2π f): the Allan curve is flat at √(2 ln 2/π)·B ≈ 0.664 B
    x = white + noise_with_psd(rng, n, rate, lambda f: B**2 / (2 * np.pi * f))
    taus, ad = allan.allan_deviation(x, rate, np.logspace(-1, np.log10(n / rate / 20), 30))
    floor = (taus > 10) & (taus < 200)
    assert np.median(ad[floor]) / allan.BIAS_INSTABILITY_FACTOR == pytest.approx(B, rel=0.05)
    b, tau_min = allan.bias_instability(taus, ad)  # the lowest point of a noisy floor: a little low, never high
    assert 0.75 * B < b < 1.05 * B and 10 < tau_min


@pytest.mark.parametrize("seed", range(4))
def test_allan_noise_fit_reads_white_noise_and_the_bias_random_walk(seed):
    """The simulator's gyro: white noise N plus a bias that walks with K (its steps' σ = K/√rate), one hour at 50 Hz.
    The walk shows on the curve's last two decades only, so K is read to ±30 % (the estimate's own scatter), N to
    2 %."""
    rng = np.random.default_rng(seed)
    rate, N, K = 50.0, 5e-3, 2e-4
    n = int(3600 * rate)
    x = N * np.sqrt(rate) * rng.normal(size=n) + np.cumsum(K / np.sqrt(rate) * rng.normal(size=n))
    n_fit, b_fit, k_fit = allan.allan_noise_fit(*allan.allan_deviation(x, rate))
    assert n_fit == pytest.approx(N, rel=0.02)
    assert 0.7 * K < k_fit < 1.3 * K
    assert b_fit < 0.5 * K * np.sqrt(3600 / 3)  # no made-up floor: a flicker level below what the walk reaches


def test_allan_noise_fit_reads_flicker_as_bias_instability_and_a_short_rest_gives_no_walk():
    rng = np.random.default_rng(14)
    rate, n, N, B = 100.0, 2**19, 1e-3, 2e-3
    x = noise_with_psd(rng, n, rate, lambda f: N**2 + B**2 / (2 * np.pi * f))
    n_fit, b_fit, _ = allan.allan_noise_fit(*allan.allan_deviation(x, rate))
    assert n_fit == pytest.approx(N, rel=0.03) and b_fit == pytest.approx(B, rel=0.15)
    white = N * np.sqrt(rate) * rng.normal(size=6000)  # one minute: nothing but white noise to see
    n_fit, b_fit, k_fit = allan.allan_noise_fit(*allan.allan_deviation(white, rate))
    assert n_fit == pytest.approx(N, rel=0.05) and k_fit < 0.1 * N


def test_allan_noise_fit_per_column():
    rng = np.random.default_rng(15)
    x = rng.normal(size=(20000, 3)) * [1.0, 2.0, 3.0]
    n_fit, b_fit, k_fit = allan.allan_noise_fit(*allan.allan_deviation(x, 100.0))
    assert n_fit.shape == b_fit.shape == k_fit.shape == (3,)
    np.testing.assert_allclose(n_fit, np.array([1.0, 2.0, 3.0]) / 10.0, rtol=0.05)  # σ = N·√rate


def test_allan_slopes_agree_with_allantools():
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(13)
    rate, n = 50.0, 100000
    for x, known in ((rng.normal(0, 1e-2, n), -0.5), (np.cumsum(rng.normal(0, 1e-4, n)), 0.5)):
        taus = np.logspace(0, 2.5, 12)
        ours = allan.allan_deviation(x, rate, taus)
        theirs = allantools.oadev(x, rate=rate, data_type="freq", taus=ours[0])
        assert abs(slope(*ours) - known) < 0.1 and abs(slope(theirs[0], theirs[1]) - known) < 0.1


def test_allan_bad_input():
    with pytest.raises(rest_calibration.CalibrationError, match="at least 9"):
        allan.allan_deviation(np.zeros(5), 10.0)
    with pytest.raises(rest_calibration.CalibrationError, match="under half the record"):
        allan.allan_deviation(np.zeros(100), 10.0, taus=[6.0])
    with pytest.raises(rest_calibration.CalibrationError, match="span τ = 1 s"):
        allan.angle_random_walk([2.0, 4.0], [1.0, 0.5])


# --- magnetometer calibration ------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_random_ellipsoids(seed):
    rng = np.random.default_rng(seed)
    mag, h, W = random_ellipsoid(rng, n=600, noise=0.05)
    h_fit, S = mag_calibration.fit_mag_calibration(mag)
    np.testing.assert_allclose(h_fit, h, atol=0.05)
    np.testing.assert_allclose(S, np.linalg.inv(W), atol=2e-3)  # W symmetric: S = W⁻¹ exactly
    np.testing.assert_allclose(S, S.T)
    norms = np.linalg.norm((mag - h_fit) @ S.T, axis=1)
    assert abs(norms.mean() - B_LONDON) < 0.02 and norms.std() < 0.1


def test_fit_of_a_general_soft_iron_leaves_only_a_rotation():
    """W not symmetric (a rotation after the scaling): norms still come out right, S is the symmetric
    (W Wᵀ)^(−½) (scipy's sqrtm as the oracle) and S·W is a rotation, the part norms cannot see."""
    from scipy.linalg import sqrtm

    rng = np.random.default_rng(21)
    u = Rotation.random(800, random_state=rng).apply([1.0, 0.0, 0.0])
    W = (
        Rotation.random(random_state=rng).as_matrix()
        @ np.diag([1.2, 0.9, 0.8])
        @ Rotation.random(random_state=rng).as_matrix()
    )
    h = np.array([5.0, -20.0, 8.0])
    mag = B_LONDON * u @ W.T + h
    h_fit, S = mag_calibration.fit_mag_calibration(mag)
    np.testing.assert_allclose(h_fit, h, atol=1e-8)
    np.testing.assert_allclose(S, np.real(sqrtm(np.linalg.inv(W @ W.T))), atol=1e-8)
    R = S @ W
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-8)
    np.testing.assert_allclose(
        np.linalg.norm(mag_calibration.apply_mag_calibration(mag, h_fit, S), axis=1), B_LONDON, rtol=1e-9
    )


def test_fit_scales_to_the_given_field_norm():
    mag, h, W = random_ellipsoid(np.random.default_rng(11), field_norm=30.0, noise=0.0)
    _, S = mag_calibration.fit_mag_calibration(mag, field_norm=30.0)
    np.testing.assert_allclose(S, np.linalg.inv(W), atol=1e-9)


def test_fit_on_simulated_board_recovers_body_frame_iron():
    rec = datasets.load("03_mag_rotations")
    h, S = mag_calibration.fit_mag_calibration(rec.body("mag"))
    M = mount_matrix(rec.meta["mount"]["mag"])
    W = np.asarray(rec.meta["sim"]["mag_soft_iron"])
    np.testing.assert_allclose(h, M @ rec.meta["sim"]["mag_hard_iron"], atol=0.1)
    np.testing.assert_allclose(S, np.linalg.inv(M @ W @ M.T), atol=5e-3)


def test_fit_rejects_poor_coverage_and_says_what_to_do():
    rec = sim.simulate_imu(calibration_motions.heading_steps(tilt=(0.0, 0.0)), seed=1, mag_hard_iron=[10.0, 0.0, 0.0])
    with pytest.raises(rest_calibration.CalibrationError, match="cover too little of the sphere.*every orientation"):
        mag_calibration.fit_mag_calibration(rec.body("mag"))


def field_seen_from(rotations, field=MAG_FIELD_LONDON, noise=0.3, seed=0):
    """Magnetometer readings (µT, body) of the field seen from ``rotations`` (body → NED), with noise."""
    rng = np.random.default_rng(seed)
    return rotations.inv().apply(field) + rng.normal(0.0, noise, (len(rotations), 3))


def test_fit_judges_coverage_against_the_field_not_the_cloud_shape():
    # A still board: isotropic noise around one reading. Its shape is round (it passes a relative
    # smallest/largest check), but it spans 0.3 µT of a 49 µT field: no ellipsoid is in it.
    still = field_seen_from(Rotation.identity(600))
    variances = np.linalg.eigvalsh(np.cov(still.T))
    assert (
        variances[0] / variances[-1] > mag_calibration.MIN_MAG_SPREAD
    )  # the old relative check would have let it through
    with pytest.raises(
        rest_calibration.CalibrationError, match=r"spread only 0\.\d+ µT.*the board hardly turned.*every orientation"
    ):
        mag_calibration.fit_mag_calibration(still)
    # Turned about one axis only (a ring): the field is never seen along that axis.
    for axis in ("z", "x"):
        ring = field_seen_from(Rotation.from_euler(axis, np.linspace(0, 2 * np.pi, 600)[:, None]))
        with pytest.raises(rest_calibration.CalibrationError, match="turned about one axis only.*every orientation"):
            mag_calibration.fit_mag_calibration(ring)
    # A tumble through every orientation, with known iron: the fit recovers it (oracle: the simulated truth).
    rotations = Rotation.random(2000, random_state=3)
    h = np.array([8.0, -5.0, 12.0])
    S_true = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, -0.04], [0.0, -0.04, 1.0]])
    raw = field_seen_from(rotations, noise=0.05) @ np.linalg.inv(S_true).T + h  # m_cal = S (m − h)
    hard, soft = mag_calibration.fit_mag_calibration(raw)
    np.testing.assert_allclose(hard, h, atol=0.05)
    np.testing.assert_allclose(soft, S_true, atol=0.005)
    # The same tumble where the field is half London's (South America), still judged with London's B: it passes.
    weak = field_seen_from(rotations, field=np.asarray(MAG_FIELD_LONDON) * 0.5, noise=0.05)
    np.testing.assert_allclose(
        np.linalg.norm(mag_calibration.apply_mag_calibration(weak, *mag_calibration.fit_mag_calibration(weak)), axis=1),
        B_LONDON,
        rtol=0.01,
    )
    with pytest.raises(rest_calibration.CalibrationError, match="field_norm must be"):
        mag_calibration.fit_mag_calibration(raw, field_norm=-1.0)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((10, 3)), "10 samples, at least 50"),
        (np.ones((60, 3)), "all readings are equal"),
        (np.zeros((60, 4)), r"expected shape \(N, 3\)"),
    ],
)
def test_fit_bad_input(bad, match):
    with pytest.raises(rest_calibration.CalibrationError, match=match):
        mag_calibration.fit_mag_calibration(bad)


def test_fit_drops_rows_without_a_sample_but_rejects_partial_nan():
    mag, _, _ = random_ellipsoid(np.random.default_rng(2))
    with_gaps = np.vstack([mag, np.full((5, 3), np.nan)])
    np.testing.assert_allclose(
        mag_calibration.fit_mag_calibration(with_gaps)[0], mag_calibration.fit_mag_calibration(mag)[0]
    )
    mag[3, 1] = np.nan
    with pytest.raises(rest_calibration.CalibrationError, match="NaN"):
        mag_calibration.fit_mag_calibration(mag)


# --- the saved calibration ----------------------------------------------------------------------------


def test_calibration_json_round_trip_and_apply(tmp_path):
    cal = C.Calibration(
        board="nucleo-iks02a1",
        gyro_bias=[0.01, -0.02, 0.03],
        accel_bias=[0.1, 0.2, 0.3],
        accel_scale=[1.01, 0.99, 1.0],
        mag_hard_iron=[1.0, 2.0, 3.0],
        mag_soft_iron=np.diag([2.0, 1.0, 0.5]),
        source="test",
    )
    path = cal.save(tmp_path / "c.json")
    assert C.Calibration.load(path) == cal
    assert set(json.loads(path.read_text())) == {
        "board",
        "rate_hz",
        "gyro_bias",
        "gyro_noise",
        "gyro_bias_walk",
        "accel_bias",
        "accel_scale",
        "accel_noise",
        "mag_hard_iron",
        "mag_soft_iron",
        "mag_noise",
        "source",
    }
    older = {k: v for k, v in json.loads(path.read_text()).items() if k != "gyro_bias_walk"}  # saved before it existed
    assert C.Calibration.from_json(json.dumps(older)).gyro_bias_walk == [0.0, 0.0, 0.0]
    gyr, acc, mag = cal.apply((np.zeros((2, 3)), np.ones((2, 3)), np.array([[2.0, 3.0, 4.0], [np.nan] * 3])))
    np.testing.assert_allclose(gyr, -np.array([[0.01, -0.02, 0.03]] * 2))
    np.testing.assert_allclose(acc[0], (1 - np.array([0.1, 0.2, 0.3])) / [1.01, 0.99, 1.0])
    np.testing.assert_allclose(mag[0], [2.0, 1.0, 0.5])
    assert np.isnan(mag[1]).all()


def test_calibration_apply_on_recording_corrects_the_simulated_board():
    cal = C.load_calibration(path=datasets.data_dir() / "calibration_nucleo-iks02a1.json")
    rec = datasets.load("02_six_faces")
    _, acc, _ = cal.apply(rec)
    for face in rest_calibration.FACES:  # the corrected up axis reads g within the noise and table tilt
        i = "xyz".index(face[0])
        sign = 1 if face.endswith("up") else -1
        assert abs(acc[rec.phase(face), i].mean() - sign * G) < 5e-3
    with pytest.raises(
        rest_calibration.CalibrationError, match="for board 'mpu6050'.*load_calibration\\(board='nucleo-iks02a1'\\)"
    ):
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
    made = C.calibrate(
        datasets.load("02_stationary"),
        datasets.load("02_six_faces"),
        datasets.load("03_mag_rotations"),
        source=datasets.load("calibration_nucleo-iks02a1").source,
    )
    assert made == datasets.load("calibration_nucleo-iks02a1")


GOOD_FILE = json.loads(
    C.Calibration(
        board="nucleo-iks02a1", gyro_noise=[1e-3] * 3, accel_noise=[6e-3] * 3, mag_noise=[0.3] * 3, source="test"
    ).to_json()
)


def changed(**fields):
    """GOOD_FILE's JSON with ``fields`` replaced (a value of ... removes the field)."""
    d = {k: v for k, v in {**GOOD_FILE, **fields}.items() if v is not ...}
    return json.dumps(d, allow_nan=True)


@pytest.mark.parametrize(
    "text, match",
    [
        ("{", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ("{}", "missing fields board, rate_hz, gyro_bias"),  # loaded as an all-zero calibration before
        (changed(mag_soft_iron=...), "missing fields mag_soft_iron"),
        (changed(gyro_bias=[1, 2]), r"gyro_bias: expected shape \(3,\), got \(2,\)"),
        (changed(gyro_bias=["a", 0, 0]), r"gyro_bias: expected numbers of shape \(3,\)"),
        (changed(gyro_bias={"x": 1}), r"gyro_bias: expected numbers"),
        (changed(colour="red"), "unknown fields colour"),
        (changed(accel_scale=[1, 0, 1]), r"accel_scale must lie within 0\.5 … 2"),
        (changed(accel_scale=[1, -1, 1]), r"accel_scale must lie within"),
        (changed(accel_scale=[1, 1e-9, 1]), r"accel_scale must lie within"),
        (changed(accel_bias=[float("nan"), 0, 0]), "accel_bias: holds NaN or inf"),
        (changed(mag_hard_iron=[float("inf"), 0, 0]), "mag_hard_iron: holds NaN or inf"),
        (changed(gyro_noise=[-1e-3, 1e-3, 1e-3]), "gyro_noise is a noise level: it cannot be negative"),
        (changed(gyro_bias_walk=[1e-5, -1e-5, 0.0]), "gyro_bias_walk is a noise level: it cannot be negative"),
        (
            changed(mag_soft_iron=[[0, 0, 0]] * 3),
            "mag_soft_iron must be symmetric positive definite and not .*singular",
        ),
        (changed(mag_soft_iron=[[1, 0, 0], [0, 1, 0], [0, 0, 1e-6]]), "mag_soft_iron .* singular"),
        (changed(mag_soft_iron=[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), "mag_soft_iron must be symmetric"),
        (
            changed(mag_soft_iron=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]),
            "mag_soft_iron must be symmetric positive definite",
        ),
        (changed(rate_hz=0), "rate_hz must be a positive finite number"),
        (changed(rate_hz=-104), "rate_hz must be a positive finite number"),
        (changed(rate_hz=float("nan")), "rate_hz must be a positive finite number"),
        (changed(rate_hz="104"), "rate_hz must be a positive finite number"),
        (changed(rate_hz=True), "rate_hz must be a positive finite number"),
        (changed(board=3), "board must be a board name"),
        (changed(board="arduino-nano"), "unknown board 'arduino-nano'"),
    ],
    ids=[
        "json",
        "list",
        "empty",
        "missing-field",
        "shape",
        "text",
        "object",
        "unknown",
        "scale-zero",
        "scale-negative",
        "scale-tiny",
        "nan",
        "inf",
        "noise-negative",
        "walk-negative",
        "soft-iron-zero",
        "soft-iron-singular",
        "soft-iron-asymmetric",
        "soft-iron-reflection",
        "rate-zero",
        "rate-negative",
        "rate-nan",
        "rate-text",
        "rate-bool",
        "board-number",
        "board-unknown",
    ],
)
def test_calibration_file_errors_name_the_file(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(rest_calibration.CalibrationError, match=match) as e:
        C.Calibration.load(path)
    assert str(path) in str(e.value)
    with pytest.raises(rest_calibration.CalibrationError, match=re.escape(str(path))):
        C.load_calibration("nucleo-iks02a1", path=path)


def test_calibration_file_with_a_byte_order_mark_loads_and_binary_is_named(tmp_path):
    path = tmp_path / "bom.json"
    path.write_bytes(b"\xef\xbb\xbf" + changed().encode())  # Notepad's "UTF-8 with BOM"
    assert C.Calibration.load(path) == C.Calibration(**GOOD_FILE)
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(rest_calibration.CalibrationError, match=re.escape(str(path)) + ": not a text file"):
        C.Calibration.load(path)


def test_every_bundled_calibration_passes_the_file_checks():
    for board in ("nucleo-iks02a1", "mpu6050", "phone-phyphox"):
        assert C.Calibration.load(C.bundled_calibration_path(board)).board == board


def test_user_recording_round_trips_through_the_kit_format(tmp_path):
    """A lab 00 capture is a kit-format file with the same phase labels; the analysis reads it the same way."""
    rec = datasets.build("02_six_faces")
    path = save_recording(rec, tmp_path / "mine.csv")
    again = load_recording(path)
    faces = {f: again.body("acc")[again.phase(f)] for f in rest_calibration.FACES}
    np.testing.assert_allclose(
        rest_calibration.accel_six_face(faces)[1],
        rest_calibration.accel_six_face({f: rec.body("acc")[rec.phase(f)] for f in rest_calibration.FACES})[1],
    )


def test_saving_again_keeps_the_previous_calibration(tmp_path):
    path = tmp_path / "calibration_nucleo-iks02a1.json"
    first = C.Calibration(gyro_bias=[0.01, 0.0, 0.0], source="first")
    first.save(path)
    first.save(path)  # the same content again: nothing to keep
    assert not (tmp_path / "calibration_nucleo-iks02a1.previous.json").exists()
    C.Calibration(gyro_bias=[0.02, 0.0, 0.0], source="second").save(path)
    assert C.Calibration.load(path).source == "second"
    assert C.Calibration.load(tmp_path / "calibration_nucleo-iks02a1.previous.json") == first


def test_bundled_recordings_get_the_bundled_unit_and_own_recordings_the_students(tmp_path, monkeypatch):
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    C.Calibration(board="nucleo-iks02a1", gyro_bias=[0.1, 0.2, 0.3], source="mine").save()
    bundled = datasets.load("03_headings")
    assert C.calibration_for(bundled) == datasets.load("calibration_nucleo-iks02a1")
    own = load_recording(save_recording(bundled, tmp_path / "my_headings.csv"))
    assert C.calibration_for(own).source == "mine"


# --- a phone: its default calibration, its saved one, its unlabelled exports ----------------------------------------

PHONE = "phone-phyphox"


def phone_export(folder, motion, seed, truth=False, unit=None):
    """A simulated phone through ``motion`` as a phyphox export folder (kfkit's writer; the format itself is
    tested in test_phyphox.py). Without ``truth``, like a real export: no kfkit_truth.csv, so no labels."""
    from kfkit import phone_sim
    from kfkit.phone_sim import simulate_phone

    files = phone_sim.simple_experiment_files(simulate_phone(motion, seed=seed, unit=unit))
    if not truth:
        files.pop(phone_sim.TRUTH_FILE)
    return phone_sim.write_export(files, folder)


def test_phone_default_is_the_identity_with_the_phone_models_noise(tmp_path, monkeypatch):
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    cal = C.load_calibration(PHONE)
    assert cal == datasets.load(f"calibration_{PHONE}") and cal.source.startswith("kfkit default for a phone: identity")
    assert cal.gyro_bias == [0.0] * 3 and cal.accel_bias == [0.0] * 3 and cal.accel_scale == [1.0] * 3
    assert cal.mag_hard_iron == [0.0] * 3 and cal.mag_soft_iron == np.eye(3).tolist()
    # the BMI160's datasheet densities (0.007 °/s/√Hz, 180 µg/√Hz) and 0.3 µT, per sample at 100 Hz
    assert cal.rate_hz == 100.0
    np.testing.assert_allclose(cal.gyro_noise, np.radians(0.007) * 10.0, rtol=1e-8)
    np.testing.assert_allclose(cal.accel_noise, 180e-6 * G * 10.0, rtol=1e-8)
    np.testing.assert_allclose(cal.mag_noise, 0.3)
    tour = datasets.load("04_phone_attitude_tour")
    assert C.calibration_for(tour) == cal  # the bundled export folder counts as bundled
    gyr, acc, mag = cal.apply(tour)
    for got, sensor in ((gyr, "gyr"), (acc, "acc"), (mag, "mag")):
        np.testing.assert_array_equal(got, tour.body(sensor))  # the identity changes nothing, NaN rows stay NaN
    with pytest.raises(ValueError, match="unknown board 'iphone'.*phone-phyphox"):
        C.load_calibration("iphone")


def test_a_saved_phone_calibration_round_trips_and_belongs_to_the_students_phone(tmp_path, monkeypatch):
    from kfkit.io import save_recording
    from kfkit.readers import load_any

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    mine = C.Calibration(
        board=PHONE,
        rate_hz=100.2,
        gyro_bias=np.radians([0.03, -0.01, 0.02]),
        gyro_noise=[0.0012] * 3,
        accel_bias=[0.03, -0.04, 0.05],
        accel_scale=[1.002, 0.998, 1.001],
        accel_noise=[0.018] * 3,
        mag_hard_iron=[0.5, -0.3, 0.9],
        source="lab 02/03: my phone",
    )
    assert mine.save() == tmp_path / "home" / f"calibration_{PHONE}.json"
    assert json.loads((tmp_path / "home" / f"calibration_{PHONE}.json").read_text())["board"] == PHONE
    assert C.load_calibration(PHONE) == mine  # what lab 04 loads for a phone
    export = load_any(phone_export(tmp_path / "export", motions.stationary(5.0, 100.0), seed=1))
    capture = load_any(save_recording(export, tmp_path / "phone_capture.csv"))  # a live capture is in the kit's format
    for own in (export, capture):
        assert own.meta["board"] == PHONE and C.calibration_for(own) == mine
    assert C.calibration_for(datasets.load("04_phone_attitude_tour")).source.startswith("kfkit default")
    gyr, acc, _ = mine.apply(export)
    np.testing.assert_allclose(mine.gyro_bias, np.radians([0.03, -0.01, 0.02]), rtol=1e-8)  # 9 significant digits
    np.testing.assert_allclose(gyr, export.body("gyr") - np.array(mine.gyro_bias), rtol=0, atol=1e-15)
    np.testing.assert_allclose(acc, (export.body("acc") - [0.03, -0.04, 0.05]) / [1.002, 0.998, 1.001])


def strip_phases(rec):
    return type(rec)({**rec.meta, "phases": []}, rec.data, rec.path)


@pytest.mark.parametrize("source", ["board", "phone export"])
def test_label_rests_finds_and_names_the_six_faces(tmp_path, source):
    motion = calibration_motions.six_faces(rate_hz=400.0 if source == "phone export" else 104.0, seed=5)
    bias_s, scale = np.array([0.06, -0.04, 0.09]), np.array([1.01, 0.994, 1.003])
    if source == "board":
        rec = strip_phases(sim.simulate_imu(motion, seed=6, accel_bias=bias_s, accel_scale=scale, accel_bias_rw=0.0))
    else:
        from kfkit.unit_errors import PHONE_UNIT

        unit = {**PHONE_UNIT, "accel_bias": bias_s, "accel_scale": scale, "accel_bias_rw": 0.0}
        rec = load_recording_or_export(phone_export(tmp_path / "faces", motion, seed=6, unit=unit))
        assert rec.phases == []  # a real export carries no labels
    labelled = rest_calibration.label_rests(rec)
    truth = {label: (a, b) for a, b, label in motion.phases}  # the simulated protocol's own windows
    found = [p for p in labelled.phases if p["label"] in rest_calibration.FACES]
    assert sorted(p["label"] for p in found) == sorted(rest_calibration.FACES)
    for p in found:
        a, b = truth[p["label"]]
        assert a <= p["start"] < p["end"] <= b and p["end"] - p["start"] > 0.7 * (b - a)
    level = [p for p in labelled.phases if p["label"] == "stationary"]
    assert [(p["start"], p["end"]) for p in level] == [(p["start"], p["end"]) for p in found if p["label"] == "z_down"]
    b, s = rest_calibration.accel_six_face({f: labelled.body("acc")[labelled.phase(f)] for f in rest_calibration.FACES})
    M = mount_matrix(rec.meta["mount"]["acc"])
    np.testing.assert_allclose(b, M @ bias_s, atol=3e-3)  # the faces sit on a table tilted ~0.5°
    np.testing.assert_allclose(s, np.abs(M) @ scale, atol=5e-4)


def load_recording_or_export(path):
    from kfkit.readers import load_any

    return load_any(path)


def test_label_rests_names_only_rests_near_a_face_and_refuses_a_recording_without_rest():
    for roll_deg, expected in ((5.0, {"z_down", "stationary"}), (15.0, {"rest"})):
        rec = sim.simulate_imu(motions.stationary(6.0, 104.0, roll=np.radians(roll_deg)), seed=7)
        assert {p["label"] for p in rest_calibration.label_rests(rec).phases} == expected, roll_deg
    held = sim.simulate_imu(
        motions.sine_roll(duration=20.0, rate_hz=104.0, still=0.0, vibration_rms=0.3, seed=8), seed=9
    )
    with pytest.raises(rest_calibration.CalibrationError, match="no rest of at least 2 s.*keep it still"):
        rest_calibration.label_rests(held)


def test_fuzzed_calibration_files_load_the_same_numbers_or_name_the_file(tmp_path):
    from test_io import check_fuzzed

    good = C.bundled_calibration_path("nucleo-iks02a1").read_bytes()
    ref = C.Calibration.from_json(good.decode())

    def same(cal):  # a garbled letter in the free-text source is harmless; every number must be the reference's
        return {**vars(cal), "source": ""} == {**vars(ref), "source": ""}

    outcome = check_fuzzed(tmp_path / "fuzzed.json", C.Calibration.load, good, rest_calibration.CalibrationError, same)
    assert outcome["rejected"] > 100 and outcome["loaded"] > 0
