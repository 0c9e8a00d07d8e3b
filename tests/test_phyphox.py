"""phyphox exports → Recordings: formats, frames, one time base, errors, and the bundled phone recording.

The exports here are written by this file's own writer, from phyphox's source as read (Android
``DataExport.java``: quoted labels, ``0.000000000E0`` numbers, ``NaN`` padding, a newline after every
line; iOS ``ExperimentExportSet.swift``: ``""`` for a missing value, no newline after the last line;
the five separator/decimal variants), not by ``kfkit.readers.phyphox_export``'s writer. Physics oracle: the phone's
readings come from scipy's Rotation applied to the phone's axes as Android documents them (x right,
y up the screen, z out of it; the accelerometer reads +g on z face up).
"""

import math
import re
import shutil
import warnings
import zipfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit import datasets, frames, io, metrics, phone_sim, readers
from kfkit.clocks import OneClock, SampleCounter
from kfkit.filters import estimate_attitude
from kfkit.io import RecordingError
from kfkit.phone_sim import simulate_phone
from kfkit.readers import phyphox_export
from kfkit.sensors import PHONE_LSB, PHONE_MOUNTS, SENSORS

G = 9.80665
FIELD_N = np.array(frames.MAG_FIELD_LONDON)
DEG = np.pi / 180


# --- an independent phyphox writer ------------------------------------------------------------------


def java_sci(v: float, decimal=".") -> str:
    """Java DecimalFormat("0.000000000E0"): one digit, nine decimals, exponent without '+' or padding."""
    if math.isnan(v):
        return "NaN"
    if v == 0:
        return ("-" if math.copysign(1, v) < 0 else "") + "0" + decimal + "0" * 9 + "E0"
    e = math.floor(math.log10(abs(v)))
    m = round(abs(v) / 10**e, 9)
    if m >= 10:
        m, e = m / 10, e + 1
    digits = f"{m:.9f}".replace(".", decimal)
    return ("-" if v < 0 else "") + digits + f"E{e}"


