"""The bundled real recordings (kfkit.real_data): the resampler against signal theory, the frame and timing
against physics (gravity at rest, gyro integration vs motion capture), the conversion checked like
``data regenerate --check``, attribution, size. Tests that read ../shared/ skip cleanly without it."""

import json

import numpy as np
import pytest
import scipy.signal
from scipy.spatial.transform import Rotation, Slerp

from kfkit import datasets, real_data
from kfkit.cli import main
from kfkit.frames import G, euler_to_quat
from kfkit.io import RecordingError, load_recording, recording_text
from kfkit.paths import data_dir

FS = 2000.0 / 7.0  # BROAD's rate, Hz
BROAD_FILES = [name for name in real_data.REAL if "broad" in name]
SHARED = real_data.shared_dir()
needs_shared = pytest.mark.skipif(
    not (SHARED / "broad").is_dir() or not (SHARED / "racetrack").is_dir(),
    reason=f"the originals are not at {SHARED} (set KFKIT_SHARED_DATA)",
)


def _sine(freq, n=20000, fs=FS, phase=0.3):
    return np.sin(2 * np.pi * freq * np.arange(n) / fs + phase)


def test_resampler_passes_the_band_and_stops_aliases():
    """A 5 Hz sine comes through at 100 Hz with its amplitude and phase (zero delay); 60 and 120 Hz, which
    decimation without a filter would fold to 40 and 20 Hz, come through at least 60 dB down."""
    t_out = np.arange(7000) / 100.0
    out = real_data.resample(_sine(5.0), FS, 100.0)
    inner = slice(200, 6800)  # away from the ends
    assert np.max(np.abs(out[inner] - np.sin(2 * np.pi * 5.0 * t_out[inner] + 0.3))) < 1e-3
    for freq in (60.0, 120.0):
        assert np.max(np.abs(real_data.resample(_sine(freq), FS, 100.0)[inner])) < 1e-3
    naive = _sine(60.0)[::20][inner]  # what picking every 20/7-th sample would keep: a full-size alias
    assert np.max(np.abs(naive)) > 0.5


def test_antialias_fir_meets_its_specification():
    fs_up = FS * 7
    h = real_data.antialias_fir(fs_up)
    assert len(h) % 2 == 1 and np.allclose(h, h[::-1])  # odd, symmetric: linear phase, whole-sample delay
    freqs, resp = scipy.signal.freqz(h, worN=2**16, fs=fs_up)
    gain = np.abs(resp)
    assert np.max(np.abs(gain[freqs <= real_data.PASS_HZ] - 1.0)) < 2e-3  # Kaiser: ripple ≈ 10^(−60/20)
    assert np.max(gain[freqs >= real_data.STOP_HZ]) < 10 ** (-real_data.STOP_DB / 20) * 1.001


def test_resampler_rejects_rates_without_a_small_ratio():
    with pytest.raises(ValueError, match="no ratio"):
        real_data.resample(np.zeros(100), FS, 100.0 * np.pi)


def test_slerp_matches_scipy_and_never_bridges_a_gap():
    rng = np.random.default_rng(3)
    rot = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (200, 3)), axis=0))
    q = rot.as_quat()[:, [3, 0, 1, 2]]
    t = np.sort(rng.uniform(0, 199 / FS, 300))
    ours = real_data.slerp_at(q, FS, t)
    theirs = Slerp(np.arange(200) / FS, rot)(t).as_quat()[:, [3, 0, 1, 2]]
    sign = np.sign(np.sum(ours * theirs, axis=1))[:, None]
    assert np.max(np.abs(ours - sign * theirs)) < 1e-12
    q[50] = np.nan
    gap = real_data.slerp_at(q, FS, np.array([49.5, 50.0, 50.5, 51.0]) / FS)
    assert np.isnan(gap[:3]).all() and np.isfinite(gap[3]).all()


@pytest.fixture(scope="module")
def broad():
    return {name: datasets.load(name) for name in BROAD_FILES}


@pytest.mark.slow
def test_body_frame_reads_gravity_and_the_accelerometer_tilt_matches_the_motion_capture(broad):
    """At rest the specific force is R_bn(−g_n): 9.81 m/s² long within 1.5 % (the dataset's own accelerometer
    calibration: trial 06's session reads 1.0 % high), and the roll/pitch it gives agree with the motion capture
    within 0.5° (the sensor's alignment to the markers and the accelerometer's bias)."""
    for name, rec in broad.items():
        rest = np.any([(rec.t >= p["start"]) & (rec.t < p["end"]) for p in rec.phases if p["label"] == "rest"], axis=0)
        f = rec.body("acc")[rest]
        assert abs(np.median(np.linalg.norm(f, axis=1)) / G - 1) < 0.015, name
        q_true = euler_to_quat(np.column_stack([rec["true_roll"], rec["true_pitch"], rec["true_yaw"]])[rest])
        seen = np.isfinite(q_true).all(axis=1)
        g_b = Rotation.from_quat(q_true[seen][:, [1, 2, 3, 0]]).inv().apply([0.0, 0.0, -G])  # R_bn(−g_n)
        angle = np.degrees(
            np.arccos(np.clip(np.sum(g_b * f[seen], axis=1) / (G * np.linalg.norm(f[seen], axis=1)), -1, 1))
        )
        assert np.median(angle) < 0.5, name


