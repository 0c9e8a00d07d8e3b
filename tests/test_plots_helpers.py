"""The one-call figure and table helpers the notebooks use: units on every axis, Okabe–Ito colours,
numbers against independent oracles (numpy, scipy), and a recording without truth said, not failed on."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.colors as mcolors
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from kfkit import plots

PALETTE = {mcolors.to_hex(c) for c in plots.COLORS.values()}


@pytest.fixture
def attitude():
    """A yaw that crosses ±180°, roll and pitch swinging; two noisy estimates; a covariance; a magnetometer at half
    rate."""
    rng = np.random.default_rng(5)
    t = np.arange(400) / 50.0
    truth = np.column_stack([0.3 * np.sin(t), 0.2 * np.cos(0.7 * t), np.angle(np.exp(1j * (2.8 + 0.2 * t)))])
    good = truth + rng.normal(0, np.radians(0.5), truth.shape)
    poor = truth + rng.normal(0, np.radians(3.0), truth.shape)
    P = np.tile(np.diag(np.radians([0.5, 0.5, 0.5]) ** 2), (len(t), 1, 1))
    mag = rng.normal(0, 1, (len(t), 3)) + [20.0, 0.0, 45.0]
    mag[1::2] = np.nan
    return t, truth, good, poor, P, mag


def line_colours(fig):
    return {mcolors.to_hex(line.get_color()) for ax in fig.axes for line in ax.get_lines()}


def texts(fig):
    return " ".join(t.get_text() for ax in fig.axes for t in ax.texts)


def test_break_wraps_cuts_the_line_only_where_the_angle_wraps():
    yaw = np.radians([170.0, 175.0, 179.0, -178.0, -170.0, -175.0])
    out = plots.break_wraps(yaw)
    assert np.isnan(out[3]) and np.isnan(out).sum() == 1
    assert np.array_equal(out[[0, 1, 2, 4, 5]], yaw[[0, 1, 2, 4, 5]])
    assert not np.isnan(yaw).any()  # a copy: the input is untouched


def test_imu_signals_have_units_leave_out_empty_magnetometer_rows_and_name_the_phases(attitude):
    t, _, _, _, _, mag = attitude
    gyr = np.column_stack([np.full_like(t, np.radians(10.0)), np.zeros_like(t), np.zeros_like(t)])
    acc = np.tile([0.0, 0.0, -9.80665], (len(t), 1))
    phases = [
        {"label": "stationary", "start": 0.0, "end": 1.0},
        {"label": "linear_acceleration", "start": 2.0, "end": 3.0},
    ]
    fig = plots.imu_signals(t, gyr, acc, mag, shade=[(2.0, 3.0)], shade_label="slide", phases=phases)
    assert [ax.get_ylabel() for ax in fig.axes] == ["gyro (°/s)", "accel (m/s²)", "mag (µT)"]
    assert fig.axes[-1].get_xlabel() == "time (s)"
    assert fig.axes[0].get_lines()[0].get_ydata() == pytest.approx(10.0)  # rad/s shown in °/s
    assert len(fig.axes[2].get_lines()[0].get_xdata()) == np.sum(~np.isnan(mag[:, 0]))
    assert "linear acceleration" in texts(fig) and "stationary" not in texts(fig)
    assert line_colours(fig) <= PALETTE
    assert len(plots.imu_signals(t, gyr, acc).axes) == 2  # a board without magnetometer


def test_compare_euler_shows_degrees_without_wrap_jumps_and_one_legend(attitude):
    t, truth, good, poor, _, _ = attitude
    fig = plots.compare_euler(t, truth, {"accel/mag": (poor, "accel"), "EKF": (good, "kf")}, shade=[(1.0, 2.0)])
    assert [ax.get_ylabel() for ax in fig.axes] == ["roll (°)", "pitch (°)", "yaw (°)"]
    assert [ax.get_legend() is not None for ax in fig.axes] == [True, False, False]
    yaw_truth = fig.axes[2].get_lines()[0].get_ydata()
    assert np.nanmax(np.abs(np.diff(yaw_truth))) < 180.0 and np.isnan(yaw_truth).any()  # the wrap is a gap
    assert line_colours(fig) <= PALETTE
    no_truth = plots.compare_euler(t, None, {"EKF": (good, "kf")})
    assert all(len(ax.get_lines()) == 1 for ax in no_truth.axes)


def test_tilt_panels_show_roll_and_pitch_in_degrees_with_the_protocol_holds(attitude):
    t, truth, good, _, _, _ = attitude
    known = np.where(t < 2.0, truth[:, :2].T, np.nan)  # a "hold": the angle known only there
    fig = plots.tilt_panels(t, truth, {"KF": ((good[:, 0], good[:, 1]), "kf")}, known=known, shade=[(1.0, 2.0)])
    assert [ax.get_ylabel() for ax in fig.axes] == ["roll (°)", "pitch (°)"]
    for i, ax in enumerate(fig.axes):
        truth_line, kf_line, hold_line = ax.get_lines()
        np.testing.assert_allclose(truth_line.get_ydata(), truth[:, i] * 180 / np.pi)
        np.testing.assert_allclose(kf_line.get_ydata(), good[:, i] * 180 / np.pi)
        assert np.isnan(hold_line.get_ydata()).sum() == np.sum(t >= 2.0)
    assert len(fig.axes[0].patches) == 1 and not fig.axes[1].patches  # shaded on roll only
    assert [x.get_text() for x in fig.legends[0].get_texts()] == ["truth", "KF", "protocol (holds)"]
    assert all(ax.get_legend() is None for ax in fig.axes)  # one legend for both panels
    assert line_colours(fig) <= PALETTE
    no_truth = plots.tilt_panels(t, None, {"KF": ((good[:, 0], good[:, 1]), "kf")})
    assert all(len(ax.get_lines()) == 1 for ax in no_truth.axes)


def test_euler_errors_band_from_P_and_a_recording_without_truth_is_said(attitude):
    t, truth, good, _, P, _ = attitude
    fig = plots.euler_errors(t, good, truth, P, label="EKF")
    assert [ax.get_ylabel() for ax in fig.axes] == ["roll error (°)", "pitch error (°)", "yaw error (°)"]
    # σ = 0.5° is the noise's own: about 95 % inside ±2σ (binomial, 400 samples: 90…99 %)
    inside = [int(ax.get_legend().get_title().get_text().split()[0]) for ax in fig.axes]
    assert all(90 <= v <= 99 for v in inside), inside
    fig = plots.euler_errors(t, good, None, P, label="EKF")
    assert plots.NO_TRUTH in texts(fig) and "EKF" in texts(fig)


def test_consistency_panels_and_nees_without_truth(attitude):
    t = attitude[0]
    rng = np.random.default_rng(1)
    nees, nis6 = rng.chisquare(3, t.size), rng.chisquare(6, t.size)
    nis6[::2] = np.nan
    fig = plots.consistency_panels(t, nees, {"6 rows": (nis6, 6)})
    assert [ax.get_ylabel() for ax in fig.axes] == ["NEES (–)", "NIS, 6 rows (–)"]
    bound = [line.get_ydata()[0] for line in fig.axes[0].get_lines() if line.get_linestyle() == ":"]
    assert bound == [pytest.approx(chi2.ppf(0.975, 3))]
    fig = plots.consistency_panels(t, None, {"6 rows": (nis6, 6)})
    assert plots.NO_TRUTH in texts(fig)


def test_rmse_table_against_numpy_and_scipy(attitude):
    _, truth, good, poor, _, _ = attitude
    lines = []
    table = plots.rmse_table({"EKF": good, "accel/mag only": poor}, truth, rotation=True, out=lines.append)
    wrapped = np.angle(np.exp(1j * (poor - truth)))  # yaw errors across ±180° wrapped, not 360°
    assert table["accel/mag only"] == pytest.approx(np.degrees(np.sqrt(np.mean(wrapped**2, axis=0))), rel=1e-9)
    rel = Rotation.from_euler("ZYX", good[:, ::-1]) * Rotation.from_euler("ZYX", truth[:, ::-1]).inv()
    rotation = np.degrees(np.sqrt(np.mean(rel.magnitude() ** 2)))
    assert lines[0].split() == ["RMSE", "(°)", "roll", "pitch", "yaw", "rotation"]
    assert lines[1].startswith("EKF ") and float(lines[1].split()[-1]) == pytest.approx(rotation, abs=0.006)
    assert [float(v) for v in lines[2].split()[-4:-1]] == pytest.approx(table["accel/mag only"], abs=0.006)
    lines.clear()
    plots.rmse_table(
        {"EKF": good}, truth, rotation=True, title="04_attitude_tour", note="   RMSE (°)", out=lines.append
    )
    assert lines[0] == f"{'04_attitude_tour':26s} {'roll':>6s} {'pitch':>6s} {'yaw':>6s} {'rotation':>9s}   RMSE (°)"
    lines.clear()
    assert plots.rmse_table({"EKF": good}, None, hint="compare by eye", out=lines.append) is None
    assert lines == [f"{plots.NO_TRUTH}: no RMSE; compare by eye"]


def test_rmse_table_of_one_angle():
    truth = np.linspace(0, 1, 50)
    lines = []
    table = plots.rmse_table({"KF": truth + 0.01}, truth, columns=("roll",), out=lines.append)
    assert table["KF"] == pytest.approx([np.degrees(0.01)]) and len(lines) == 2


def test_consistency_table_against_scipy():
    rng = np.random.default_rng(2)
    nees, nis3 = rng.chisquare(3, 500), rng.chisquare(3, 500)
    nis3[:100] = np.nan
    lines = []
    plots.consistency_table(nees, {"3 rows": (nis3, 3)}, out=lines.append)
    assert f"mean {nees.mean():6.2f}" in lines[0]
    n = 400
    lo, hi = chi2.ppf(0.025, 3 * n) / n, chi2.ppf(0.975, 3 * n) / n  # bounds of a mean of n χ²(3) values
    assert lines[1].startswith("NIS (3 rows)") and f"{lo:.2f} … {hi:.2f}" in lines[1]
    inside = np.mean((nis3[100:] >= chi2.ppf(0.025, 3)) & (nis3[100:] <= chi2.ppf(0.975, 3)))
    assert f"{100 * inside:3.0f} % of samples" in lines[1]
    lines.clear()
    plots.consistency_table(None, {}, out=lines.append)
    assert lines == ["NEES          needs the truth: none in this recording"]


def test_sweep_is_log_log_with_units_and_marks():
    values = np.logspace(-2, 1, 7)
    fig = plots.sweep(values, {"roll": values**0.5, "pitch": values}, xlabel="σ_a (m/s²)", marks={"datasheet": 0.006})
    ax = fig.axes[0]
    assert (ax.get_xscale(), ax.get_yscale()) == ("log", "log")
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("σ_a (m/s²)", "RMSE (°)")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["roll", "pitch", "datasheet"]
    assert line_colours(fig) <= PALETTE


def test_sweep_draws_each_reference_as_a_level_line_in_its_sensors_colour():
    values = np.logspace(-12, -2, 11)
    fig = plots.sweep(
        values,
        {"KF": 1.0 + np.abs(np.log10(values) + 7)},
        "q (rad²)",
        marks={"best q": 1e-7},
        references={"accel only": (4.2, "accel"), "gyro only": (9.1, "gyro")},
    )
    ax = fig.axes[0]
    levels = {line.get_label(): line for line in ax.get_lines()}
    for label, y, kind in (("accel only", 4.2, "accel"), ("gyro only", 9.1, "gyro")):
        assert np.all(np.asarray(levels[label].get_ydata()) == y) and list(levels[label].get_xdata()) == [
            0,
            1,
        ]  # axhline
        assert mcolors.to_hex(levels[label].get_color()) == plots.COLORS[kind].lower()
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["KF", "best q", "accel only", "gyro only"]
    assert plots.sweep(values, {"KF": values}, "q (rad²)").axes[0].get_lines()[-1].get_label() == "KF"  # none asked


def test_windows_of_and_label_phases_take_both_phase_forms():
    phases = [{"label": "hold", "start": 1.0, "end": 2.0}, (3.0, 4.0, "hold"), (5.0, 6.0, "turn")]
    assert plots.windows_of(phases, "hold") == [(1.0, 2.0), (3.0, 4.0)]
    fig = plots.imu_signals(np.arange(10.0), np.zeros((10, 3)), np.zeros((10, 3)), phases=phases)
    assert texts(fig).split() == ["hold", "hold", "turn"]


def board_recording(sensors=("acc", "gyr", "mag"), phases=()):
    """A 10 s, 10 Hz recording in counts; the phone's 'flat' mount (body x = sensor y, y = x, z = −z)."""
    from kfkit.io import SENSOR_COLUMNS, Recording

    t = np.arange(100) / 10.0
    data = {"t": t}
    for k, sensor in enumerate(sensors):
        for i, col in enumerate(SENSOR_COLUMNS[sensor]):
            data[col] = np.full(len(t), 100.0 * (k + 1) + i)
    meta = {
        "rate_hz": 10.0,
        "phases": list(phases),
        "sensors": {s: {"sensitivity": 0.01} for s in sensors},
        "mount": {s: [[0, 1, 0], [1, 0, 0], [0, 0, -1]] for s in sensors},
    }
    return Recording(meta, data)


