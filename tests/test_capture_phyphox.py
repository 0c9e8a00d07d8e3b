"""A phone as the capture port: phyphox's REST API against the virtual phone on 127.0.0.1.

A live capture records with the recorder's statistics (rate, jitter, dropped samples against their
statistical expectations), the phone's physics (specific force g up, the heading it lies at), its
metadata; and the errors: remote access off, an unreachable phone, an experiment without the
sensors, phyphox refusing to start, a phone that pauses or stops answering mid-capture (what arrived
is saved). Every server is on 127.0.0.1 and stops by itself. Most phones here step their clock by a fixed
amount per poll (``step_s``), so a busy machine makes a test slower, never different.
"""

import json
import socket
import time
from http.server import BaseHTTPRequestHandler, HTTPServer
from threading import Thread

import numpy as np
import pytest
import serial.tools.list_ports

from kfkit import frames
from kfkit.capture import Recorder, capture
from kfkit.capture.errors import (
    PhoneError,
    PhoneExperimentError,
    PhoneStoppedError,
    PhoneUnreachableError,
    RemoteAccessOffError,
)
from kfkit.capture.phyphox_http import PhyphoxClient, parse_url
from kfkit.capture.virtual_phone import VirtualPhone, format_number
from kfkit.cli import main
from kfkit.io import load_recording
from kfkit.phone_sim import PHONE_RATES, TIMESTAMP_JITTER
from kfkit.sensors import PHONE_ACCEL, PHONE_GYRO, PHONE_LSB
from kfkit.unit_errors import PHONE_UNIT

G = 9.80665
STILL_YAW = 30.0  # the virtual phone's default: flat and still, top edge 30° east of north


@pytest.fixture
def vphone():
    with VirtualPhone(step_s=0.8, seed=3) as vp:
        yield vp


def test_live_capture_records_with_the_recorders_statistics(tmp_path):
    """20 s of a phone flat and still, 5 % of its samples lost: every sample or loss is counted."""
    p_drop = 0.05
    with VirtualPhone(step_s=1.0, seed=5, drop=p_drop) as vp:
        rec = capture(vp.url, seconds=20.0, out=tmp_path / "phone.csv")
        assert vp.requests["keep_alive"] == 0 and vp.requests["get"] > 10  # one connection per request
        assert not vp.measuring  # the capture started the phone, so it stopped it again
    s = rec.meta["capture"]["stats"]
    assert s["bad_lines"] == 0 and s["resets"] == 0
    made = s["samples"] + s["dropped"]  # gyro samples the phone made in the recorded span
    assert made == pytest.approx(20.0 * PHONE_RATES["gyr"], abs=2)
    # lost samples: binomial(made, p), within 4σ
    assert abs(s["dropped"] - p_drop * made) < 4 * np.sqrt(made * p_drop * (1 - p_drop))
    # interval jitter of i.i.d. timestamp jitter σ_t: σ_t·√2 (consecutive samples only)
    assert s["jitter_us"] == pytest.approx(TIMESTAMP_JITTER * 1e6 * np.sqrt(2), rel=0.12)
    assert s["dt_mean_us"] == pytest.approx(1e6 / PHONE_RATES["gyr"], rel=2e-3)
    # physics: at rest, level, the specific force is g up; the heading is the one the phone lies at
    acc, mag = rec.body("acc"), rec.body("mag")
    np.testing.assert_allclose(acc.mean(axis=0), [0.0, 0.0, -G], atol=0.08)  # a few mg of offset
    roll, pitch = frames.accel_tilt(acc)
    fresh = np.isfinite(mag[:, 0])
    assert fresh.mean() == pytest.approx(PHONE_RATES["mag"] / PHONE_RATES["gyr"], abs=0.05)
    psi = frames.tilt_compensated_heading(mag[fresh], roll[fresh], pitch[fresh], frames.declination())
    assert np.degrees(np.mean(psi)) == pytest.approx(STILL_YAW, abs=4.0)  # ~1 µT of residual hard iron
    # the file on disk is the same recording, with the phone's metadata
    saved = load_recording(tmp_path / "phone.csv")
    assert len(saved) == len(rec) and saved.meta["board"] == "phone-phyphox"
    assert saved.meta["sensors"]["gyr"]["sensitivity"] == PHONE_LSB["gyr"] and saved.meta["mount_name"] == "flat"
    assert saved.meta["phone"]["experiment"] == "Phone IMU" and "kfkit" in saved.meta["phone"]["device"]["deviceBrand"]
    np.testing.assert_array_equal(saved.body("gyr"), rec.body("gyr"))