def write_set(path, labels, columns, sep=",", decimal=".", ios=False):
    """One export set as phyphox writes it; columns may differ in length (padded as the platform pads)."""
    n = max(len(c) for c in columns)
    lines = [sep.join(f'"{label}"' for label in labels)]
    for i in range(n):
        cells = []
        for c in columns:
            if i < len(c):
                cells.append(java_sci(float(c[i]), decimal))
            else:
                cells.append('""' if ios else "NaN")
        lines.append(sep.join(cells))
    text = "\n".join(lines) + ("" if ios else "\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text.encode("utf-8"))


ANDROID_LABELS = {
    "acc": ["Acceleration x (m/s^2)", "Acceleration y (m/s^2)", "Acceleration z (m/s^2)"],
    "gyr": ["Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)"],
    "mag": ["Magnetic field x (µT)", "Magnetic field y (µT)", "Magnetic field z (µT)"],
}
IOS_LABELS = {
    "acc": ["X (m/s^2)", "Y (m/s^2)", "Z (m/s^2)"],
    "gyr": ["X (rad/s)", "Y (rad/s)", "Z (rad/s)"],
    "mag": ["X (µT)", "Y (µT)", "Z (µT)"],
}
SETS = {"acc": "Accelerometer", "gyr": "Gyroscope", "mag": "Magnetometer"}


def write_simple_experiment(folder, samples, sep=",", decimal=".", ios=False, sensors=("acc", "gyr", "mag")):
    labels = IOS_LABELS if ios else ANDROID_LABELS
    for k in sensors:
        t, v = samples[k]
        write_set(
            folder / f"{SETS[k]}.csv", ["Time (s)"] + labels[k], [t, v[:, 0], v[:, 1], v[:, 2]], sep, decimal, ios
        )
    return folder


# --- the phone's readings from scipy ----------------------------------------------------------------

#: the phone flat, screen up, top edge north: its axes (x right, y up the screen, z out) in NED
R_NS_FLAT_NORTH = np.column_stack([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: the body frame FRD of a phone lying flat, top edge forward, written in phone axes (columns x_b, y_b, z_b)
R_SB_FLAT = np.column_stack([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def tilt_samples(axis, angle_deg, heading_deg=60.0, rates=(100.0, 97.0, 50.0)):
    """A phone at rest flat (top edge at ``heading_deg``) 0–2 s, tilted smoothly by ``angle_deg`` about
    its own ``axis`` ('x' right edge, 'y' top edge) during 2–3 s, at rest tilted 3–5 s.
    Returns ({sensor: (t, values)}, function t → R_ns)."""

    def angle(t):
        u = np.clip(t - 2.0, 0.0, 1.0)
        return np.radians(angle_deg) * u**3 * (10 - 15 * u + 6 * u**2)

    def rate(t):
        u = np.clip(t - 2.0, 0.0, 1.0)
        return np.radians(angle_deg) * 30 * u**2 * (1 - u) ** 2

    heading = Rotation.from_euler("z", heading_deg, degrees=True)

    def R_ns(t):
        tilt = Rotation.from_rotvec(np.outer(np.atleast_1d(angle(t)), np.eye(3)["xyz".index(axis)]))
        return (heading * Rotation.from_matrix(R_NS_FLAT_NORTH) * tilt).as_matrix()

    out = {}
    for k, rate_hz, phase in (("gyr", rates[0], 0.0041), ("acc", rates[1], 0.0017), ("mag", rates[2], 0.0093)):
        t = phase + np.arange(int(5.0 * rate_hz)) / rate_hz
        R = R_ns(t)
        if k == "acc":  # specific force at rest: the table's push, up: f_n = [0, 0, −g]
            v = np.einsum("nji,j->ni", R, [0.0, 0.0, -G])
        elif k == "mag":
            v = np.einsum("nji,j->ni", R, FIELD_N)
        else:  # rotation about the phone's own axis at the rate of the tilt
            v = np.zeros((len(t), 3))
            v[:, "xyz".index(axis)] = rate(t)
        out[k] = (t, v)
    return out, R_ns


def expected_euler(R_ns):
    """[roll, pitch, yaw] (deg) of the body frame FRD: R_nb = R_ns R_sb, from scipy's ZYX angles."""
    yaw, pitch, roll = Rotation.from_matrix(R_ns @ R_SB_FLAT).as_euler("ZYX", degrees=True)[0]
    return np.array([roll, pitch, yaw])


@pytest.mark.parametrize("axis, angle, which", [("x", 30.0, "pitch"), ("y", 25.0, "roll"), ("x", -20.0, "pitch")])
def test_flat_then_tilted_gives_the_known_tilt_and_heading(tmp_path, axis, angle, which):
    samples, R_ns = tilt_samples(axis, angle)
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "export", samples), require=("acc", "gyr", "mag"))
    acc, gyr, mag = rec.body("acc"), rec.body("gyr"), rec.body("mag")
    roll, pitch = frames.accel_tilt(acc)
    for window, t_probe in (((0.2, 1.8), 1.0), ((3.2, 4.8), 4.0)):
        rest = (rec.t > window[0]) & (rec.t < window[1])
        want = expected_euler(R_ns(t_probe))
        assert want[{"roll": 1, "pitch": 0}[which]] == pytest.approx(0.0, abs=1e-9)  # tilted about one axis only
        np.testing.assert_allclose(np.degrees([roll[rest].mean(), pitch[rest].mean()]), want[:2], atol=0.01)
        fresh = rest & np.isfinite(mag[:, 0])
        psi = frames.tilt_compensated_heading(mag[fresh], roll[fresh], pitch[fresh], frames.declination(FIELD_N))
        np.testing.assert_allclose(np.degrees(psi), want[2], atol=0.02)
    assert expected_euler(R_ns(4.0))[{"roll": 0, "pitch": 1}[which]] == pytest.approx(angle, abs=1e-9)
    # the gyro, in the body frame, integrates to the tilt about the body axis it is (pitch: y, roll: x)
    turned = np.trapezoid(gyr[:, {"roll": 0, "pitch": 1}[which]], rec.t)
    assert np.degrees(turned) == pytest.approx(angle, abs=0.05)
    # and the accelerometer at rest is g: the specific force, positive up the phone's z when flat
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), G, atol=1e-3)
    np.testing.assert_allclose(rec.sensor_si("acc")[rec.t < 1.8].mean(axis=0), [0.0, 0.0, G], atol=1e-3)


def test_other_mountings_follow_their_matrices(tmp_path):
    """An upright phone (portrait, screen to you) reads +g on y; its mounting makes that level."""
    samples, _ = tilt_samples("x", 0.0)
    upright = {k: (t, v @ Rotation.from_euler("x", 90, degrees=True).as_matrix()) for k, (t, v) in samples.items()}
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "up", upright), mount="upright")
    np.testing.assert_allclose(rec.sensor_si("acc").mean(axis=0), [0.0, G, 0.0], atol=1e-3)
    np.testing.assert_allclose(rec.body("acc").mean(axis=0), [0.0, 0.0, -G], atol=1e-3)
    custom = readers.load_phyphox(tmp_path / "up", mount=PHONE_MOUNTS["upright"])
    assert custom.meta["mount_name"] == "custom" and custom.meta["mount"] == rec.meta["mount"]
    with pytest.raises(ValueError, match="rotation"):
        readers.load_phyphox(tmp_path / "up", mount=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="unknown phone mounting 'sideways'.*flat"):
        readers.load_phyphox(tmp_path / "up", mount="sideways")


# --- formats -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tour_samples():
    from kfkit import attitude_motions

    s = simulate_phone(attitude_motions.attitude_tour(rate_hz=400.0, seed=3), seed=9)
    return {k: (s.t[k][:1500], s.values[k][:1500]) for k in SENSORS}


