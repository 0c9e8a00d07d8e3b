"""kfkit.datasets: bundled recordings match their simulations, loading, and physics sanity."""

import numpy as np
import pytest

from kfkit import datasets
from kfkit.frames import accel_tilt, wrap_angle

NAME = "01_roll_sine"
SHAKES = ((22.0, 25.0), (42.0, 45.0))  # shake windows of the bundled recording, s


@pytest.fixture(scope="module")
def roll_sine():
    return datasets.load(NAME)


def in_shakes(t, margin=0.0):
    return np.any([(t >= a - margin) & (t < b + margin) for a, b in SHAKES], axis=0)


# --- shipped files and regeneration -------------------------------------------------------
# One full rebuild checks every shipped file; the checker's messages are tested on a few files of each kind
# (a recording, a vehicle drive, a calibration), which go through the same code.
FEW = (NAME, "06_lane_change", "calibration_phone-phyphox")


@pytest.fixture()
def few_files(monkeypatch):
    monkeypatch.setattr(datasets, "BUNDLED", {name: datasets.BUNDLED[name] for name in FEW})


@pytest.mark.slow
def test_regenerate_writes_every_bundled_file_byte_for_byte_as_shipped(tmp_path):
    written = datasets.regenerate(directory=tmp_path)
    assert written == [str(tmp_path / f"{name}{entry.suffix}") for name, entry in datasets.BUNDLED.items()]
    shipped = datasets.data_dir()
    for path in sorted(p for p in tmp_path.rglob("*") if p.is_file()):
        rel = path.relative_to(tmp_path)
        assert path.read_bytes() == (shipped / rel).read_bytes(), f"data/{rel} differs from what its simulation makes"


def test_check_passes_on_what_regenerate_wrote(tmp_path, few_files):
    datasets.regenerate(directory=tmp_path)
    assert datasets.regenerate(check=True, directory=tmp_path) == []


def test_check_reports_a_changed_byte_with_its_line(tmp_path, few_files):
    datasets.regenerate(directory=tmp_path)
    path = tmp_path / f"{NAME}.csv"
    lines = path.read_text(encoding="utf-8").split("\n")
    lines[99] = lines[99][:-1] + ("7" if lines[99][-1] != "7" else "8")  # line 100, last character
    path.write_text("\n".join(lines), encoding="utf-8")
    [report] = datasets.regenerate(check=True, directory=tmp_path)
    assert str(path) in report and "line 100" in report


def test_check_reports_a_missing_file(tmp_path, few_files):
    datasets.regenerate(directory=tmp_path)
    (tmp_path / f"{NAME}.csv").unlink()
    [report] = datasets.regenerate(check=True, directory=tmp_path)
    assert str(tmp_path / f"{NAME}.csv") in report and "missing" in report


def test_check_reports_a_truncated_file(tmp_path, few_files):
    datasets.regenerate(directory=tmp_path)
    path = tmp_path / f"{NAME}.csv"
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    path.write_text("".join(lines[:50]), encoding="utf-8")
    [report] = datasets.regenerate(check=True, directory=tmp_path)
    assert str(path) in report and "line counts differ" in report