def test_gyro_integration_follows_the_motion_capture(broad):
    """Over 1 s windows in the movement phase, the rotation the body rates integrate to (scipy's Rotation,
    midpoint rule) equals the motion capture's relative rotation within 2°: the gyro is in the body frame
    of the truth and the resampling kept the two in time."""
    for name in ("01_broad_slow_rotation", "04_broad_fast_rotation"):
        rec = broad[name]
        w = rec.body("gyr")
        q = euler_to_quat(np.column_stack([rec["true_roll"], rec["true_pitch"], rec["true_yaw"]]))
        moving = [p for p in rec.phases if p["label"] == "movement"][0]
        errors = []
        for start in np.arange(moving["start"] + 5, moving["end"] - 5, 7.0):
            i0, i1 = np.searchsorted(rec.t, [start, start + 1.0])
            if not np.isfinite(q[[i0, i1]]).all():
                continue
            r = Rotation.identity()
            for k in range(i0, i1):
                r = r * Rotation.from_rotvec(0.5 * (w[k] + w[k + 1]) * (rec.t[k + 1] - rec.t[k]))
            truth = Rotation.from_quat(q[i0][[1, 2, 3, 0]]).inv() * Rotation.from_quat(q[i1][[1, 2, 3, 0]])
            errors.append(np.degrees((r.inv() * truth).magnitude()))
        assert len(errors) >= 8 and np.median(errors) < 2.0, (name, np.round(errors, 2))


@pytest.mark.slow
def test_every_real_file_carries_its_attribution_and_the_data_readme_names_it():
    readme = (data_dir() / "README.md").read_text(encoding="utf-8")
    for name, entry in real_data.REAL.items():
        rec = datasets.load(name)
        assert "licence" in rec.meta["license"].lower() or "CC BY 4.0" in rec.meta["license"], name
        assert rec.meta["changes"], name
        assert f"`{name}{entry.suffix}`" in readme, f"data/README.md does not describe {name}"
    assert "Laidig" in readme and "CC BY 4.0" in readme and "MIT" in readme and "Leanza" in readme


def test_the_real_data_stays_under_20_mb():
    total = sum((data_dir() / f"{name}{entry.suffix}").stat().st_size for name, entry in real_data.REAL.items())
    assert total < 20e6, f"{total / 1e6:.1f} MB"


def test_an_empty_truth_cell_loads_as_nan_and_saves_back_empty(tmp_path):
    rec = datasets.load("01_broad_slow_rotation")
    unseen = np.flatnonzero(np.isnan(rec["true_roll"]))
    assert unseen.size  # the markers were not seen for a while
    path = tmp_path / "copy.csv"
    path.write_text(recording_text(rec), encoding="utf-8")
    again = load_recording(path)
    assert np.array_equal(np.isnan(again["true_roll"]), np.isnan(rec["true_roll"]))
    line = path.read_text(encoding="utf-8").splitlines()[2 + unseen[0]]
    assert line.endswith(",,,")  # true_roll, true_pitch, true_yaw empty


def test_an_empty_sensor_cell_is_still_an_error(tmp_path):
    lines = (data_dir() / "01_broad_slow_rotation.csv").read_text(encoding="utf-8").splitlines(keepends=True)[:10]
    cells = lines[5].split(",")
    cells[2] = ""  # ax
    lines[5] = ",".join(cells)
    path = tmp_path / "bad.csv"
    path.write_text("".join(lines), encoding="utf-8")
    with pytest.raises(RecordingError, match=r"bad\.csv.*line 6.*'ax'"):
        load_recording(path)


@pytest.mark.slow
@needs_shared
def test_the_bundled_files_are_what_the_conversion_makes():
    report, skipped = datasets.convert_real(check=True)
    assert not skipped and not report, report + skipped


@pytest.mark.slow
@needs_shared
def test_data_real_check_names_a_changed_file_and_writes_nothing(tmp_path, capsys):
    for name, entry in real_data.REAL.items():
        (tmp_path / f"{name}{entry.suffix}").write_text(
            (data_dir() / f"{name}{entry.suffix}").read_text(encoding="utf-8")
        )
    target = tmp_path / "06_racetrack.csv"
    lines = target.read_text(encoding="utf-8").splitlines(keepends=True)
    lines[500] = lines[500].replace("0", "1", 1)
    target.write_text("".join(lines), encoding="utf-8")
    before = target.read_text(encoding="utf-8")
    report, _ = datasets.convert_real(check=True, directory=tmp_path)
    assert len(report) == 1 and "06_racetrack.csv" in report[0] and "line 501" in report[0]
    assert target.read_text(encoding="utf-8") == before


def test_data_real_without_the_originals_skips_each_file_and_says_where_it_looked(tmp_path, capsys):
    assert main(["data", "real", "--check", "--source", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("skipped") == len(real_data.REAL) and str(tmp_path / "broad") in out


def test_racetrack_keeps_the_log_values_and_the_published_parameters():
    rec = datasets.load("06_racetrack")
    meta = rec.meta["vehicle"]
    assert (meta["m"], meta["a"], meta["b"], meta["Cf"], meta["Cr"]) == (982.0, 1.33, 1.07, 70_000.0, 120_000.0)
    assert abs(meta["Iz"] - 982.0 / 12 * (1.7**2 + 4.09**2)) < 0.1
    assert "mu" not in meta  # none was published: lab 06 reads the friction from the log (vehicle.peak_friction)
    assert np.allclose(np.diff(rec.t), 0.01, atol=1e-6)
    beta_from_v = np.arctan2(rec["true_vy"], rec["vx"])  # β ≈ v_y / v_x: the log's two measurements agree
    assert np.sqrt(np.mean((beta_from_v - rec["true_beta"]) ** 2)) < np.radians(0.2)
    assert json.loads(json.dumps(rec.meta))  # plain JSON metadata