def test_recording_signal_is_the_body_frame_in_units_with_runs_of_one_label_named_once():
    runs = [("a", 0.0, 1.0), ("b", 2.0, 3.0), ("b", 4.0, 5.0), ("c", 6.0, 7.0)]
    rec = board_recording(phases=[{"label": l, "start": s, "end": e} for l, s, e in runs])
    fig, ax = plt_subplots()
    plots.recording_signal(ax, rec, "gyr", title="board: turns")
    counts = np.array([200.0, 201.0, 202.0])  # gyro, sensor frame; body = M_bs · counts · 0.01 rad/s
    expected = np.degrees(np.array([counts[1], counts[0], -counts[2]]) * 0.01)
    assert [line.get_ydata()[0] for line in ax.get_lines()] == pytest.approx(expected)
    assert (ax.get_ylabel(), ax.get_xlabel(), ax.get_title()) == ("angular rate (°/s)", "time (s)", "board: turns")
    assert [t.get_text() for t in ax.texts] == ["a", "b", "c"]  # the two "b" windows: one name
    assert [t.get_position()[0] for t in ax.texts] == pytest.approx([0.5, 3.5, 6.5])
    assert len(ax.patches) == 4 and line_colours(fig) <= PALETTE
    fig, ax = plt_subplots()
    plots.recording_signal(ax, board_recording(phases=[{"label": "stationary", "start": 0.0, "end": 9.0}]), "acc")
    assert len(ax.texts) == 0 and len(ax.patches) == 1 and ax.get_ylabel() == "specific force (m/s²)"


