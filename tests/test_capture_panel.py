"""The capture panel driven from code (as its buttons and timer would) against the virtual board,
and the "done when" of issue 3: every guided dataset recorded and saved from the panel loads in the
analyses of labs 02–05 and gives the physics back."""
import time
from types import SimpleNamespace

import numpy as np
import pytest
import serial.tools.list_ports

from kfkit import calibration, capture, filters, frames, metrics, sensors
from kfkit.capture import virtual as C_virtual
from kfkit.filters.attitude import euler_to_quat
from kfkit.io import load_recording
from kfkit.widgets import capture_panel


@pytest.fixture
def panel(monkeypatch, tmp_path):
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [])
    p = capture_panel(out_dir=tmp_path, quick=True, fast=True)
    yield p
    p.stop()


def run_until_done(p, timeout=20.0):
    deadline = time.monotonic() + timeout
    while p.recorder is not None and time.monotonic() < deadline:
        p.refresh()  # what the canvas timer calls on the kernel's main thread
        time.sleep(0.05)
    assert p.recorder is None


def test_defaults_to_the_virtual_board_without_boards(panel):
    assert panel.port.value == "virtual" and panel.port.options[-1][1] == "virtual"


def test_guided_tilt_protocol_records_labelled_phases(panel, tmp_path):
    panel.protocol.value = "tilt"
    assert panel.board.value == "mpu6050" and panel.out.value.endswith("05_tilt_protocol.csv")
    panel.record()
    assert panel.recorder is not None and panel.record_button.disabled
    run_until_done(panel)
    rec = load_recording(tmp_path / "05_tilt_protocol.csv")
    assert {p["label"] for p in rec.phases} == {"pitch_0", "pitch_90", "roll_0", "roll_90"}
    assert len(rec) == len(panel.recording) == round(panel.seconds.value * 100)
    assert "done" in panel.status.value and panel.progress.value == 1.0
    assert len(panel.lines["acc"][0].get_xdata()) > 0  # the live plot was drawn


def test_stop_early_clips_phases_and_saves(panel, tmp_path):
    panel.fast = False  # real time, so that stop() comes before the end
    panel.protocol.value = "mag-rotations"
    panel.record()
    time.sleep(1.0)
    panel.refresh()
    panel.stop()
    rec = load_recording(tmp_path / "03_mag_rotations.csv")
    (phase,) = rec.phases
    assert phase["end"] <= rec.t[-1] + 0.011 and len(rec) < panel.seconds.value * 104
    assert 0.0 < panel.coverage.value <= 1.0


def test_board_decides_the_file_name_and_what_can_be_recorded(panel, monkeypatch):
    panel.board.value = "mpu6050"
    panel.protocol.value = "six-faces"
    assert panel.out.value.endswith("05_six_faces.csv")  # lab 05's board
    panel.board.value = "nucleo-iks02a1"
    assert panel.out.value.endswith("02_six_faces.csv")  # lab 02's
    panel.protocol.value = "mag-rotations"
    assert panel.board.value == "nucleo-iks02a1" and panel.out.value.endswith("03_mag_rotations.csv")
    panel.board.value = "mpu6050"  # no magnetometer
    assert "no magnetometer" in panel.prompt.value
    panel.record()
    assert panel.recorder is None and "no magnetometer" in panel.status.value
    for name, stem in (("axis-turns", "03_axis_turns"), ("headings", "03_headings")):  # lab 03's: the Nucleo's
        panel.board.value = "mpu6050"
        panel.protocol.value = name
        assert panel.board.value == "nucleo-iks02a1" and panel.out.value.endswith(f"{stem}.csv"), name
    panel.protocol.value = "stationary"  # recorded for labs 02 and 05: the board chosen stays
    panel.board.value = "mpu6050"
    panel.protocol.value = "six-faces"
    assert panel.board.value == "mpu6050" and panel.out.value.endswith("05_six_faces.csv")


def test_a_file_name_typed_by_the_user_is_kept(panel):
    panel.protocol.value = "mag-rotations"
    panel.out.value = "my_recordings/04_live_attitude.csv"  # lab 04: not over the lab 03 recording
    panel.board.value = "mpu6050"
    panel.board.value = "nucleo-iks02a1"
    panel.protocol.value = "stationary"
    assert panel.out.value == "my_recordings/04_live_attitude.csv"


