"""kfkit.readers.load_broad: a small file in BROAD's format written here, and the real trials when present."""

import glob
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from scipy.spatial.transform import Rotation

from kfkit.filters import estimate_attitude
from kfkit.frames import G, enu_to_ned_quat, quat_to_dcm
from kfkit.io import RecordingError
from kfkit.labs.lab04b import vqf_quat
from kfkit.metrics import attitude_errors
from kfkit.readers import load_broad

BROAD_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"
REAL_TRIALS = sorted(glob.glob(str(BROAD_DIR / "*.mat")))
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # swap x, y; negate z
FIELD_ENU = np.array([0.0, 18.0, -44.0])  # magnetic north along ENU y, pointing down: µT


def write_trial(path, n=3000, rate=200.0, seed=0):
    """A BROAD-format trial: an IMU (z up) turned slowly, ENU truth with a NaN gap."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    rotvec = np.column_stack([0.4 * np.sin(0.5 * t), 0.3 * np.sin(0.3 * t + 1), 1.2 * np.sin(0.2 * t)])
    rot = Rotation.from_rotvec(rotvec)  # IMU → ENU
    omega = np.empty((n, 3))  # body rates from consecutive rotations (finite differences)
    omega[1:] = (rot[:-1].inv() * rot[1:]).as_rotvec() * rate
    omega[0] = omega[1]
    acc = rot.inv().apply([0.0, 0.0, G]) + rng.normal(0, 0.02, (n, 3))  # specific force points up
    mag = rot.inv().apply(FIELD_ENU) + rng.normal(0, 0.2, (n, 3))
    quat = rot.as_quat()[:, [3, 0, 1, 2]]
    quat[500:520] = np.nan
    movement = np.zeros((n, 1), np.uint8)
    movement[400:] = 1
    scipy.io.savemat(
        path,
        {
            "imu_gyr": omega + rng.normal(0, 0.002, (n, 3)),
            "imu_acc": acc,
            "imu_mag": mag,
            "opt_quat": quat,
            "opt_pos": np.zeros((n, 3)),
            "sampling_rate": np.array([[rate]]),
            "movement": movement,
            "info": np.array(["test trial"]),
        },
    )
    return rot


def test_enu_to_ned_quaternion_matches_the_frame_matrix():
    rng = np.random.default_rng(1)
    rot = Rotation.from_quat(rng.normal(size=(40, 4)))
    q_ned = enu_to_ned_quat(rot.as_quat()[:, [3, 0, 1, 2]])
    np.testing.assert_allclose(quat_to_dcm(q_ned), ENU_TO_NED @ rot.as_matrix(), atol=1e-12)
    assert np.isclose(np.linalg.det(ENU_TO_NED), 1.0)


def test_load_broad_reads_the_format_and_converts_truth_to_ned(tmp_path):
    path = tmp_path / "99_test_trial.mat"
    rot = write_trial(path)
    rec = load_broad(path)
    raw = scipy.io.loadmat(path)
    assert len(rec) == 3000 and rec.rate_hz == 200.0 and rec.meta["trial"] == "99_test_trial"
    np.testing.assert_array_equal(rec.body("gyr"), raw["imu_gyr"])
    np.testing.assert_array_equal(rec.body("acc"), raw["imu_acc"])
    np.testing.assert_array_equal(rec.body("mag"), raw["imu_mag"])
    q = np.column_stack([rec[c] for c in ("true_qw", "true_qx", "true_qy", "true_qz")])
    ok = ~np.isnan(q[:, 0])
    assert ok.sum() == 2980 and np.isnan(rec.truth()[500:520]).all()
    np.testing.assert_allclose(quat_to_dcm(q[ok]), ENU_TO_NED @ rot.as_matrix()[ok], atol=1e-12)
    ned = Rotation.from_matrix(ENU_TO_NED @ rot.as_matrix()[ok]).as_euler("ZYX")[:, ::-1]
    np.testing.assert_allclose(np.cos(rec.truth()[ok] - ned), 1.0, atol=1e-9)
    assert rec["movement"].dtype == bool and rec["movement"].sum() == 2600
    # At rest the truth must map the measured specific force onto −g along NED down.
    f_n = np.einsum("nij,nj->ni", quat_to_dcm(q[:5]), rec.body("acc")[:5])
    np.testing.assert_allclose(f_n, np.tile([0, 0, -G], (5, 1)), atol=0.2)


def test_filters_on_a_broad_format_file_agree_with_its_truth(tmp_path):
    # End to end: the filter's sensor → NED (magnetic north) output against truth converted from ENU.
    path = tmp_path / "98_test_trial.mat"
    write_trial(path, n=4000)
    rec = load_broad(path)
    q_true = np.column_stack([rec[c] for c in ("true_qw", "true_qx", "true_qy", "true_qz")])
    for method in ("euler-ekf", "mekf"):
        res = estimate_attitude(rec.body("gyr"), rec.body("acc"), rec.body("mag"), rec.rate_hz, method=method)
        total, heading, incl = attitude_errors(res.quat, q_true)
        keep = rec["movement"] & ~np.isnan(total)
        assert np.degrees(np.sqrt(np.mean(total[keep] ** 2))) < 1.5, method


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d.pop("opt_quat"), "missing field.*opt_quat"),
        (lambda d: d.update(imu_acc=np.zeros((10, 2))), r"'imu_acc' must have shape \(N, 3\)"),
        (lambda d: d.update(imu_mag=np.zeros((9, 3))), "'imu_mag' has 9 rows but imu_gyr has 10"),
        (lambda d: d.update(movement=np.zeros((3, 1))), "'movement' has 3 entries"),
        (lambda d: d.update(sampling_rate=np.array([[0.0]])), "'sampling_rate' must be one positive finite number"),
        (lambda d: d["imu_gyr"].__setitem__((4, 1), np.nan), "'imu_gyr' row 4 is not finite"),
    ],
)
def test_load_broad_names_the_bad_field(tmp_path, change, message):
    data = {
        "imu_gyr": np.zeros((10, 3)),
        "imu_acc": np.tile([0, 0, G], (10, 1)),
        "imu_mag": np.ones((10, 3)),
        "opt_quat": np.tile([1.0, 0, 0, 0], (10, 1)),
        "sampling_rate": np.array([[100.0]]),
        "movement": np.ones((10, 1), np.uint8),
    }
    change(data)
    path = tmp_path / "bad.mat"
    scipy.io.savemat(path, data)
    with pytest.raises(RecordingError, match=message) as err:
        load_broad(path)
    assert "bad.mat" in str(err.value)


def test_load_broad_rejects_a_file_that_is_not_mat(tmp_path):
    path = tmp_path / "trial.mat"
    path.write_text("not a mat file")
    with pytest.raises(RecordingError, match="trial.mat"):
        load_broad(path)
    with pytest.raises(FileNotFoundError, match="no BROAD trial"):
        load_broad(tmp_path / "missing.mat")


@pytest.mark.skipif(not REAL_TRIALS, reason=f"no BROAD trials in {BROAD_DIR}")
@pytest.mark.parametrize("path", REAL_TRIALS, ids=[Path(p).stem for p in REAL_TRIALS])
def test_real_broad_trial(path):
    rec = load_broad(path)
    q = np.column_stack([rec[c] for c in ("true_qw", "true_qx", "true_qy", "true_qz")])
    ok = ~np.isnan(q[:, 0])
    np.testing.assert_allclose(np.linalg.norm(q[ok], axis=1), 1.0, atol=1e-6)
    assert rec["movement"].any() and 100 < rec.rate_hz < 1000
    # Physics check of the ENU → NED conversion on real data: in the still start, the truth maps the
    # measured specific force onto −g along NED down (within a couple of degrees).
    still = np.flatnonzero(ok & ~rec["movement"])[:200]
    f_n = np.einsum("nij,nj->ni", quat_to_dcm(q[still]), rec.body("acc")[still]).mean(axis=0)
    assert np.degrees(np.arccos(-f_n[2] / np.linalg.norm(f_n))) < 2.0
    # ... and the measured field onto north, dipping down (BROAD's global frame is magnetic ENU: a
    # wrong x/y swap or sign would put it east, west or south, a wrong z would make it point up).
    m_n = np.einsum("nij,nj->ni", quat_to_dcm(q[still]), rec.body("mag")[still]).mean(axis=0)
    assert abs(np.degrees(np.arctan2(m_n[1], m_n[0]))) < 5.0 and m_n[2] > 0
    # The first 20 s through the MEKF: inclination within a degree of the optical truth.
    n = int(20 * rec.rate_hz)
    res = estimate_attitude(rec.body("gyr")[:n], rec.body("acc")[:n], rec.body("mag")[:n], rec.rate_hz, method="mekf")
    _, _, incl = attitude_errors(res.quat, q[:n])
    assert np.degrees(np.sqrt(np.nanmean(incl**2))) < 1.0


UNDISTURBED_TRIALS = [p for p in REAL_TRIALS if "_undisturbed_" in Path(p).name]


@pytest.mark.slow
@pytest.mark.skipif(not UNDISTURBED_TRIALS, reason=f"no undisturbed BROAD trials in {BROAD_DIR}")
@pytest.mark.parametrize("path", UNDISTURBED_TRIALS, ids=[Path(p).stem for p in UNDISTURBED_TRIALS])
def test_mekf_on_a_whole_real_trial(path):
    # Issue 29's goal, kept from regressing: the MEKF with its defaults over the whole trial at the trial's own
    # rate, BROAD's total error over the movement phases against the optical truth, at most VQF's (Laidig & Seel
    # 2023, the best published filter on BROAD; causal, its defaults) on the same data. Undisturbed trials only:
    # with a magnet near or on the IMU (trials 28, 34) the bench (benchmarks/bench_attitude.py) holds the figure.
    # On trial 06 both follow a field that in motion is 4° off the rest's north and 7 % stronger (the bench's
    # "field in the truth's frame" table): 3.8° and 4.0°.
    pytest.importorskip("vqf")
    rec = load_broad(path)
    q = np.column_stack([rec[c] for c in ("true_qw", "true_qx", "true_qy", "true_qz")])
    gyr, acc, mag = rec.body("gyr"), rec.body("acc"), rec.body("mag")
    res = estimate_attitude(gyr, acc, mag, rec.rate_hz, method="mekf")
    peer = vqf_quat(gyr, acc, mag, rec.rate_hz)
    moving = rec["movement"]
    ours, theirs = (np.degrees(np.sqrt(np.nanmean(attitude_errors(e, q)[0][moving] ** 2))) for e in (res.quat, peer))
    assert ours < 4.5 and ours <= theirs, (ours, theirs)


def minimal_trial(**changes):
    data = {
        "imu_gyr": np.zeros((10, 3)),
        "imu_acc": np.tile([0, 0, G], (10, 1)),
        "imu_mag": np.ones((10, 3)),
        "opt_quat": np.tile([1.0, 0, 0, 0], (10, 1)),
        "sampling_rate": np.array([[100.0]]),
        "movement": np.ones((10, 1), np.uint8),
    }
    data.update(changes)
    return {k: v for k, v in data.items() if v is not None}


@pytest.mark.parametrize(
    "changes, message",
    [
        (
            {"sampling_rate": np.array([[np.inf]])},
            r"'sampling_rate' must be one positive finite number \(Hz\), got \[inf\]",
        ),
        ({"sampling_rate": np.array([[np.nan]])}, r"'sampling_rate' must be one positive finite number"),
        ({"sampling_rate": np.zeros((0, 0))}, r"'sampling_rate' must be one positive finite number \(Hz\), got \[\]"),
        ({"sampling_rate": np.array([[100.0, 200.0]])}, r"got \[100.0, 200.0\]"),
        ({"sampling_rate": None}, r"missing field\(s\) sampling_rate"),
        ({"sampling_rate": np.array(["fast"])}, r"'sampling_rate' must be numeric"),
        ({"movement": np.full((10, 1), 2.0)}, r"'movement' must hold 0 or 1, got 2"),
        ({"opt_quat": np.tile([2.0, 0, 0, 0], (10, 1))}, r"'opt_quat' row 0 is not a unit quaternion \(norm 2\)"),
        ({"opt_quat": np.tile([np.nan, 0, 0, 0], (10, 1))}, r"'opt_quat' row 0 is not finite"),
        ({"imu_mag": np.full((10, 3), np.inf)}, r"'imu_mag' row 0 is not finite"),
        (
            {
                "imu_gyr": np.zeros((1, 3)),
                "imu_acc": np.zeros((1, 3)),
                "imu_mag": np.zeros((1, 3)),
                "opt_quat": np.array([[1.0, 0, 0, 0]]),
                "movement": np.ones((1, 1)),
            },
            "at least 2 samples",
        ),
    ],
    ids=[
        "rate-inf",
        "rate-nan",
        "rate-empty",
        "rate-two",
        "rate-missing",
        "rate-text",
        "movement",
        "quat-norm",
        "quat-partial-nan",
        "mag-inf",
        "one-sample",
    ],
)
def test_load_broad_checks_the_rate_and_the_truth(tmp_path, changes, message):
    path = tmp_path / "bad.mat"
    scipy.io.savemat(path, minimal_trial(**changes))
    with pytest.raises(RecordingError, match=re.escape(str(path)) + ": .*" + message):
        load_broad(path)


def test_load_broad_names_a_v73_file_and_gaps_stay_gaps(tmp_path):
    # MATLAB v7.3 files are HDF5 with a 128-byte MAT header whose version field is 0x0200 (scipy refuses them).
    path = tmp_path / "v73.mat"
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    path.write_bytes(header.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM" + b"\x89HDF\r\n\x1a\n" + b"\x00" * 512)
    with pytest.raises(RecordingError, match=re.escape(str(path)) + r": a MATLAB v7.3 \(HDF5\) .mat file.*-v7"):
        load_broad(path)
    ok = tmp_path / "gaps.mat"  # NaN rows are gaps the filters skip: a magnetometer without a sample, markers unseen
    mag, quat = np.ones((10, 3)), np.tile([1.0, 0, 0, 0], (10, 1))
    mag[3], quat[4] = np.nan, np.nan
    scipy.io.savemat(ok, minimal_trial(imu_mag=mag, opt_quat=quat))
    rec = load_broad(ok)
    assert np.isnan(rec["mx"][3]) and np.isnan(rec["true_qw"][4]) and rec.rate_hz == 100.0


def test_fuzzed_broad_files_load_the_same_numbers_or_name_the_file(tmp_path):
    """A .mat file has no checksum, so a garbled number inside it cannot be seen; a cut file always can."""
    from test_io import check_fuzzed

    good = tmp_path / "good.mat"
    write_trial(good, n=200)
    ref = load_broad(good)

    def same(rec):
        return all(np.array_equal(rec[c], ref[c], equal_nan=True) for c in ref.columns)

    cut = check_fuzzed(tmp_path / "fuzzed.mat", load_broad, good.read_bytes(), RecordingError, same, garble=False)
    assert cut["rejected"] > 100  # a few cuts lose only the unused fields after the trial's: identical numbers
    path = tmp_path / "garbled.mat"  # garbled anywhere: nothing but the loader's own error may come out
    original = good.read_bytes()
    for k in np.random.default_rng(1).integers(0, len(original), 200):
        data = bytearray(original)
        data[k] ^= 0xFF
        path.write_bytes(bytes(data))
        try:
            load_broad(path)
        except RecordingError as e:
            assert str(path) in str(e)