def test_the_file_carries_the_whole_captures_clock_rate_and_a_90_degree_turn_integrates_to_90(tmp_path):
    """A phone whose gyro runs at 401.9 Hz with 0.3 ms of timestamp jitter: the header's rate is a guess from the first
    rows (it was 0.7 % to 1.55 % off, and a 90° turn integrated to 1.4° wrong); the final file's rate_hz must be the
    phone clock's over the whole capture, within 4σ of the jitter's effect on it (√2·σ_t/T) plus its rounding, and the
    turn about body x (calibration_motions.axis_turns) must integrate to 90° with it."""
    from kfkit import calibration_motions

    served, seconds = 401.9, 6.0
    motion = calibration_motions.axis_turns(
        hold=2.0, move=1.5, rate_hz=1000.0
    )  # rest 2 s, roll 90° in 1.5 s, rest 2 s, …
    with VirtualPhone(motion, seed=11, step_s=0.5, rates={"gyr": served, "acc": 400.7}) as vp:
        capture(vp.url + "?timeout=60", seconds=seconds, out=tmp_path / "turn.csv")
    rec = load_recording(tmp_path / "turn.csv")
    header_rate = rec.meta["capture"]["header_rate_hz"]
    tolerance = 4 * np.sqrt(2) * TIMESTAMP_JITTER / seconds + 5e-6
    assert abs(rec.rate_hz / served - 1) < tolerance, (rec.rate_hz, header_rate)
    assert rec.meta["capture"]["stats"]["dt_mean_us"] == pytest.approx(1e6 / rec.rate_hz, rel=5e-6)
    # the roll about body x, from the rest before it (bias removed as lab 02 does) to the rest after it
    gyr_x = rec.body("gyr")[:, 0]
    bias = gyr_x[rec.t < 1.5].mean()
    turned = np.degrees(np.sum(gyr_x[rec.t < 4.5] - bias) / rec.rate_hz)
    assert turned == pytest.approx(90.0, abs=0.1), (turned, np.degrees(np.sum(gyr_x[rec.t < 4.5] - bias) / header_rate))


def test_capture_of_a_phone_already_measuring_skips_old_data_and_leaves_it_running(tmp_path):
    with VirtualPhone(speed=10.0, autostart=True) as vp:
        time.sleep(0.3)  # 3 s of the phone's data before the capture
        before = vp.experiment_time()
        rec = capture(vp.url, seconds=2.0)
        assert vp.measuring  # not ours to stop
    assert len(rec) == pytest.approx(2.0 * PHONE_RATES["gyr"], abs=2)
    assert rec.meta["protocol"]["header"].startswith("#KFKIT,1,board=phone-phyphox")
    assert before > 2.0


def test_mounting_rides_on_the_address(vphone):
    rec = capture(vphone.url + "?mount=flat_landscape&poll=0.05", seconds=1.0)
    assert rec.meta["mount_name"] == "flat_landscape"
    np.testing.assert_allclose(rec.body("acc").mean(axis=0), [0.0, 0.0, -G], atol=0.08)
    assert parse_url("phyphox://10.0.0.7") == ("10.0.0.7", 8080, {})