def test_detected_board_sets_the_board_and_the_first_prompt(monkeypatch, tmp_path):
    ports = [SimpleNamespace(device="/dev/ttyUSB0", vid=0x1A86, pid=0x7523, description="USB Serial")]
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: ports)
    p = capture_panel(out_dir=tmp_path)
    assert p.port.value == "/dev/ttyUSB0" and p.board.value == "mpu6050" and p.board.layout.display == "none"
    p.protocol.value = "six-faces"
    assert "before you press record" in p.prompt.value and "components up" in p.prompt.value
    assert p.out.value.endswith("05_six_faces.csv")


def test_error_is_shown_not_raised(panel, monkeypatch, tmp_path):
    panel.port.options = [("nowhere", "/dev/ttyNOPE"), ("virtual", "virtual")]
    panel.port.value = "/dev/ttyNOPE"
    panel.record()
    assert panel.recorder is None and "not found" in panel.status.value


def test_timer_drives_the_panel_in_a_real_kernel(tmp_path):
    """In ipykernel the canvas timer fires on the kernel's main thread between cells: the panel
    records, redraws and saves with nobody calling refresh()."""
    from jupyter_client.manager import start_new_kernel

    km, kc = start_new_kernel(kernel_name="python3", cwd=str(tmp_path))
    try:
        def run(code):
            reply = kc.execute_interactive(code, timeout=60, output_hook=lambda msg: outputs.append(msg))
            assert reply["content"]["status"] == "ok", outputs

        outputs = []
        run("import threading, time\nfrom kfkit.widgets import capture_panel\n"
            "p = capture_panel(out_dir='rec', interval_ms=100)\np.port.value = 'virtual'\np.seconds.value = 1.0\n"
            "calls = []\nreal = p.refresh\n"
            "p.refresh = lambda: (calls.append(threading.current_thread() is threading.main_thread()), real())\n"
            "p.timer.remove_callback(real)\np.timer.add_callback(p.refresh)\np.record()")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            time.sleep(0.5)  # the kernel is idle here: only its event loop runs the timer
            outputs = []
            run("print(p.recording is not None and len(p.recording), len(calls), all(calls))")
            printed = "".join(m["content"].get("text", "") for m in outputs if m["msg_type"] == "stream")
            if not printed.startswith("False"):
                break
        samples, ticks, main_thread = printed.split()
        assert int(samples) == 104 and int(ticks) >= 3 and main_thread == "True"
        assert (tmp_path / "rec" / "capture.csv").exists()
    finally:
        kc.stop_channels()
        km.shutdown_kernel(now=True)