def test_recording_grid_hides_unused_panels_and_shares_one_axis_legend():
    panels = {f"r{i}": (board_recording(), sensor) for i, sensor in enumerate(["acc", "gyr", "mag"])}
    fig = plots.recording_grid(panels, title="guided")
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in visible] == ["r0", "r1", "r2"] and len(fig.axes) == 4
    assert [ax.get_ylabel() for ax in visible] == ["specific force (m/s²)", "angular rate (°/s)", "magnetic field (µT)"]
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["x (body)", "y (body)", "z (body)"]
    assert fig.get_suptitle() == "guided"


def test_recording_signals_show_only_the_sensors_a_recording_has():
    assert len(plots.recording_signals(board_recording()).axes) == 3
    fig = plots.recording_signals(board_recording(("acc", "gyr"), [{"label": "tilt", "start": 1.0, "end": 2.0}]))
    assert [ax.get_ylabel() for ax in fig.axes] == ["gyro (°/s)", "accel (m/s²)"]  # an MPU6050: no magnetometer
    assert texts(fig) == "tilt"


def plt_subplots():
    import matplotlib.pyplot as plt

    return plt.subplots()


def test_allan_draws_the_curves_scaled_and_the_white_noise_line_meets_allantools():
    """White noise of density N (σ = N√f_s per sample): the helper's N/√τ line against allantools' overlapping
    Allan deviation of the same samples, within its sampling error; the K√(τ/3) line is left out without K."""
    allantools = pytest.importorskip("allantools")
    import matplotlib.pyplot as plt

    rate, N = 50.0, 0.002
    x = np.random.default_rng(3).normal(0.0, N * np.sqrt(rate), (20000, 3))
    taus = np.array([0.02, 0.1, 1.0, 5.0, 20.0])
    adev = np.column_stack([allantools.oadev(x[:, i], rate=rate, data_type="freq", taus=taus)[1] for i in range(3)])
    fig, ax = plt.subplots()
    plots.allan(
        ax,
        taus,
        adev,
        "°/s",
        scale=np.degrees(1.0),
        white=("datasheet", N),
        walk=("bias walk", None),
        arw=N,
        minimum=(taus[[-1, -1, -1]], adev[-1]),
        title="gyro",
    )
    curves, _, _, white, arw, _ = ax.get_lines()  # x, y, z, N/√τ, ARW, minimum: no walk line, K is None
    assert (ax.get_xscale(), ax.get_yscale(), ax.get_ylabel()) == ("log", "log", "Allan deviation (°/s)")
    assert curves.get_ydata() == pytest.approx(np.degrees(adev[:, 0]))
    assert white.get_label() == "datasheet N/√τ (slope −½)"
    # a 1-sample-τ estimate from 20 000 samples is good to ~1 %; the longest τ (400 clusters) to ~10 %
    assert np.degrees(adev[:3]) == pytest.approx(np.tile(white.get_ydata()[:3, None], 3), rel=0.05)
    assert np.degrees(adev[3:]) == pytest.approx(np.tile(white.get_ydata()[3:, None], 3), rel=0.3)
    assert arw.get_ydata()[0] == pytest.approx(np.degrees(N)) and arw.get_xdata()[0] == 1.0
    lo, hi = ax.get_ylim()
    assert lo < np.degrees(adev).min() and hi > np.degrees(adev).max()
    assert line_colours(fig) <= PALETTE
    plots.allan(ax, taus, adev, "°/s", walk=("bias walk", 1e-4))
    walk = ax.get_lines()[-1]
    assert walk.get_ydata()[taus == 1.0][0] == pytest.approx(1e-4 * np.sqrt(1 / 3))  # K√(τ/3)