@pytest.mark.parametrize(
    "sep, decimal, ios",
    [
        (",", ".", False),
        ("\t", ".", False),
        (";", ".", False),
        ("\t", ",", False),
        (";", ",", False),
        (",", ".", True),
        (";", ",", True),
    ],
)
def test_every_csv_variant_loads_the_same(tmp_path, tour_samples, sep, decimal, ios):
    """Unzipped or zipped: iOS omits the last newline, and its complete last row is kept either way (the folder
    used to drop it: 23,305 rows from a real export's folder, 23,306 from its zip)."""
    ref = readers.load_phyphox(write_simple_experiment(tmp_path / "ref", tour_samples))
    folder = write_simple_experiment(tmp_path / "v", tour_samples, sep, decimal, ios)
    for source in (folder, zip_folder(folder, tmp_path / "v.zip")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # nothing dropped, nothing to say
            rec = readers.load_phyphox(source)
        assert len(rec) == len(ref) and rec.meta["phone"]["warnings"] == []
        for c in ref.columns:
            np.testing.assert_array_equal(rec[c], ref[c], err_msg=f"{source.name}: {c}")
    # the counts are the SI values to the fixed-point LSB
    t, v = tour_samples["gyr"]
    kept = np.searchsorted(t, rec.t - 1e-6)  # the file's times carry ten significant digits
    np.testing.assert_allclose(rec.t, t[kept], atol=5e-7)  # µs: the kit's time resolution
    np.testing.assert_allclose(rec.sensor_si("gyr"), v[kept], atol=PHONE_LSB["gyr"] / 2 + 1e-12)


def zip_folder(folder, archive, prefix=""):
    """``folder``'s CSVs (and meta/) zipped as phyphox shares an export, under ``prefix`` inside."""
    with zipfile.ZipFile(archive, "a" if archive.exists() else "w") as z:
        for p in sorted(folder.rglob("*.csv")):
            z.write(p, prefix + p.relative_to(folder).as_posix())
    return archive


def cut_last_row(line: str, how: str) -> str:
    """The last row of an export cut as a copy cut short would leave it."""
    cells = line.split(",")
    return {
        "mid-number": ",".join(cells[:3] + [cells[3][:8]]),  # '-1.234567890E-3' → '-1.23456': parses, 1000× off
        "in the exponent": ",".join(cells[:3] + [cells[3].rsplit("E", 1)[0] + "E"]),
        "a field missing": ",".join(cells[:3]),
        "after a separator": ",".join(cells[:3]) + ",",
        "iOS padding": ",".join(cells[:3] + ['"']),
    }[how]  # '""' cut after its first quote


@pytest.mark.parametrize("ios", [False, True], ids=["android", "ios"])
@pytest.mark.parametrize(
    "how", ["mid-number", "in the exponent", "a field missing", "after a separator", "iOS padding"]
)
def test_a_visibly_cut_last_row_is_dropped_counted_and_warned_about_wherever_it_comes_from(
    tmp_path, tour_samples, how, ios
):
    """The class of `1.000000000E-3` cut to `1.000000`: a last row without newline that is not complete (a field
    missing, a number not in phyphox's full format) is dropped, counted, noted and warned about, from a folder as from
    a zip (a zip used to keep it: its CRC proves the file is what was zipped, not what the phone wrote)."""
    ref = readers.load_phyphox(write_simple_experiment(tmp_path / "ref", tour_samples, ios=ios))
    folder = write_simple_experiment(tmp_path / "cut", tour_samples, ios=ios)
    gyro = folder / "Gyroscope.csv"
    head, last = gyro.read_text(encoding="utf-8").rstrip("\n").rsplit("\n", 1)
    gyro.write_text(head + "\n" + cut_last_row(last, how), encoding="utf-8")
    n = head.count("\n") + 2  # the cut row's line number
    for source in (folder, zip_folder(folder, tmp_path / "cut.zip")):
        with pytest.warns(
            UserWarning, match=f"Gyroscope.csv.*, line {n}: the last line has no newline and is cut short .*: dropped"
        ):
            rec = readers.load_phyphox(source)
        assert rec.meta["phone"]["skipped"]["gyr"]["cut_last_row"] == 1
        (note,) = rec.meta["phone"]["warnings"]
        assert "Gyroscope.csv" in note and f", line {n}: the last line has no newline" in note
        assert len(rec) == len(ref) - 1  # the gyro is the time base: its last row is gone, the rest identical
        for c in ref.columns:
            np.testing.assert_array_equal(rec[c], ref[c][:-1], err_msg=f"{source.name}: {c}")
    assert ref.meta["phone"]["warnings"] == [] and ref.meta["phone"]["skipped"]["gyr"]["cut_last_row"] == 0


def test_zip_folder_and_meta_files_agree(tmp_path, tour_samples):
    folder = write_simple_experiment(tmp_path / "f", tour_samples)
    (folder / "meta").mkdir()
    (folder / "meta" / "device.csv").write_text(
        '"property","value"\n"accelerometer Name","LSM6DSO Accelerometer"\n"accelerometer Range","78.4532"\n',
        encoding="utf-8",
    )
    (folder / "meta" / "time.csv").write_text(
        '"event","experiment time","system time","system time text"\n'
        '"START",0.000000000E0,1700000000.000,"2023-11-14 22:13:20.000 UTC+00:00"\n'
    )
    (folder / "Results.csv").write_text('"Time (s)","Period (s)"\n1.0E0,2.0E0\n')  # another export set: not a sensor
    archive = tmp_path / "phyphox 2024-05-01 10-00-00.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for p in sorted(folder.rglob("*.csv")):
            z.write(p, p.relative_to(folder).as_posix())
    a, b = readers.load_phyphox(folder), readers.load_phyphox(archive)
    for c in a.columns:
        np.testing.assert_array_equal(a[c], b[c])
    assert (
        a.meta["sensors"]["acc"]["chip"] == "LSM6DSO Accelerometer"
        and a.meta["sensors"]["acc"]["full_scale"] == 78.4532
    )
    assert b.meta["phone"]["export"] == archive.name


def test_raw_data_of_a_single_sensor_experiment(tmp_path, tour_samples):
    """'Acceleration with g' exports Raw Data.csv with an Absolute column; alone it gives an accel-only recording."""
    t, v = tour_samples["acc"]
    raw = tmp_path / "Raw Data.csv"
    write_set(
        raw,
        ["Time (s)"] + ANDROID_LABELS["acc"] + ["Absolute acceleration (m/s^2)"],
        [t, v[:, 0], v[:, 1], v[:, 2], np.linalg.norm(v, axis=1)],
    )
    rec = readers.load_phyphox(raw, require=("acc",))
    assert rec.meta["phone"]["time_base"] == "accelerometer" and "gx" not in rec.columns
    np.testing.assert_allclose(rec.t, t, atol=1e-6)  # µs: the kit's time resolution
    np.testing.assert_allclose(rec.sensor_si("acc"), v, atol=PHONE_LSB["acc"] / 2 + 1e-12)


def test_one_time_base_interpolates_the_accelerometer_and_places_each_magnetometer_sample(tmp_path):
    """Linear signals interpolate exactly; each magnetometer sample lands in the first gyro row at or after it."""
    t_g = 0.003 + np.arange(500) * 0.01
    t_a = 0.0 + np.arange(480) * 0.0103
    t_m = 0.011 + np.arange(240) * 0.0201
    acc = np.column_stack([1.0 + 0.5 * t_a, -2.0 * t_a, np.full_like(t_a, G)])
    mag = np.column_stack([20.0 + t_m, np.zeros_like(t_m), 45.0 - t_m])
    samples = {"gyr": (t_g, np.zeros((500, 3))), "acc": (t_a, acc), "mag": (t_m, mag)}
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "e", samples))
    assert rec.t[0] >= t_a[0] and rec.t[-1] <= t_a[-1]  # gyro rows outside the accelerometer's span are left out
    np.testing.assert_allclose(rec.sensor_si("acc")[:, 0], 1.0 + 0.5 * rec.t, atol=1e-4)
    np.testing.assert_allclose(rec.sensor_si("acc")[:, 1], -2.0 * rec.t, atol=1e-4)
    m = rec.sensor_si("mag")
    fresh = np.flatnonzero(np.isfinite(m[:, 0]))
    placed = [int(np.searchsorted(rec.t, tm - 1e-9)) for tm in t_m if rec.t[0] - 0.01 <= tm <= rec.t[-1]]
    assert list(fresh) == placed
    np.testing.assert_allclose(m[fresh, 0] - 20.0, [tm for tm in t_m if rec.t[0] - 0.01 <= tm <= rec.t[-1]], atol=1e-3)
    assert np.isnan(m[~np.isin(np.arange(len(m)), fresh)]).all()