# -- done when: each guided dataset from the panel, saved, loaded, analysed as labs 02–05 do -------------------
LAB_DATASETS = {"nucleo-iks02a1": ("stationary", "six-faces", "mag-rotations", "axis-turns", "headings"),  # labs 02–04
                "mpu6050": ("stationary", "six-faces", "tilt")}  # lab 05


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Record every guided dataset with the panel (full durations, virtual board faster than real time)."""
    folder = tmp_path_factory.mktemp("my_recordings")
    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [])
    panel = capture_panel(out_dir=folder, fast=True)
    files = {}
    try:
        for board, protocols in LAB_DATASETS.items():
            for name in protocols:
                panel.port.value = "virtual"
                panel.protocol.value = name
                panel.board.value = board
                panel.record()
                assert panel.recorder is not None, panel.status.value
                run_until_done(panel, timeout=60)
                assert "done" in panel.status.value, panel.status.value
                files[board, name] = panel.out.value
    finally:
        panel.stop()
        monkeypatch.undo()
    return folder, {key: load_recording(path) for key, path in files.items()}  # as the labs load them


def test_each_guided_dataset_is_saved_under_the_name_its_lab_reads(recorded):
    folder, recs = recorded
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["02_stationary.csv", "02_six_faces.csv", "03_mag_rotations.csv", "03_axis_turns.csv", "03_headings.csv",
         "05_stationary.csv", "05_six_faces.csv", "05_tilt_protocol.csv"])
    for (board, name), rec in recs.items():
        motion = capture.protocol_motion(name, rec.rate_hz)
        s = rec.meta["capture"]["stats"]
        assert rec.meta["board"] == board and len(rec) == len(motion.t) and (s["bad_lines"], s["dropped"]) == (0, 0)
        assert [(p["start"], p["end"], p["label"]) for p in rec.phases] == [tuple(ph) for ph in motion.phases]


def test_lab02_bias_noise_and_six_faces_on_the_recordings(recorded):
    _, recs = recorded
    for board in LAB_DATASETS:
        still, faces = recs[board, "stationary"], recs[board, "six-faces"]
        cal = calibration.calibrate(still, faces)
        spec = faces.meta["sensors"]
        # the virtual board has no scale error: six faces give s = 1 within the noise of 5 s rests
        np.testing.assert_allclose(cal.accel_scale, 1.0, atol=3e-3)
        # two independent bias estimates agree: six faces vs the level rest (the virtual table is level)
        flat = calibration.accel_bias(still.body("acc"), [0.0, 0.0, -frames.G])
        np.testing.assert_allclose(cal.accel_bias, flat, atol=0.02)
        # corrected, every face reads |f| = g (within a few counts)
        for face in calibration.FACES:
            f = (faces.body("acc")[faces.phase(face)] - cal.accel_bias) / cal.accel_scale
            assert abs(np.linalg.norm(f.mean(axis=0)) - frames.G) < 3 * spec["acc"]["sensitivity"] + 0.005
        # the same board (seed) in both recordings: the gyro at rest on the faces reads lab 02's bias, within
        # 4 standard errors of the two means (white noise σ per sample from the rest)
        rest = np.zeros(len(faces), dtype=bool)
        for face in calibration.FACES:
            rest |= faces.phase(face)
        on_faces = faces.body("gyr")[rest]
        sem = np.asarray(cal.gyro_noise) * np.sqrt(1 / rest.sum() + 1 / len(still))
        # + the board's bias walk: both means are over windows of one path from t = 0 (each virtual board plays it
        # from its seed), Var(mean over [0, T]) = K²T/3; their (positive) covariance left out: an upper bound
        walk = C_virtual.BIAS_RANDOM_WALK[board][0] * np.sqrt((faces.t[-1] + still.t[-1]) / 3)
        assert np.all(np.abs(on_faces.mean(axis=0) - cal.gyro_bias) < 4 * np.hypot(sem, walk))
        # lab 02's noise σ matches the datasheet density of kfkit.sensors, σ = N·√rate (quantisation adds < 1 %)
        gyro_spec = sensors.board(board).gyro
        np.testing.assert_allclose(cal.gyro_noise, gyro_spec.noise_std(still.rate_hz), rtol=0.1)
        taus, adev = calibration.allan_deviation(still.body("gyr"), still.rate_hz)
        # at short τ white noise rules the Allan curve: σ(τ) = N/√τ with N the datasheet density
        k = int(np.argmin(np.abs(taus - 0.1)))
        np.testing.assert_allclose(adev[k], gyro_spec.noise_std(1.0) / np.sqrt(taus[k]), rtol=0.1)


def test_lab03_and_lab04_magnetometer_and_attitude_on_the_recordings(recorded):
    _, recs = recorded
    rot = recs["nucleo-iks02a1", "mag-rotations"]
    mag = rot.body("mag")
    assert capture.sphere_coverage(mag) >= 0.9  # what the panel's indicator asks for
    hard, soft = calibration.fit_mag_calibration(mag)
    fresh = np.isfinite(mag[:, 0])
    norms = np.linalg.norm(calibration.apply_mag_calibration(mag[fresh], hard, soft), axis=1)
    field = np.linalg.norm(frames.MAG_FIELD_LONDON)
    # the virtual board has no iron: the fit finds none, and calibrated norms are the local field
    assert np.linalg.norm(hard) < 1.0 and np.abs(soft - np.eye(3) * np.mean(np.diag(soft))).max() < 0.02
    assert abs(norms.mean() - field) < 0.05 and norms.std() < 0.02 * field
    # lab 04: the attitude EKF on the same recording, calibrated by labs 02/03, against the motion played
    cal = calibration.calibrate(recs["nucleo-iks02a1", "stationary"], recs["nucleo-iks02a1", "six-faces"], rot)
    gyr, acc, mag_cal = cal.apply(rot)
    result = filters.estimate_attitude(gyr, acc, mag_cal, rot.rate_hz, method="mekf", field_n=frames.MAG_FIELD_LONDON)
    truth = capture.protocol_motion("mag-rotations", rot.rate_hz).euler
    total, heading, tilt = metrics.attitude_errors(result.quat, euler_to_quat(truth))
    settled = rot.t > 5.0
    assert np.degrees(metrics.rmse(total[settled], 0.0)) < 1.0  # 0.25° here


def test_lab03_alignment_and_headings_on_the_recordings(recorded):
    """Lab 03 on the panel's recordings, calibrated by labs 02/03 from the recorded rest, faces and rotations:
    the turns show the IIS2MDC's 180° about y (DESIGN.md), the headings come out as the prompts asked."""
    _, recs = recorded
    still, faces, rot, turns, heads = (recs["nucleo-iks02a1", name] for name in LAB_DATASETS["nucleo-iks02a1"])
    cal = calibration.calibrate(still, faces, rot)
    # axis turns: the gyro (bias removed) integrates to +90° and back over each phase; the field read with the
    # IMU's mounting turns against it about x and z (the sense of each turn is that axis's sign, D = diag(−1, 1, −1))
    gyr = turns.body("gyr") - np.array(cal.gyro_bias)
    mag_as_imu = turns.sensor_si("mag") @ np.array(turns.meta["mount"]["acc"]).T
    plane = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}
    senses = []
    for k, axis in enumerate("xyz"):
        phase = turns.phase(f"turn_{axis}")
        angle = np.cumsum(gyr[phase, k]) / turns.rate_hz
        assert abs(np.degrees(angle.max()) - 90.0) < 0.5 and abs(np.degrees(angle[-1])) < 0.2, axis  # ~0.03°
        fresh = np.isfinite(mag_as_imu[phase, 0])
        i, j = plane[axis]
        field = np.unwrap(np.arctan2(mag_as_imu[phase][fresh, j], mag_as_imu[phase][fresh, i]))
        senses.append(np.sign(np.sum(angle[fresh] * -(field - field[0]))))
    assert senses == [-1.0, 1.0, -1.0]
    # headings: tilt from the six-face-corrected accelerometer, the magnetometer corrected by the rotations' fit;
    # each rest's mean heading against the heading its prompt asked for (flat, then tilted in reverse order)
    _, acc, mag = cal.apply(heads)
    roll, pitch = frames.accel_tilt(acc)
    fresh = np.isfinite(mag[:, 0])
    psi = frames.tilt_compensated_heading(mag[fresh], roll[fresh], pitch[fresh], frames.declination())
    asked = {"heading_flat": capture.guided.HEADINGS_DEG, "heading_tilted": capture.guided.HEADINGS_DEG[::-1]}
    for label, headings in asked.items():
        rests = [p for p in heads.phases if p["label"] == label]
        assert len(rests) == len(headings) == 6
        for p, want in zip(rests, headings):
            inside = ((heads.t >= p["start"]) & (heads.t < p["end"]))[fresh]
            error = np.angle(np.mean(np.exp(1j * (psi[inside] - np.radians(want)))))
            assert abs(np.degrees(error)) < 0.5, (label, want, np.degrees(error))  # ~0.1° here
        tilt = heads.phase(label)
        expected = capture.guided.HEADING_TILT_DEG if label == "heading_tilted" else (0, 0)
        np.testing.assert_allclose(np.degrees([np.median(roll[tilt]), np.median(pitch[tilt])]), expected, atol=0.2)


