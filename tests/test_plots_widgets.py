"""Figures carry units; the tuning panel re-runs the filter and redraws when a value changes."""

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from waiting import HANG_GUARD_S

from kfkit import filters, motions, plots, sim, widgets
from kfkit.io import Recording
from kfkit.metrics import rmse


@pytest.fixture
def signals():
    rng = np.random.default_rng(0)
    t = np.arange(600) / 100.0
    truth = 0.4 * np.sin(t)
    gyro = np.gradient(truth, t) + rng.normal(0, 0.01, t.size)
    z = truth + rng.normal(0, 0.05, t.size)
    return t, truth, gyro, z


def test_standard_figures_have_units(signals):
    t, truth, gyro, z = signals
    run = filters.roll_kf(gyro, z, 0.01, 1e-6, 0.05**2)
    fig = plots.compare_angles(t, truth, {"accel only": (z, "accel"), "KF": (run.x, "kf")})
    assert fig.axes[0].get_ylabel() == "roll (°)" and fig.axes[0].get_xlabel() == "time (s)"
    fig = plots.consistency(t, run.x - truth, run.P, run.y, run.S)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["roll error (°)", "innovation (°)", "NIS (–)"]


def test_tuning_panel_reruns_and_redraws(signals):
    t, truth, gyro, z = signals
    calls = []

    def run(q, r):
        calls.append((q, r))
        return filters.roll_kf(gyro, z, 0.01, q, r).x

    panel = widgets.tune(run, t, truth, {"q": (1e-6, 1e-12, 1e-2), "r": (1e-3, 1e-6, 1.0)})
    first = panel.rmse
    assert first == pytest.approx(rmse(run(1e-6, 1e-3), truth))
    before = panel.line.get_ydata().copy()
    panel.sliders["q"].value = 1e-2  # as a student's drag would
    assert calls[-1][0] == pytest.approx(1e-2)
    assert not np.allclose(panel.line.get_ydata(), before)
    assert panel.rmse != first and "RMSE" in panel.status.value
    n = len(calls)
    panel.set(q=1e-5, r=1e-2)
    assert len(calls) == n + 1, "set() should re-run the filter once, not once per slider"


# --- live 3-D attitude view (lab 04) --------------------------------------------------------


def enu_from_ned(v):
    return np.array([v[1], v[0], -v[2]])


def scipy_quat(rotation):
    """w-x-y-z from scipy's x-y-z-w."""
    x, y, z, w = rotation.as_quat()
    return np.array([w, x, y, z])


def test_attitude_view_draws_the_body_axes_where_scipy_puts_them():
    rots = Rotation.from_euler("ZYX", [[0, 0, 0], [30, 20, -40], [-120, 70, 10]], degrees=True)
    quat = np.array([scipy_quat(r) for r in rots])
    view = widgets.attitude_view(np.arange(3) * 0.01, quat, truth=quat, stride=1)
    box, ghost, lines = view.box, view.ghost, list(view.axis_lines)
    n_artists = len(view.ax.collections) + len(view.ax.lines)
    for k, rot in enumerate(rots):
        view.slider.value = k  # as a student's drag (or the Play button) would
        for i, line in enumerate(view.axis_lines):
            xs, ys, zs = line.get_data_3d()
            tip = np.array([xs[1], ys[1], zs[1]])
            want = enu_from_ned(rot.as_matrix()[:, i])  # body axis i in NED, drawn as (E, N, U)
            np.testing.assert_allclose(tip / np.linalg.norm(tip), want, atol=1e-9)
        yaw, pitch, roll = rot.as_euler("ZYX", degrees=True)
        assert f"roll {roll:+6.1f}°" in view.status.value and f"yaw {yaw:+6.1f}°" in view.status.value
    # updates move the same artists; nothing is added
    assert view.box is box and view.ghost is ghost and list(view.axis_lines) == lines
    assert len(view.ax.collections) + len(view.ax.lines) == n_artists
    labels = [t.get_text() for t in view.ax.get_legend().get_texts()]
    assert labels == ["x forward", "y right", "z down"]
    assert [t.get_text() for t in view.ned_labels] == ["north", "east", "down"]
    for text, ned in zip(view.ned_labels, np.eye(3)):  # each drawn where its NED axis points (E, N, U)
        position = np.array(text.get_position_3d())
        np.testing.assert_allclose(position / np.linalg.norm(position), enu_from_ned(ned))