def test_streaming_the_merge_in_pieces_gives_the_file_result(tour_samples):
    whole = OneClock()
    for k, (t, v) in tour_samples.items():
        whole.push(k, t, v)
    t_ref, ref, _ = whole.pop(final=True)
    live = OneClock()
    rng = np.random.default_rng(0)
    cut = np.sort(rng.uniform(tour_samples["gyr"][0][0], tour_samples["gyr"][0][-1], 40))
    pieces, start = [], dict.fromkeys(tour_samples, 0)
    for c in np.append(cut, np.inf):  # a poll: every sensor's samples up to time c
        for k, (t, v) in tour_samples.items():
            stop = int(np.searchsorted(t, c, side="right"))
            live.push(k, t[start[k] : stop], v[start[k] : stop])
            start[k] = stop
        pieces.append(live.pop(final=np.isinf(c)))
    t_live = np.concatenate([p[0] for p in pieces])
    np.testing.assert_array_equal(t_live, t_ref)
    for k in ("gyr", "acc", "mag"):
        np.testing.assert_allclose(np.concatenate([p[1][k] for p in pieces]), ref[k], atol=1e-12, equal_nan=True)
    assert live.stats["mag_late"] == 0


def test_a_late_magnetometer_sample_goes_into_the_next_row():
    """Live, rows wait ``hold_s`` past the magnetometer's last sample; one that comes later still is late."""
    clock = OneClock(hold_s=0.01)
    clock.push("gyr", [0.0, 0.01, 0.02, 0.03], np.zeros((4, 3)))
    clock.push("acc", [0.0, 0.05], np.zeros((2, 3)))
    clock.push("mag", [0.004], [[1.0, 2.0, 3.0]])
    t, out, _ = clock.pop()
    assert list(t) == [0.0, 0.01]  # up to the magnetometer's last time + hold_s
    np.testing.assert_array_equal(out["mag"][1], [1.0, 2.0, 3.0])  # in the first row at or after it
    assert np.isnan(out["mag"][0]).all()
    clock.push("mag", [0.006, 0.015], [[7.0, 8.0, 9.0], [4.0, 5.0, 6.0]])  # 0.006 belonged to a row already out
    t, out, _ = clock.pop(final=True)
    assert list(t) == [0.02, 0.03] and clock.stats["mag_late"] == 1 and clock.stats["mag_merged"] == 1
    np.testing.assert_array_equal(out["mag"][0], [4.0, 5.0, 6.0])  # the newer of the two in that row
    assert np.isnan(out["mag"][1]).all()


def test_saves_and_loads_in_the_kit_format(tmp_path, tour_samples):
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "e", tour_samples), require=("acc", "gyr", "mag"))
    again = io.load_recording(io.save_recording(rec, tmp_path / "phone.csv"))
    assert again.meta == rec.meta
    for c in rec.columns:
        np.testing.assert_array_equal(again[c], rec[c])
    np.testing.assert_array_equal(again.body("mag"), rec.body("mag"))


def test_repeated_timestamps_and_gaps_are_counted_not_fatal(tmp_path, tour_samples):
    t, v = tour_samples["gyr"]
    t = t.copy()
    t[100] = t[99]  # the phone stamped two events alike
    t, v = np.delete(t, range(200, 205)), np.delete(v, range(200, 205), axis=0)  # five samples lost
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "e", {**tour_samples, "gyr": (t, v)}))
    assert rec.meta["phone"]["skipped"]["gyr"]["repeated_times"] == 1
    assert np.diff(rec["seq"]).max() == 6  # the gap shows as dropped samples in seq