def test_lab05_tilt_filter_on_the_recordings(recorded):
    _, recs = recorded
    tilt, still, faces = (recs["mpu6050", name] for name in ("tilt", "stationary", "six-faces"))
    cal = calibration.calibrate(still, faces)
    gyr, acc, _ = cal.apply(tilt)
    gyr_raw = tilt.body("gyr")
    roll, pitch = frames.accel_tilt(acc)
    ok = filters.accel_static_ok(acc)
    known_roll, known_pitch = filters.tilt.protocol_angles(tilt)
    for axis, rate, angle, known in (("roll", 0, roll, known_roll), ("pitch", 1, pitch, known_pitch)):
        kf = filters.TiltBiasKF(1.0 / tilt.rate_hz, filters.tilt.DEFAULT_Q_ANGLE, filters.tilt.DEFAULT_Q_BIAS,
                                filters.tilt.DEFAULT_R)
        run = kf.run(gyr_raw[:, rate], angle, ok)  # raw gyro: the filter finds the bias itself
        held = np.isfinite(known) & (tilt.t > 3.0)
        assert np.degrees(metrics.rmse(run.angle[held], known[held])) < 0.5, axis  # 0.1–0.2° here
        # its bias state agrees with lab 02's bias from the separate rest recording (same board): within the
        # filter's error (≤ 0.02 °/s here) and 4σ of the board's bias walk between the rest's mean and the end
        # of the tilt recording (Var ≤ K²(t_end + T_rest/3), as above)
        walk = C_virtual.BIAS_RANDOM_WALK["mpu6050"][0] * np.sqrt(tilt.t[-1] + still.t[-1] / 3)
        assert abs(run.bias[-1] - cal.gyro_bias[rate]) < np.radians(0.02) + 4 * walk, axis  # biases: 1–6 °/s