def test_compare_values_shows_its_own_unit_and_compare_angles_stays_in_degrees(attitude):
    t, truth, good, _, _, _ = attitude
    fig = plots.compare_values(t, truth[:, 0], {"KF": (good[:, 0], "kf"), "raw": good[:, 1]}, ylabel="v_y", unit="m/s")
    ax = fig.axes[0]
    assert [line.get_ydata() for line in ax.get_lines()] == [
        pytest.approx(v) for v in (truth[:, 0], good[:, 0], good[:, 1])
    ]
    assert (ax.get_ylabel(), ax.get_xlabel()) == ("v_y (m/s)", "time (s)") and line_colours(fig) <= PALETTE
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["truth", "KF", "raw"]
    ax = plots.compare_angles(t, truth[:, 0], {"KF": (good[:, 0], "kf")}, ylabel="sideslip β").axes[0]
    assert (
        ax.get_lines()[0].get_ydata() == pytest.approx(truth[:, 0] * 180.0 / np.pi)
        and ax.get_ylabel() == "sideslip β (°)"
    )
    assert len(plots.compare_values(t, None, {"KF": good[:, 0]}).axes[0].get_lines()) == 1  # no truth: estimates only


def test_compare_angles_shades_its_windows_and_names_them_once_in_the_legend(attitude):
    t, truth, good, _, _, _ = attitude
    ax = plots.compare_angles(
        t, truth[:, 0], {"KF": (good[:, 0], "kf")}, shade=[(1.0, 2.0), (5.0, 6.0)], shade_label="sideways shake"
    ).axes[0]
    spans = [p.get_x() for p in ax.patches], [p.get_x() + p.get_width() for p in ax.patches]
    assert spans == ([1.0, 5.0], [2.0, 6.0])
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["truth", "KF", "sideways shake"]
    assert not plots.compare_angles(t, truth[:, 0], {"KF": good[:, 0]}).axes[0].patches  # none asked, none drawn