def test_a_400_hz_export_with_timestamp_jitter_shows_no_false_gaps_and_every_real_one(tmp_path):
    """At 400 Hz a phone's 0.3 ms jitter is 12 % of a period: rounding each interval to periods would call
    ~0.3 % of them gaps (checked on this very export), the smoothed grid none; five lost samples are five."""
    from kfkit import motions

    s = simulate_phone(motions.stationary(20.0, 1000.0), seed=4, rates={"gyr": 400.0, "acc": 400.0, "mag": 100.0})
    samples = {k: (s.t[k], s.values[k]) for k in SENSORS}
    rec = readers.load_phyphox(write_simple_experiment(tmp_path / "e", samples))
    assert len(rec) > 7500 and np.array_equal(np.diff(rec["seq"]), np.ones(len(rec) - 1))
    rounded = np.rint(np.diff(rec.t) / np.median(np.diff(rec.t)))
    assert np.sum(rounded != 1) >= 5  # what each interval rounded on its own would have shown
    t, v = samples["gyr"]
    lost = [1000, 3000, 3001, 6000, 6002]
    cut = readers.load_phyphox(
        write_simple_experiment(tmp_path / "cut", {**samples, "gyr": (np.delete(t, lost), np.delete(v, lost, axis=0))})
    )
    steps = np.diff(cut["seq"])
    assert int(np.sum(steps - 1)) == len(lost) and sorted(steps[steps > 1].tolist()) == [2, 2, 2, 3]


def test_the_sample_counter_counts_the_same_in_pieces_and_rejects_a_bad_period():
    rng = np.random.default_rng(5)
    t = np.delete(np.arange(3000) / 400.0, [500, 1500, 1501]) + rng.normal(0.0, 3e-4, 2997)
    whole = SampleCounter(1 / 400.0).count(t)
    counter = SampleCounter(1 / 400.0)
    pieces = np.concatenate([counter.count(part) for part in np.split(t, [7, 100, 1234, 2900])])
    np.testing.assert_array_equal(pieces, whole)
    assert whole[-1] == 2999 and np.diff(whole).max() == 3
    with pytest.raises(ValueError, match="positive period"):
        SampleCounter(0.0)


# --- errors -------------------------------------------------------------------------------------------


def test_a_missing_sensor_names_the_experiment_to_use(tmp_path, tour_samples):
    folder = write_simple_experiment(tmp_path / "e", tour_samples, sensors=("acc", "mag"))
    with pytest.raises(
        RecordingError, match="no gyroscope.*found: accelerometer \\(Accelerometer.csv\\).*simple experiment"
    ) as e:
        readers.load_phyphox(folder)
    assert str(folder) in str(e.value)
    with pytest.raises(RecordingError, match="no magnetometer"):
        readers.load_phyphox(
            write_simple_experiment(tmp_path / "f", tour_samples, sensors=("acc", "gyr")), require=("acc", "gyr", "mag")
        )


@pytest.mark.parametrize(
    "name, labels",
    [
        (
            "Linear Acceleration.csv",
            ["Linear Acceleration x (m/s^2)", "Linear Acceleration y (m/s^2)", "Linear Acceleration z (m/s^2)"],
        ),
        (
            "Raw Data.csv",
            ["Linear Acceleration x (m/s^2)", "Linear Acceleration y (m/s^2)", "Linear Acceleration z (m/s^2)"],
        ),
        ("Linear Accelerometer.csv", ["X (m/s^2)", "Y (m/s^2)", "Z (m/s^2)"]),  # iOS simple experiment
    ],
)
def test_linear_acceleration_instead_of_the_accelerometer_says_acceleration_with_g(
    tmp_path, tour_samples, name, labels
):
    folder = write_simple_experiment(tmp_path / "e", tour_samples, sensors=("gyr",))
    t, v = tour_samples["acc"]
    write_set(folder / name, ["Time (s)"] + labels, [t, v[:, 0], v[:, 1], v[:, 2] - G])
    with pytest.raises(RecordingError, match="linear acceleration \\(gravity removed\\).*'Acceleration with g'"):
        readers.load_phyphox(folder)


def test_an_export_without_time_column_names_file_and_columns(tmp_path, tour_samples):
    t, v = tour_samples["acc"]
    raw = tmp_path / "Raw Data.csv"
    write_set(raw, ANDROID_LABELS["acc"], [v[:, 0], v[:, 1], v[:, 2]])
    with pytest.raises(RecordingError, match="Raw Data.csv, line 1: no time column.*'Acceleration x \\(m/s\\^2\\)'"):
        readers.load_phyphox(raw, require=("acc",))


@pytest.mark.parametrize("bad, message", [("9.8.1E0", "'9.8.1E0' is not a number"), ("nine", "'nine' is not a number")])
def test_a_malformed_number_names_file_line_and_column(tmp_path, tour_samples, bad, message):
    folder = write_simple_experiment(tmp_path / "e", tour_samples)
    path = folder / "Gyroscope.csv"
    lines = path.read_text(encoding="utf-8").split("\n")
    cells = lines[41].split(",")
    cells[2] = bad
    lines[41] = ",".join(cells)
    path.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(RecordingError, match=f"Gyroscope.csv, line 42: column 'Gyroscope y \\(rad/s\\)': {message}"):
        readers.load_phyphox(folder)


def test_a_short_row_time_going_back_and_an_empty_file(tmp_path, tour_samples):
    folder = write_simple_experiment(tmp_path / "e", tour_samples)
    path = folder / "Accelerometer.csv"
    lines = path.read_text(encoding="utf-8").split("\n")
    good = list(lines)
    lines[10] = lines[10].rsplit(",", 1)[0]
    path.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(RecordingError, match="Accelerometer.csv, line 11: expected 4 fields separated by ',', got 3"):
        readers.load_phyphox(folder)
    lines = list(good)
    lines[20], lines[21] = lines[21], lines[20]
    path.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(RecordingError, match="Accelerometer.csv, line 22: time goes back"):
        readers.load_phyphox(folder)
    path.write_text("", encoding="utf-8")
    with pytest.raises(RecordingError, match="Accelerometer.csv, line 1: the file is empty"):
        readers.load_phyphox(folder)
    with pytest.raises(FileNotFoundError, match="no phyphox export at"):
        readers.load_phyphox(tmp_path / "nowhere")