def test_the_cli_records_from_a_phone(vphone, tmp_path, capsys):
    out = tmp_path / "cli.csv"
    assert main(["capture", "--port", vphone.url, "--seconds", "1.5", "--out", str(out), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["board"] == "phone-phyphox" and stats["samples"] == len(load_recording(out)) > 140


def test_the_capture_panel_records_from_a_phone(vphone, tmp_path, monkeypatch):
    from kfkit.widgets import capture_panel

    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [])
    panel = capture_panel(out_dir=tmp_path)
    panel.port.value = "phone"
    assert panel.phone.layout.display is None and panel.baud.layout.display == "none"
    panel.phone.value = vphone.address
    panel.seconds.value = 1.5
    panel.record()
    assert panel.recorder is not None, panel.status.value
    deadline = time.monotonic() + 20
    while panel.recorder is not None and time.monotonic() < deadline:
        panel.refresh()
        time.sleep(0.05)
    assert "done" in panel.status.value and len(panel.recording) > 140
    assert len(panel.lines["acc"][0].get_xdata()) > 0  # the live plot drew the phone's signals
    panel.phone.value = ""
    panel.record()
    assert panel.recorder is None and "no host" in panel.status.value


# --- errors ----------------------------------------------------------------------------------------------


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_remote_access_off_says_so(tmp_path, capsys):
    url = f"phyphox://127.0.0.1:{free_port()}"  # nothing listens there
    with pytest.raises(RemoteAccessOffError, match="connection refused.*'Allow remote access'"):
        Recorder(url).start()
    assert main(["capture", "--port", url, "--seconds", "1", "--out", str(tmp_path / "x.csv")]) == 2
    assert "remote access" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_an_unreachable_phone_times_out_with_advice():
    with socket.socket() as s:  # accepts connections (the kernel does) but never answers
        s.bind(("127.0.0.1", 0))
        s.listen(8)
        url = f"phyphox://127.0.0.1:{s.getsockname()[1]}?timeout=0.5"
        t0 = time.monotonic()
        with pytest.raises(PhoneUnreachableError, match="no answer .* within 0.5 s.*same Wi-Fi"):
            Recorder(url).start()
        assert time.monotonic() - t0 < 60.0  # a safety net: it gave up (after 0.5 s), it did not hang


def test_a_server_that_is_not_phyphox():
    class NotPhyphox(BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(404)
            self.end_headers()

        def log_message(self, *args):
            pass

    server = HTTPServer(("127.0.0.1", 0), NotPhyphox)
    Thread(target=server.handle_request, daemon=True).start()
    try:
        with pytest.raises(PhoneError, match="HTTP 404.*not phyphox"):
            PhyphoxClient("127.0.0.1", server.server_address[1], timeout=2.0).config()
    finally:
        server.server_close()


@pytest.mark.parametrize(
    "experiment, message",
    [
        ("gyroscope", r"'Gyroscope'\) has no accelerometer \(it has: gyroscope\).*New simple experiment"),
        ("acceleration-without-g", r"no accelerometer.*linear acceleration \(gravity removed\).*'Acceleration with g'"),
        ("simple-linear", r"no accelerometer.*linear acceleration"),
    ],
)
def test_an_experiment_without_the_sensors_names_what_to_open(experiment, message):
    with VirtualPhone(experiment=experiment) as vp:
        with pytest.raises(PhoneExperimentError, match=message):
            Recorder(vp.url).start()
        assert not vp.measuring  # nothing was started


def test_without_a_magnetometer_it_records_gyro_and_accelerometer():
    with VirtualPhone(experiment="simple-no-mag", speed=8.0) as vp:
        rec = capture(vp.url, seconds=1.0)
    assert "mx" not in rec.columns and set(rec.meta["sensors"]) == {"acc", "gyr"}


def test_phyphox_refusing_to_start():
    with (
        VirtualPhone(faults={"refuse_start": True}) as vp,
        pytest.raises(PhoneExperimentError, match="refused to start"),
    ):
        Recorder(vp.url).start()


def test_a_phone_that_pauses_mid_capture_keeps_what_arrived(tmp_path):
    with (
        VirtualPhone(step_s=0.8, faults={"pause_at": 4.0}) as vp,
        pytest.raises(PhoneStoppedError, match="stopped measuring"),
    ):
        capture(vp.url, seconds=30.0, out=tmp_path / "paused.csv")
    rec = load_recording(tmp_path / "paused.csv")
    assert 3.5 < rec.t[-1] < 4.0 and rec.meta["capture"]["stats"]["samples"] == len(rec)


@pytest.mark.slow
def test_a_phone_that_stops_answering_mid_capture_keeps_what_arrived(tmp_path):
    with (
        VirtualPhone(step_s=0.4, faults={"hang_after": 15}) as vp,
        pytest.raises(PhoneUnreachableError, match="no answer"),
    ):
        capture(vp.url + "?timeout=5", seconds=60.0, out=tmp_path / "lost.csv")  # 5 s: a busy machine answers
    rec = load_recording(tmp_path / "lost.csv")
    assert len(rec) > 100 and rec.meta["capture"]["stats"]["samples"] == len(rec)


# --- the virtual phone speaks phyphox ----------------------------------------------------------------------


def test_virtual_phone_answers_like_phyphox(vphone):
    client = PhyphoxClient("127.0.0.1", vphone.port)
    config = client.config()
    assert {i["source"] for i in config["inputs"]} == {"accelerometer", "gyroscope", "magnetic_field"}
    assert config["export"][0]["set"] == "Accelerometer" and config["export"][0]["sources"][0]["label"] == "Time (s)"
    empty = client.get([("gyr_time", ""), ("nope", "full")])
    assert empty["buffer"] == {"gyr_time": {"size": 0, "updateMode": "single", "buffer": [None]}}
    assert empty["status"]["measuring"] is False and client.start()
    time.sleep(0.3)
    full = client.get([("gyr_time", "full"), ("gyrX", "full")])["buffer"]
    t = full["gyr_time"]["buffer"]
    assert full["gyr_time"]["updateMode"] == "full" and len(t) == len(full["gyrX"]["buffer"]) > 10
    # incremental: only values after the threshold, for a buffer and for one read against it
    part = client.get([("gyr_time", repr(t[4])), ("gyrZ", f"{t[4]!r}|gyr_time")])["buffer"]
    assert part["gyr_time"]["updateMode"] == "partial" and part["gyr_time"]["buffer"][0] == t[5]
    assert len(part["gyrZ"]["buffer"]) == len(part["gyr_time"]["buffer"])
    with pytest.raises(PhoneError, match="HTTP 400.*Invalid threshold"):
        client.get([("gyr_time", "soon|gyr_time")])
    with pytest.raises(PhoneError, match="HTTP 400.*Unknown reference buffer"):
        client.get([("gyrX", "1|nope")])
    assert client.clear() and client.get([("gyr_time", "full")])["buffer"]["gyr_time"]["buffer"] == []


def test_values_have_phyphox_8_significant_digits():
    assert format_number(9.80665) == "9.80665E0" and format_number(-0.00123456789) == "-1.2345679E-3"
    assert format_number(0.0) == "0E0" and format_number(float("nan")) == "null"


@pytest.mark.slow
def test_virtual_phone_clocks_and_bias_walks_run_on_across_its_loops():
    """20 min from the virtual phone (its 30 s motion looped 40 times): no sample lost at a seam, and the Allan
    curves follow the phone's white noise and its unit's walk (PHONE_UNIT), each point within its 99.9 %
    chi-square interval (tests/allan_oracle.py): the gyro as captured (the time base), the accelerometer as the
    phone serves it (the capture interpolates it at the gyro's times, which changes its short-τ curve)."""
    from allan_oracle import allan_curves, model_adev, outside_chi2_interval

    with VirtualPhone(seed=3, step_s=20.0) as vp:  # its clock moves 20 s per poll, however long a poll takes
        rec = capture(vp.url + "?timeout=120", seconds=1200.0)
        t_acc, acc = vp._series("acc", 1200.0)
    s = rec.meta["capture"]["stats"]
    assert (s["dropped"], s["bad_lines"]) == (0, 0) and len(rec) > 1200 * 100
    assert np.all(np.diff(t_acc) > 0) and np.diff(t_acc).max() < 1.5 / PHONE_RATES["acc"]  # no seams
    series = {"gyr": (rec.sensor_si("gyr"), s["rate_hz"]), "acc": (acc, (len(t_acc) - 1) / (t_acc[-1] - t_acc[0]))}
    for sensor, chip, K in (
        ("gyr", PHONE_GYRO, PHONE_UNIT["gyro_bias_rw"]),
        ("acc", PHONE_ACCEL, PHONE_UNIT["accel_bias_rw"]),
    ):
        x, rate = series[sensor]
        taus, adev = allan_curves(x, rate)
        model = model_adev(taus, chip.noise_density, K, PHONE_LSB[sensor], rate)
        assert outside_chi2_interval(taus, adev, model, len(x), rate) == [], sensor