@pytest.mark.parametrize("mask", ["0011100110", "1100000011", "1111111111", "0000000000", "0100000000", "0000000001"])
def test_windows_where_are_the_runs_of_true_samples(mask):
    from scipy import ndimage

    t = 0.5 + np.arange(len(mask)) / 4.0
    flags = np.array([c == "1" for c in mask])
    labels, n = ndimage.label(flags)  # independent oracle: connected runs
    expected = [(t[labels == k].min(), t[labels == k].max()) for k in range(1, n + 1)]
    assert plots.windows_where(t, flags) == expected


def test_vehicle_signals_are_four_panels_in_degrees_and_km_per_hour():
    from kfkit.io import Recording

    t = np.arange(50) / 10.0
    columns = {
        "delta": np.full(50, np.pi / 36),
        "yaw_rate": np.full(50, np.pi / 18),
        "ay": np.full(50, 2.5),
        "vx": np.full(50, 10.0),
    }
    fig = plots.vehicle_signals(Recording({"rate_hz": 10.0}, {"t": t, **columns}), title="drive")
    assert [ax.get_ylabel() for ax in fig.axes] == ["δ (°)", "r (°/s)", "a_y (m/s²)", "V_x (km/h)"]
    assert [ax.get_lines()[0].get_ydata()[0] for ax in fig.axes] == pytest.approx([5.0, 10.0, 2.5, 36.0])
    assert fig.axes[-1].get_xlabel() == "time (s)" and fig.get_suptitle() == "drive"
    assert all(ax.get_legend() is not None for ax in fig.axes) and line_colours(fig) <= PALETTE