# --- the bundled phone recording -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bundled_phone():
    return datasets.load("04_phone_attitude_tour")


def test_bundled_phone_export_is_phyphox_shaped(bundled_phone):
    folder = datasets.data_dir() / "04_phone_attitude_tour"
    header = (folder / "Gyroscope.csv").read_text(encoding="utf-8").split("\n", 2)
    assert header[0] == '"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)"'
    t, *xyz = header[1].split(",")
    assert all(phone_sim.format_number(float(c)) == c == java_sci(float(c)) for c in [t, *xyz])
    assert (folder / "meta" / "device.csv").exists() and (folder / "meta" / "time.csv").exists()
    rec = bundled_phone
    assert rec.meta["board"] == "phone-phyphox" and rec.meta["source"] == "simulated phone (phyphox export)"
    assert 60 * 99 < len(rec) < 60 * 101 and rec.rate_hz == pytest.approx(100.2, abs=0.1)
    assert {p["label"] for p in rec.phases} >= {"stationary", "roll", "pitch", "yaw", "tumble"}


def test_bundled_truth_follows_the_mounting(bundled_phone):
    """The truth is stored for the phone's own frame, so another mounting gives that frame's body attitude."""
    other = phyphox_export.load_phyphox(datasets.data_dir() / "04_phone_attitude_tour", mount="flat_landscape")
    R_flat = Rotation.from_euler("ZYX", bundled_phone.truth()[:, ::-1])
    R_land = Rotation.from_euler("ZYX", other.truth()[:, ::-1])
    M_flat, M_land = (np.array(PHONE_MOUNTS[m]) for m in ("flat", "flat_landscape"))
    # R_ns = R_nb M_bs for both: the phone's attitude is one and the same
    np.testing.assert_allclose(
        (R_flat * Rotation.from_matrix(M_flat)).as_matrix(),
        (R_land * Rotation.from_matrix(M_land)).as_matrix(),
        atol=1e-7,
    )
    # and at rest the body-frame specific force points along the true "up" of each
    rest = bundled_phone.phase("stationary")
    for rec, R in ((bundled_phone, R_flat), (other, R_land)):
        np.testing.assert_allclose(
            rec.body("acc")[rest].mean(axis=0), R[rest].inv().apply([0, 0, -G]).mean(axis=0), atol=0.06
        )


@pytest.mark.parametrize("method", ["euler-ekf", "mekf"])
def test_lab04_ekf_meets_its_budget_on_the_bundled_phone_recording(bundled_phone, method):
    """Lab 04's budget: roll and pitch RMSE < 1°, yaw < 2° against the truth (phone: the OS has calibrated
    its gyro and magnetometer, so the lab uses the body-frame signals as they are)."""
    rec = bundled_phone
    result = estimate_attitude(
        rec.body("gyr"), rec.body("acc"), rec.body("mag"), rec.rate_hz, method=method, field_n=FIELD_N
    )
    rmse = np.degrees(metrics.rmse(metrics.angle_error(result.euler, rec.truth()), 0.0))
    assert rmse[0] < 1.0 and rmse[1] < 1.0 and rmse[2] < 2.0, rmse


# --- a phone recording in the labs: one loader for every source, recordings without truth -----------------------