def test_loaded_matches_built(roll_sine):
    built = datasets.build(NAME)
    assert roll_sine.meta == built.meta and roll_sine.columns == built.columns
    for c in ("seq", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz"):
        np.testing.assert_array_equal(roll_sine[c], built[c])


@pytest.mark.parametrize("func", [datasets.load, datasets.build])
def test_unknown_name_lists_the_available(func):
    with pytest.raises(ValueError, match=f"'nope'.*{NAME}"):
        func("nope")


def test_kfkit_data_overrides_the_folder(tmp_path, monkeypatch, few_files):
    monkeypatch.setenv("KFKIT_DATA", str(tmp_path))
    assert datasets.data_dir() == tmp_path
    with pytest.raises(FileNotFoundError, match="kfkit data regenerate") as err:
        datasets.load(NAME)
    assert str(tmp_path) in str(err.value)
    datasets.regenerate()  # default folder follows KFKIT_DATA
    assert len(datasets.load(NAME)) == 60 * 104


# --- physics sanity on the bundled roll recording -----------------------------------------


def test_roll_sine_basic_shape(roll_sine):
    assert roll_sine.rate_hz == 104.0 and len(roll_sine) == 6240
    truth = roll_sine.truth()
    assert np.abs(truth[:, 0]).max() == pytest.approx(np.radians(30.0), abs=np.radians(0.5))
    assert np.all(truth[:, 1:] == 0)


def test_accel_tilt_follows_true_roll_outside_shakes(roll_sine):
    roll_acc, pitch_acc = accel_tilt(roll_sine.body("acc"))
    err = np.degrees(wrap_angle(roll_acc - roll_sine["true_roll"]))
    calm = ~in_shakes(roll_sine.t, margin=0.2)
    assert np.sqrt(np.mean(err[calm] ** 2)) < 3.0
    assert np.sqrt(np.mean(np.degrees(pitch_acc[calm]) ** 2)) < 3.0
    # the shakes are there, and fool the accelerometer far more
    assert np.sqrt(np.mean(err[in_shakes(roll_sine.t)] ** 2)) > 3 * np.sqrt(np.mean(err[calm] ** 2))


def test_gyro_x_integrates_to_the_roll_change(roll_sine):
    p = roll_sine.body("gyr")[:, 0]
    roll = roll_sine["true_roll"]
    per = 104  # 1 s
    starts = range(0, len(p) - per, per)
    gyro_change = np.array([np.trapezoid(p[k : k + per + 1], dx=1 / 104) for k in starts])
    true_change = np.array([roll[k + per] - roll[k] for k in starts])
    assert np.abs(gyro_change - true_change).max() < np.radians(1.0)  # zero-rate level ±1 °/s typ.
    # removing the bias seen at rest (first 5 s) leaves its random walk, 1e-4 rad/s/√s:
    # within 60 s it drifts less than 4·1e-4·√60 ≈ 0.003 rad/s (0.18 °/s)
    bias = p[roll_sine.t < 5.0].mean()
    assert np.abs(gyro_change - bias - true_change).max() < np.radians(0.25)


@pytest.mark.parametrize("name", ["04_attitude_tour", "04_gimbal_lock", "04_mag_disturbance"])
def test_lab04_recordings_take_the_labs_02_03_calibration(name):
    """Lab 04's files come from the board labs 02/03 calibrate: corrected, the field has the
    reference norm and the specific force at rest is g along the true 'up' (physics, not the filter)."""
    from scipy.spatial.transform import Rotation

    from kfkit.calibration import Calibration, bundled_calibration_path

    rec = datasets.load(name)
    gyr, acc, mag = Calibration.load(bundled_calibration_path(rec.meta["board"])).apply(rec)
    truth = rec.truth()
    R_bn = Rotation.from_euler("ZYX", truth[:, ::-1]).inv()
    field = np.array(rec.meta["sim"]["field_n"])
    calm = ~rec.phase("mag_disturbance") if name == "04_mag_disturbance" else np.ones(len(rec), bool)
    fresh = calm & ~np.isnan(mag[:, 0])
    np.testing.assert_allclose(np.linalg.norm(mag[fresh], axis=1).mean(), np.linalg.norm(field), rtol=0.01)
    np.testing.assert_allclose(mag[fresh], R_bn[fresh].apply(field), atol=2.0)  # µT: noise 0.3, residual iron
    rest = rec.phase("stationary")
    np.testing.assert_allclose(acc[rest].mean(axis=0), R_bn[rest].apply([0.0, 0.0, -9.80665]).mean(axis=0), atol=0.02)
    assert np.abs(gyr[rest].mean(axis=0)).max() < np.radians(0.05)  # the calibrated gyro bias is gone
    if name == "04_mag_disturbance":  # inside the window the field is 15 % stronger
        inside = rec.phase("mag_disturbance") & ~np.isnan(mag[:, 0]) & (rec.t > 13.0) & (rec.t < 19.0)
        assert np.linalg.norm(mag[inside], axis=1).mean() > 1.1 * np.linalg.norm(field)