def test_attitude_view_rejects_mismatched_inputs():
    q = np.tile([1.0, 0, 0, 0], (5, 1))
    with pytest.raises(ValueError, match=r"one time per quaternion \(5\), got 4"):
        widgets.attitude_view(np.arange(4.0), q)
    with pytest.raises(ValueError, match=r"truth must have the shape of quat \(5, 4\), got \(3, 4\)"):
        widgets.attitude_view(np.arange(5.0), q, truth=q[:3])


def test_live_view_follows_a_growing_recording_and_a_reset():
    angles = np.radians([25.0, -15.0, 60.0])  # roll, pitch, yaw
    rec = sim.simulate_imu(motions.stationary(6.0, 104.0, *angles), seed=3, gyro_bias=[0, 0, 0])
    arrived = {"n": 0}

    def source():  # what recorder.recording(last_seconds=2) returns as samples arrive
        n = arrived["n"]
        keep = (rec.t < rec.t[max(n - 1, 0)] + 1e-9) & (rec.t >= rec.t[max(n - 1, 0)] - 2.0) if n else rec.t < -1
        return Recording(rec.meta, {k: v[keep] for k, v in rec.data.items()})

    fed = []
    estimator = widgets.LiveAttitude()
    update = estimator.update

    def counting_update(r):
        fed.append(len(r))
        return update(r)

    estimator.update = counting_update
    view = widgets.AttitudeView.live(source, estimator=estimator, start=False)
    assert view.poll() is None and view.latest is None  # nothing has arrived yet (and a timer callback returns None)
    for n in range(52, len(rec) + 1, 52):  # half a second per tick
        arrived["n"] = n
        assert view.poll() is None
        q = view.latest
    # fed in half-second pieces, the filter ends where one run over the whole recording ends
    whole = filters.EulerAttitudeEKF(rate_hz=rec.rate_hz).run(rec.body("gyr"), rec.body("acc"), rec.body("mag"))
    np.testing.assert_allclose(q, whole.quat[-1], atol=1e-9)
    assert sum(fed) > len(rec)  # it was shown overlapping snapshots, yet used each sample once
    true = Rotation.from_euler("ZYX", angles[::-1])
    got = Rotation.from_quat(np.r_[q[1:], q[0]])
    assert (true.inv() * got).magnitude() < np.radians(3.0)
    assert estimator.t_last == pytest.approx(rec.t[-1])
    yaw, pitch, roll = got.as_euler("ZYX", degrees=True)
    assert f"t = {rec.t[-1]:6.2f} s" in view.status.value
    assert f"roll {roll:+6.1f}°, pitch {pitch:+5.1f}°, yaw {yaw:+6.1f}°" in view.status.value
    # a board reset: time starts again from zero, the filter starts again
    arrived["n"] = 10
    view.poll()
    assert estimator.t_last == pytest.approx(rec.t[9])


def test_live_attitude_applies_a_calibration_and_names_a_bad_method():
    from kfkit.calibration import Calibration

    bias = np.array([0.01, -0.02, 0.015])  # rad/s, body frame
    rec = sim.simulate_imu(
        motions.stationary(3.0, 104.0, 0.2, -0.1, 1.0), seed=4, gyro_bias=np.diag([1.0, -1.0, -1.0]) @ bias
    )
    cal = Calibration(gyro_bias=bias.tolist())
    q = widgets.LiveAttitude(calibration=cal).update(rec)
    gyr, acc, mag = cal.apply(rec)
    np.testing.assert_allclose(q, filters.EulerAttitudeEKF(rate_hz=104.0).run(gyr, acc, mag).quat[-1], atol=1e-12)
    assert not np.allclose(q, widgets.LiveAttitude().update(rec), atol=1e-6)  # the bias matters
    with pytest.raises(ValueError, match="method must be one of euler-ekf, mekf, got 'ekf'"):
        widgets.LiveAttitude("ekf").update(rec)