def _band_at(ax, label, x):
    """(lower, upper) of the filled band called ``label`` at abscissa ``x``."""
    band = next(c for c in ax.collections if c.get_label() == label)
    v = np.concatenate([p.vertices for p in band.get_paths()])
    y = v[np.isclose(v[:, 0], x), 1]
    return y.min(), y.max()


@pytest.mark.parametrize("every", [1, 2, 3])
def test_nis_average_bounds_count_the_valid_samples_in_the_window(every):
    # A magnetometer on every other (or third) row: a 96-sample average holds 96/every values, and its
    # 95 % band is that of an average of 96/every χ²(6) values (scipy), wider than a full window's.
    rng = np.random.default_rng(3)
    t = np.arange(1040) / 104.0
    values = rng.chisquare(6, len(t))
    values[np.arange(len(t)) % every != 0] = np.nan
    fig = plots.nis_plot(t, values, dof=6, window=96)
    ax = fig.axes[0]
    n = 96 // every
    for k in (300, 500, 700):  # inside the record: the whole window is there
        lo, hi = _band_at(ax, "95 % bounds, average", t[k])
        assert lo == pytest.approx(chi2.ppf(0.025, 6 * n) / n, rel=1e-9)
        assert hi == pytest.approx(chi2.ppf(0.975, 6 * n) / n, rel=1e-9)
    # at the first sample half the window lies before the record: fewer values, a wider band
    lo0, hi0 = _band_at(ax, "95 % bounds, average", t[0])
    assert lo0 < chi2.ppf(0.025, 6 * n) / n and hi0 > chi2.ppf(0.975, 6 * n) / n
    # the drawn average is the mean of the valid values in the window (numpy)
    line = next(ln for ln in ax.lines if "average" in ln.get_label())
    k = 500
    assert line.get_ydata()[k] == pytest.approx(np.nanmean(values[k - 48 : k + 48]), rel=1e-12)


def test_nis_plot_of_an_update_that_never_happened_draws_no_band():
    t = np.arange(200) / 100.0
    fig = plots.nis_plot(t, np.full(len(t), np.nan), dof=3)
    band = next(c for c in fig.axes[0].collections if c.get_label() == "95 % bounds, average")
    assert band.get_paths() == []  # no valid sample in any window: no average, no bounds


def test_rmse_table_rotation_leaves_out_rows_whose_truth_is_missing(attitude):
    # Motion capture loses its markers now and then (BROAD: NaN rows); the rotation column is the RMSE of the rows
    # that have a truth, the rotation angle between the two attitudes by scipy.
    t, truth, good, _, _, _ = attitude
    gappy = truth.copy()
    gappy[50:80] = np.nan
    lines = []
    plots.rmse_table({"good": good}, gappy, rotation=True, out=lines.append)
    keep = ~np.isnan(gappy[:, 0])
    angle = (
        Rotation.from_euler("ZYX", good[keep][:, ::-1]).inv() * Rotation.from_euler("ZYX", truth[keep][:, ::-1])
    ).magnitude()
    assert float(lines[-1].split()[-1]) == pytest.approx(np.degrees(np.sqrt(np.mean(angle**2))), abs=0.006)


def test_consistency_table_nees_leaves_out_steps_without_truth():
    # Motion capture that lost its markers gives NaN errors, so NaN NEES: the mean and the fraction inside the
    # one-step bounds are those of the steps that have a truth (scipy's χ²(3) bounds).
    rng = np.random.default_rng(4)
    nees = rng.chisquare(3, 600)
    nees[200:260] = np.nan
    lines = []
    plots.consistency_table(nees, {}, out=lines.append)
    valid = nees[~np.isnan(nees)]
    inside = np.mean((valid >= chi2.ppf(0.025, 3)) & (valid <= chi2.ppf(0.975, 3)))
    assert f"mean {valid.mean():6.2f}" in lines[0] and f"{100 * inside:3.0f} % of samples" in lines[0]