def test_load_any_reads_the_kits_format_and_every_phyphox_export_shape(tmp_path, tour_samples):
    folder = write_simple_experiment(tmp_path / "export", tour_samples)
    from_folder = readers.load_any(folder)
    assert from_folder.meta["source"] == "phone (phyphox export)"
    archive = tmp_path / "export.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for p in sorted(folder.glob("*.csv")):
            z.write(p, p.name)
    t, v = tour_samples["acc"]
    write_set(tmp_path / "Raw Data.csv", ["Time (s)"] + ANDROID_LABELS["acc"], [t, v[:, 0], v[:, 1], v[:, 2]])
    kit_file = io.save_recording(from_folder, tmp_path / "capture.csv")  # what a live phone capture writes
    for path in (archive, kit_file):
        rec = readers.load_any(path)
        for c in from_folder.columns:
            np.testing.assert_array_equal(rec[c], from_folder[c], err_msg=f"{path.name}: {c}")
    assert readers.load_any(tmp_path / "Raw Data.csv", require=("acc",)).meta["phone"]["time_base"] == "accelerometer"
    upright = readers.load_any(folder, mount="upright")
    assert upright.meta["mount_name"] == "upright" and upright.meta["mount"]["acc"] == [
        list(r) for r in PHONE_MOUNTS["upright"]
    ]
    with pytest.raises(FileNotFoundError, match="no recording or phyphox export at .*nowhere"):
        readers.load_any(tmp_path / "nowhere")
    (tmp_path / "notes.csv").write_text("a,b\n1,2\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="notes.csv, line 1: no time column"):
        readers.load_any(tmp_path / "notes.csv")
    with pytest.raises(RecordingError, match="no magnetometer"):
        readers.load_any(
            write_simple_experiment(tmp_path / "no_mag", tour_samples, sensors=("acc", "gyr")),
            require=("acc", "gyr", "mag"),
        )


def test_consistency_figure_and_tuning_panel_work_without_truth():
    from kfkit import plots, widgets

    rng = np.random.default_rng(0)
    t = np.arange(500) / 100.0
    y, S = rng.normal(0, 0.01, 500), np.full(500, 1e-4)
    assert len(plots.consistency(t, None, S, y, S).axes) == 2  # innovations and NIS: they need no truth
    assert len(plots.consistency(t, y, S, y, S).axes) == 3
    panel = widgets.tune(lambda q: np.full(500, q), t, None, {"q": (1e-3, 1e-6, 1.0)})
    assert np.isnan(panel.rmse) and "no truth" in panel.status.value
    assert np.isnan(panel.set(q=1e-2)) and panel.line.get_ydata()[0] == pytest.approx(np.degrees(1e-2))
    with_truth = widgets.tune(lambda q: np.full(500, q), t, np.zeros(500), {"q": (1e-3, 1e-6, 1.0)})
    assert with_truth.rmse == pytest.approx(1e-3) and "RMSE" in with_truth.status.value


@pytest.mark.slow
def test_lab01_runs_top_to_bottom_on_a_phone_export_without_truth(tmp_path):
    """A student's own phyphox export of lab 01's experiment (rest, then rolls by hand): no truth, no labels."""
    from test_calibration_labs import run_solution_on

    from kfkit import motions

    motion = motions.sine_roll(
        duration=40.0, rate_hz=400.0, amplitude=np.radians(30.0), freq_hz=0.1, still=5.0, vibration_rms=0.3, seed=21
    )
    files = phone_sim.simple_experiment_files(simulate_phone(motion, seed=22))
    files.pop(phone_sim.TRUTH_FILE)
    export = phone_sim.write_export(files, tmp_path / "phyphox roll")
    errors, text = run_solution_on("01_roll_kf_1d.ipynb", {"RECORDING": str(export)})
    assert errors == [] and "Warning" not in text
    assert "board phone-phyphox" in text and "no truth in this recording" in text and "RMSE accel only :" not in text
    assert "q = " in text and "from the sliders" in text  # the tuned q falls back to the sliders' value


# --- damaged or doubled exports, garbled truth, fuzz ------------------------------------------------------


@pytest.fixture(scope="module")
def small_export(tmp_path_factory):
    """A short simulated simple-experiment export with its truth file, as a folder and as a zip."""
    from kfkit import motions

    samples = simulate_phone(motions.stationary(duration=1.0, rate_hz=100.0), seed=5)
    folder = phone_sim.write_export(
        phone_sim.simple_experiment_files(samples), tmp_path_factory.mktemp("small") / "export"
    )
    return folder, zip_folder(folder, folder.parent / "export.zip"), readers.load_phyphox(folder)


def test_a_cut_or_damaged_zip_is_called_a_damaged_zip(tmp_path, small_export):
    _, archive, _ = small_export
    data = archive.read_bytes()
    for name, content in (("cut.zip", data[: len(data) // 2]), ("cut-no-suffix", data[: len(data) - 30])):
        path = tmp_path / name
        path.write_bytes(content)  # was reported as "a CSV without a time column"
        with pytest.raises(RecordingError, match=re.escape(str(path)) + ": a damaged .zip file.*again"):
            readers.load_phyphox(path)
        with pytest.raises(RecordingError, match="damaged .zip"):
            readers.load_any(path)
    crc = tmp_path / "crc.zip"  # a flipped byte inside a stored member: the CRC-32 tells
    with zipfile.ZipFile(crc, "w", zipfile.ZIP_STORED) as z:
        z.write(small_export[0] / "Gyroscope.csv", "Gyroscope.csv")
    raw = bytearray(crc.read_bytes())
    k = raw.index(b"E-") + 1
    raw[k] = ord("+")
    crc.write_bytes(bytes(raw))
    with pytest.raises(RecordingError, match=re.escape(str(crc)) + ": a damaged .zip file .*CRC"):
        readers.load_phyphox(crc, require=("gyr",))


def test_a_zip_with_two_exports_is_an_error_and_macos_copies_are_skipped(tmp_path, small_export):
    folder, _, ref = small_export
    two = zip_folder(folder, zip_folder(folder, tmp_path / "two.zip", "first/"), "second/")
    with pytest.raises(RecordingError, match=r"two exports in one zip \(first/.*second/.*load each"):
        readers.load_phyphox(two)
    mac = zip_folder(folder, tmp_path / "mac.zip", "export/")  # Finder's "Compress" adds __MACOSX/._* copies
    with zipfile.ZipFile(mac, "a") as z:
        z.writestr("__MACOSX/export/._Gyroscope.csv", b"\x00\x05\x16\x07 binary resource fork")
    rec = readers.load_phyphox(mac)
    for c in ref.columns:
        np.testing.assert_array_equal(rec[c], ref[c], err_msg=c)


def test_duplicate_columns_are_named(tmp_path, tour_samples):
    t, v = tour_samples["acc"]
    for labels, message in (
        (["Time (s)", "Time (s)"] + ANDROID_LABELS["acc"], "2 time columns"),
        (["Time (s)"] + ANDROID_LABELS["acc"] + ["Acceleration x (m/s^2)"], "two x columns"),
    ):
        raw = tmp_path / "Raw Data.csv"
        write_set(raw, labels, [t] * (len(labels) - 3) + [v[:, 0], v[:, 1], v[:, 2]])
        with pytest.raises(RecordingError, match=re.escape(str(raw)) + ", line 1: " + message):
            readers.load_phyphox(raw, require=("acc",))


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda lines: [lines[0].replace('"phases"', '"phases" "')] + lines[1:],
            r"line 1: the metadata is not valid JSON",
        ),
        (lambda lines: [lines[0][:40]] + lines[1:], r"line 1: the metadata is not valid JSON"),
        (lambda lines: lines[:5] + [lines[5].replace(",", ";", 1)] + lines[6:], r"line 6: expected 5 fields"),
        (lambda lines: lines[:5] + [lines[5].replace("0.", "O.", 1)] + lines[6:], r"line 6: .* is not a number"),
        (lambda lines: lines[:5] + ["3.5" + lines[5][1:]] + lines[6:], r"line 6: '3.5' is not an integer count"),
        (lambda lines: lines[:5] + [lines[5].replace(",", ",2", 1)] + lines[6:], r"line 6: not a unit quaternion"),
        (lambda lines: lines[:-1] + [lines[-1][:-3]], r"line \d+: the last line is cut short"),
    ],
    ids=["json", "json-cut", "fields", "number", "row-index", "not-unit", "cut"],
)
def test_a_garbled_truth_file_is_named_with_its_line(small_export, tmp_path, edit, message):
    folder = tmp_path / "export"
    shutil.copytree(small_export[0], folder)
    truth = folder / phone_sim.TRUTH_FILE
    lines = truth.read_text(encoding="utf-8").rstrip("\n").split("\n")
    changed = edit(lines)
    truth.write_text("\n".join(changed) + ("" if message.endswith("cut short") else "\n"), encoding="utf-8")
    with pytest.raises(RecordingError, match=re.escape(str(truth)) + ", " + message):
        readers.load_phyphox(folder)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:.*the last line has no newline and is cut short:UserWarning")  # the cuts: dropped
def test_fuzzed_exports_load_the_same_numbers_or_name_the_file(tmp_path, small_export):
    """The gyroscope CSV cut or garbled in a folder, and the zip cut or garbled: the loader's own error naming
    the file, or the reference's first rows exactly (a cut last line is dropped, never read)."""
    from test_io import check_fuzzed

    folder, archive, ref = small_export
    sensors = [c for c in ref.columns if c[0] in "agm" and len(c) == 2] + ["t"]

    def prefix(rec):
        n = len(rec)
        return 0 < n <= len(ref) and all(np.array_equal(rec[c], ref[c][:n], equal_nan=True) for c in sensors)

    copy = tmp_path / "export"
    shutil.copytree(folder, copy)
    gyro = copy / "Gyroscope.csv"
    good = gyro.read_bytes()
    outcome = check_fuzzed(gyro, lambda _: readers.load_phyphox(copy), good, RecordingError, prefix, names=copy)
    assert outcome["loaded"] > 100 and outcome["rejected"] > 10
    outcome = check_fuzzed(tmp_path / "fuzzed.zip", readers.load_phyphox, archive.read_bytes(), RecordingError, prefix)
    assert outcome["rejected"] > 100


# --- values a recording cannot hold: named with file, line and column, no NumPy warning ---------------------------


@pytest.mark.parametrize(
    "column, value, words",
    [
        (
            1,
            "1.000000000E20",
            r"'1.000000000E20' rad/s is beyond what a phone recording holds \(\|value\| ≤ 21,474.8365",
        ),
        (3, "-2.147483648E4", r"'-2.147483648E4' rad/s is beyond what a phone recording holds"),  # one LSB past int32
        (
            2,
            "0." + "0" * 1_000_000 + "1",
            r"'0.0000000000000000000000'… \(1,000,003 characters\) is longer than any number",
        ),
        (1, "9" * 65, r"'999999999999999999999999'… \(65 characters\) is longer than any number"),
        (0, "1.000000000E300", r"'1.000000000E300' s is beyond the time a recording holds"),
        (2, "Infinity", "'Infinity' is not a finite number"),
        (2, "1E999", "'1E999' is not a finite number"),
    ],
    ids=["1e20", "int32+1", "1 MB of digits", "65 digits", "time 1e300", "Infinity", "1e999"],
)
def test_a_value_a_recording_cannot_hold_names_file_line_column_and_value(tmp_path, tour_samples, column, value, words):
    """These used to load as int64 garbage (1e20 rad/s) or 0.0 (a megabyte of digits), with only a NumPy warning."""
    folder = write_simple_experiment(tmp_path / "e", tour_samples)
    path = folder / "Gyroscope.csv"
    lines = path.read_text(encoding="utf-8").split("\n")
    cells = lines[41].split(",")
    cells[column] = value
    lines[41] = ",".join(cells)
    path.write_text("\n".join(lines), encoding="utf-8")
    label = re.escape(["Time (s)", *ANDROID_LABELS["gyr"]][column])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning from a cast on the way
        with pytest.raises(RecordingError, match=f"{re.escape(str(path))}, line 42: column '{label}': {words}"):
            readers.load_phyphox(folder)


def test_the_largest_values_a_phone_recording_holds_load_exactly(tmp_path):
    """±(2³¹ − 1) LSBs, the protocol's int32: the edge of the range loads, as counts exactly."""
    t = 0.01 * np.arange(100)
    edge = (2**31 - 1) * PHONE_LSB["gyr"]
    gyro = np.column_stack([np.full(100, edge), np.full(100, -edge), np.zeros(100)])
    acc = np.column_stack([np.zeros(100), np.zeros(100), np.full(100, -G)])
    write_set(tmp_path / "e" / "Gyroscope.csv", ["Time (s)"] + ANDROID_LABELS["gyr"], [t, *gyro.T])
    write_set(tmp_path / "e" / "Accelerometer.csv", ["Time (s)"] + ANDROID_LABELS["acc"], [t, *acc.T])
    rec = readers.load_phyphox(tmp_path / "e")
    assert rec["gx"].max() == 2**31 - 1 and rec["gy"].min() == -(2**31 - 1)