def test_live_view_follows_the_virtual_board(tmp_path, monkeypatch):
    """End to end: a virtual board on a pty, the recorder's thread, polls from this thread; the board is the bundled
    unit, so the kit's default calibration (nothing saved) corrects it."""
    from kfkit import capture

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    angles = np.radians([17.0, -11.0, 57.0])
    motion = motions.stationary(20.0, 104.0, *angles)
    with capture.Recorder(capture.VirtualBoard(motion=motion, realtime=False, seed=1), seconds=8) as recorder:
        view = widgets.AttitudeView.live(
            lambda: recorder.recording(last_seconds=2.0),
            estimator=widgets.LiveAttitude("mekf", calibration="auto"),
            start=False,
        )
        assert recorder.done.wait(120)  # a safety net: the board's 8 s end it
        view.poll()
        q = view.latest
    got = Rotation.from_quat(np.r_[q[1:], q[0]])
    true = Rotation.from_euler("ZYX", angles[::-1])
    assert (true.inv() * got).magnitude() < np.radians(3.0)  # heading from a learned field: magnetic north
    assert view.estimator.t_last > 7.0


def test_live_view_follows_the_capture_panel_on_the_virtual_board(tmp_path, monkeypatch):
    """Lab 04's wiring: the capture panel (virtual board) drives the 3-D view; nothing is drawn
    before record; when the panel stops, the view keeps the last attitude."""
    from scipy.spatial.transform import Rotation as Rot

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))  # nothing saved: the kit's default calibration
    panel = widgets.capture_panel(out_dir=tmp_path, fast=True)
    panel.port.value, panel.seconds.value = "virtual", 4.0
    view = widgets.AttitudeView.live(panel, estimator=widgets.LiveAttitude("mekf", calibration="auto"), start=False)
    view.poll()
    assert view.latest is None and "t = " not in view.status.value  # not recording yet: nothing drawn
    panel.record()
    assert panel.recorder.done.wait(120)  # a safety net
    view.poll()
    q = view.latest
    # the virtual board lies level and north-facing (the MEKF's north: the field it learned)
    assert Rot.from_quat(np.r_[q[1:], q[0]]).magnitude() < np.radians(2.0)
    assert "t = " in view.status.value
    panel.refresh()  # the panel's timer tick: finishes and saves
    view.poll()
    assert panel.recorder is None and view.latest is q
    with pytest.raises(TypeError, match="source must be a capture panel, a Recorder or a callable"):
        widgets.AttitudeView.live(42)


def test_live_attitude_finds_the_boards_calibration_and_shows_a_wrong_one():
    from kfkit import datasets
    from kfkit.calibration import Calibration, load_calibration

    rec = datasets.load("04_attitude_tour").head(5.0)  # the Nucleo unit the bundled calibration belongs to
    q = widgets.LiveAttitude("mekf", calibration="auto").update(rec)
    gyr, acc, mag = load_calibration(board=rec.meta["board"]).apply(rec)
    np.testing.assert_allclose(
        q, filters.estimate_attitude(gyr, acc, mag, rec.rate_hz, method="mekf").quat[-1], atol=1e-12
    )
    view = widgets.AttitudeView.live(
        lambda: rec, estimator=widgets.LiveAttitude(calibration=Calibration(board="mpu6050")), start=False
    )
    view.poll()
    assert view.latest is None and "calibration is for board 'mpu6050'" in view.status.value


# --- the live views' timers, through matplotlib's own timer machinery ------------------------------------------


def run_timer_on_tornado(timer, stop_when, safety_s=HANG_GUARD_S):
    """Run ``timer`` (ipympl's TimerTornado) on a real tornado IOLoop, as ipykernel does, until ``stop_when()`` or the
    timer stopped itself; matplotlib's TimerBase._on_timer calls the callbacks and judges what they return, and
    tornado logs what they raise (as the Jupyter server log showed). Returns the number of ticks."""
    import asyncio
    import time

    ticks = {"n": 0}
    on_timer = timer._on_timer

    def counting():
        ticks["n"] += 1
        on_timer()

    timer._on_timer = counting
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    try:

        async def until_done():
            timer.start()
            deadline = time.monotonic() + safety_s  # a hang guard only
            while timer._timer is not None and not stop_when() and time.monotonic() < deadline:
                await asyncio.sleep(0.02)

        loop.run_until_complete(until_done())
    finally:
        timer._on_timer = on_timer
        asyncio.set_event_loop(None)
        loop.close()
    return ticks["n"]


def test_live_view_timer_runs_clean_and_stops_when_the_capture_ends(tmp_path, monkeypatch, caplog):
    """Lab 04's view on a Recorder, driven by the real timer: no callback error (poll returned the quaternion array
    and matplotlib's `if ret == 0` raised on every tick), and the timer stops by itself once the capture has ended,
    after drawing its last attitude."""
    import logging

    from scipy.spatial.transform import Rotation

    from kfkit import capture, motions

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    angles = np.radians([12.0, -8.0, 40.0])
    board = capture.VirtualBoard(motion=motions.stationary(30.0, 104.0, *angles), seed=2)  # real time: many ticks
    with caplog.at_level(logging.ERROR), capture.Recorder(board, seconds=1.5) as recorder:
        view = widgets.AttitudeView.live(
            recorder, estimator=widgets.LiveAttitude("mekf", calibration="auto"), interval_ms=50, start=False
        )
        ticks = run_timer_on_tornado(view.timer, stop_when=lambda: False)
        assert recorder.done.is_set()
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text  # not one traceback
    assert view.timer._timer is None and ticks >= 3  # it ticked while recording, then stopped by itself
    assert view.timer.callbacks == [(view.poll, (), {})]  # and poll was never dropped for returning 0
    assert view.latest is not None and view.estimator.t_last == pytest.approx(
        1.5 - 1 / 104, abs=1e-6
    )  # the last sample
    got = Rotation.from_quat(np.r_[view.latest[1:], view.latest[0]])
    assert (Rotation.from_euler("ZYX", angles[::-1]).inv() * got).magnitude() < np.radians(3.0)


def test_live_view_on_the_panel_starts_with_each_capture_stops_after_it_and_when_closed(tmp_path, monkeypatch):
    import serial.tools.list_ports

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [])
    panel = widgets.capture_panel(out_dir=tmp_path, fast=True)
    panel.port.value, panel.seconds.value = "virtual", 1.0
    view = widgets.AttitudeView.live(panel)  # start=True before the panel records: it waits, no timer
    assert view.timer._timer is None and "waiting for the capture panel" in view.status.value
    for capture_number in range(2):  # each capture starts the view, its end stops it
        panel.record()
        assert view.timer._timer is not None, capture_number
        assert panel.recorder.done.wait(120)  # a safety net
        panel.timer._on_timer()  # the panel's tick: it finishes and saves
        assert panel.recorder is None and panel.timer._timer is None
        view.timer._on_timer()  # the view's tick: draws the end of the saved recording and stops
        assert view.timer._timer is None and view.estimator.t_last == pytest.approx(1.0 - 1 / 104, abs=1e-6)
    view.start()
    assert view.timer._timer is None  # nothing being recorded: nothing to poll
    view.close()
    panel.record()
    assert view.timer._timer is None and not panel.on_record  # a closed view follows nothing
    panel.stop()
    other = widgets.AttitudeView.live(lambda: None, interval_ms=50)  # a callable: runs until closed
    assert other.timer._timer is not None
    other.canvas.close()  # its widget closed (as by the notebook): the next tick stops the timer
    other.timer._on_timer()
    assert other.timer._timer is None


def test_tuning_sliders_start_at_their_values_even_outside_the_suggested_range(signals):
    """A measured r below the lab's range widens the range; the browser's slider grid passes through each
    initial value (value = 10**(min + k·step)), so its read-out shows what panel.values holds."""
    t, truth, gyro, z = signals
    panel = widgets.tune(
        lambda q, r: filters.roll_kf(gyro, z, 0.01, q, r).x,
        t,
        truth,
        {"q": (7.5e-11, 1e-9, 1e-2), "r": (3.3e-4, 1e-3, 1.0)},
    )
    assert panel.values == pytest.approx({"q": 7.5e-11, "r": 3.3e-4}, rel=1e-12)
    for name, slider in panel.sliders.items():
        assert 10**slider.min <= panel.values[name] <= 10**slider.max
        k = (np.log10(panel.values[name]) - slider.min) / slider.step
        assert abs(k - round(k)) < 1e-9, f"{name}: its value is not on the slider's grid"
    assert 10 ** panel.sliders["q"].max >= 1e-2 and 10 ** panel.sliders["r"].max >= 1.0  # the suggested range is kept
    with pytest.raises(ValueError, match="slider 'q'"):
        widgets.tune(lambda q: truth, t, truth, {"q": (1e-3, 1.0, 1e-6)})


def test_tuning_panel_without_truth_draws_no_error_line(signals):
    t, _, gyro, z = signals
    panel = widgets.tune(lambda q: filters.roll_kf(gyro, z, 0.01, q, 1e-3).x, t, None, {"q": (1e-6, 1e-9, 1e-2)})
    assert not panel.err_line.get_visible() and np.isnan(panel.rmse)
