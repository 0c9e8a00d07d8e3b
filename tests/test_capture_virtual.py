"""End to end over a pseudo-terminal: the virtual board with each fault kind, the recorder,
the streamed file, the CLI. Expected statistics come from the fault positions, not from the code."""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import unit_truth
from allan_oracle import allan_curves, loglog_slope, model_adev, outside_chi2_interval

import kfkit.capture as C
from kfkit import motions
from kfkit.capture import ports as ports_module
from kfkit.cli import main
from kfkit.frames import MAG_FIELD_LONDON, G
from kfkit.io import load_recording, recording_text
from kfkit.unit_errors import BIAS_RANDOM_WALK

RATE = 1000.0
N = 200  # samples the board makes in SECONDS of board time
SECONDS = N / RATE


@pytest.fixture(autouse=True)
def no_leaks():
    """Every test closes its threads and file descriptors."""
    fds, threads = set(os.listdir("/proc/self/fd")), threading.active_count()
    yield
    for t in threading.enumerate():
        if t.name.startswith("kfkit-"):
            t.join(5)
    assert threading.active_count() <= threads
    assert set(os.listdir("/proc/self/fd")) <= fds | {f for f in os.listdir("/proc/self/fd") if not f.isdigit()}


def record(faults=None, board="nucleo-iks02a1", out=None, seconds=SECONDS, board_options=None, **options):
    """Record from a virtual board that sends as fast as it is read. The recorder's own (wall-clock) timeouts stay at
    their defaults unless a test is about them, so a busy machine cannot make a clean stream look silent."""
    vb = C.VirtualBoard(rate_hz=RATE, board=board, faults=faults, realtime=False, seed=3, **(board_options or {}))
    rec = C.Recorder(vb, out=out, seconds=seconds, **options)
    with rec:
        assert rec.wait(120)  # a safety net: the capture ends by the board's clock (or an error) long before
    return rec


def test_clean_stream_physics_and_time():
    rec = record(board="nucleo-iks02a1")
    s, r = rec.stats, rec.recording()
    assert (s.samples, s.bad_lines, s.dropped, s.resets) == (N, 0, 0, 0)
    np.testing.assert_allclose(r.t, np.arange(N) / RATE, atol=1e-6)  # t_us rounds to whole µs
    np.testing.assert_array_equal(r["seq"], np.arange(N))
    assert s.rate_hz == pytest.approx(RATE, rel=1e-9) and s.dt_mean_us == 1000.0 and s.jitter_us == 0.0
    fresh = np.isfinite(r.body("mag")[:, 0])
    # IIS2MDC at 50 Hz beside 1 kHz samples: a new reading on 1 sample in 20, counting the first
    assert fresh.sum() == (N - 1) * 50 // 1000 + 1


# --- the unit it simulates: by default the bundled recordings' (kfkit.datasets), or an ideal sensor -------------
# Oracle: the sensor model written out here (sensor frame: ω_s = b_g, f_s = k ⊙ M_accᵀ f_b + b_a,
# m_s = W M_magᵀ m_b + h) with the errors kfkit.datasets simulates the bundled recordings with (tests/unit_truth.py).


def expected_at_rest(rec, errors):
    """What each sensor of ``rec``'s board reads on average lying flat at yaw 0 (sensor frame, SI) with ``errors``."""
    f_b, m_b = np.array([0.0, 0.0, -G]), np.asarray(MAG_FIELD_LONDON, float)  # level, nose north: body = NED
    M = {k: np.array(v) for k, v in rec.meta["mount"].items()}
    want = {
        "gyr": np.asarray(errors.get("gyro_bias", np.zeros(3)), float),
        "acc": np.asarray(errors.get("accel_scale", np.ones(3))) * (M["acc"].T @ f_b) + errors.get("accel_bias", 0.0),
    }
    if "mag" in M:
        want["mag"] = np.asarray(errors.get("mag_soft_iron", np.eye(3))) @ M["mag"].T @ m_b + errors.get(
            "mag_hard_iron", 0.0
        )
    return want


def assert_reads_at_rest(rec, errors):
    """Each sensor's mean within 4 standard deviations of ``expected_at_rest`` (white noise and ``errors``' walks)."""
    walks = {"gyr": errors.get("gyro_bias_rw", 0.0), "acc": errors.get("accel_bias_rw", 0.0), "mag": 0.0}
    for sensor, want in expected_at_rest(rec, errors).items():
        x = rec.sensor_si(sensor)
        fresh = np.isfinite(x[:, 0])
        z = (x[fresh].mean(axis=0) - want) / unit_truth.mean_sd(rec, fresh, sensor, walks[sensor])
        assert np.all(np.abs(z) < 4), (sensor, z)


@pytest.mark.parametrize("board", ["nucleo-iks02a1", "mpu6050"])
@pytest.mark.parametrize("unit", ["bundled", None])
def test_at_rest_each_sensor_reads_its_units_errors(board, unit):
    """By default the board is the unit of its bundled recordings: 20 s at rest read its biases, scale errors and
    iron, each axis within 4 standard errors; ``unit=None`` reads the bare physics (no bias, walk, scale, iron)."""
    rec = C.capture("virtual", 20.0, virtual={"board": board, "realtime": False, "seed": 11, "unit": unit})
    assert_reads_at_rest(rec, unit_truth.UNITS[board] if unit == "bundled" else {})


def test_a_unit_of_ones_own_and_bad_units():
    """A dict sets only the errors it names (the rest are zero); bad ones are refused before any thread starts."""
    errors = {"gyro_bias": [0.01, -0.02, 0.03], "mag_hard_iron": [5.0, 0.0, -5.0]}
    rec = C.capture("virtual", 20.0, virtual={"realtime": False, "seed": 12, "unit": errors})
    assert_reads_at_rest(rec, errors)
    for unit, match in (
        ("ideal", "unit must be 'bundled', None or a dict"),
        ({"hard_iron": [1, 2, 3]}, "unknown sensor error\\(s\\) hard_iron.*known: gyro_bias"),
        ({"mag_soft_iron": np.eye(2)}, "mag_soft_iron: expected finite values of shape \\(3, 3\\)"),
        ({"gyro_bias_rw": float("nan")}, "gyro_bias_rw: expected finite"),
        ({"accel_bias_rw": -1e-5}, "accel_bias_rw: .*a walk ≥ 0"),
    ):
        with pytest.raises(ValueError, match=match):
            C.VirtualBoard(unit=unit)
    with pytest.raises(ValueError, match="no bundled unit for board 'phone-phyphox'.*unit=None"):
        C.VirtualBoard(board="phone-phyphox")
    with pytest.raises(ValueError, match="sim_options: colour, seed cannot be set"):
        C.VirtualBoard(sim_options={"seed": 1, "colour": "red"})


def at(position):
    """Board time (s) of the sample the board made at ``position`` (1 kHz, from t = 0)."""
    return round(position / RATE, 6)


# Each fault kind on its own and all together. Expected values follow from the positions by hand:
# a lost sample at position p leaves a gap "before sample p − (losses before p)", at t = p / RATE.
FAULT_CASES = {
    "corrupt": (
        {"corrupt": [10, 20]},
        {},
        dict(
            samples=N - 2,
            bad_checksum=2,
            malformed=0,
            dropped=2,
            drops=[(10, at(10), 1), (19, at(20), 1)],
            resets=0,
            reset_positions=[],
        ),
    ),
    "drop": (
        {"drop": [30, 31, 32]},
        {},
        dict(
            samples=N - 3, bad_checksum=0, malformed=0, dropped=3, drops=[(30, at(30), 3)], resets=0, reset_positions=[]
        ),
    ),
    "truncate": (
        {"truncate": [40]},
        {},
        dict(
            samples=N - 1, bad_checksum=0, malformed=1, dropped=1, drops=[(40, at(40), 1)], resets=0, reset_positions=[]
        ),
    ),
    "reset": (
        {"reset": [100]},
        {},
        dict(samples=N, bad_checksum=0, malformed=0, dropped=0, drops=[], resets=1, reset_positions=[100]),
    ),
    # after 50 min micros() > 2³¹: a restart to 1500 µs looks like a step forwards; the header gives it away
    "reset after 2**31 us": (
        {"reset": [100]},
        {"start_us": 3_000_000_000},
        dict(samples=N, bad_checksum=0, malformed=0, dropped=0, drops=[], resets=1, reset_positions=[100]),
    ),
    # seq 65436 + 100 = 65536 wraps to 0 at position 100: that sample and the one at 150 are lost
    "drops across the seq wrap": (
        {"drop": [100, 150]},
        {"start_seq": 65436},
        dict(
            samples=N - 2,
            bad_checksum=0,
            malformed=0,
            dropped=2,
            drops=[(100, at(100), 1), (149, at(150), 1)],
            resets=0,
            reset_positions=[],
        ),
    ),
    "all at once": (
        {"corrupt": [10, 20], "drop": [30, 31, 32], "truncate": [40], "reset": [100]},
        {},
        dict(
            samples=N - 6,
            bad_checksum=2,
            malformed=1,
            dropped=6,
            drops=[(10, at(10), 1), (19, at(20), 1), (28, at(30), 3), (35, at(40), 1)],
            resets=1,
            reset_positions=[100 - 6],
        ),
    ),
}


@pytest.mark.parametrize("case", FAULT_CASES)
def test_each_fault_gives_exactly_its_statistics(case):
    faults, board_options, expected = FAULT_CASES[case]
    rec = record(faults=faults, board_options=board_options)
    s = rec.stats
    assert {k: getattr(s, k) for k in expected} == expected
    assert s.duration_s == at(N - 1) and s.rate_hz == pytest.approx((expected["samples"] - 1) / at(N - 1))
    assert s.dt_mean_us == 1000.0 and s.jitter_us == 0.0  # consecutive samples only: gaps and resets left out
    seq = rec.recording()["seq"]
    for i in expected["reset_positions"]:
        assert seq[i] == 0 and seq[i - 1] != 65535  # seq restarts at the reset
    if board_options.get("start_seq"):
        assert seq[0] == 65436 and seq[99] == 65535 and seq[100] == 1  # wrapped, seq 0 lost


def test_jitter_of_a_104_hz_board_clock():
    """t_us = round(k · 10⁶/104): steps of 9615 or 9616 µs; the recorder's jitter is their standard deviation."""
    vb = C.VirtualBoard(rate_hz=104.0, board="mpu6050", realtime=False)
    with C.Recorder(vb, seconds=4.0) as rec:
        assert rec.wait(10)
    steps = np.diff(np.round(np.arange(416) * 1e6 / 104.0))
    s = rec.stats
    assert s.samples == 416 and set(steps) == {9615.0, 9616.0}
    assert s.dt_mean_us == pytest.approx(steps.mean(), abs=1e-9) and s.jitter_us == pytest.approx(steps.std(), abs=1e-6)
    assert s.rate_hz == pytest.approx(415 / (steps.sum() * 1e-6), rel=1e-12)


def test_random_faults_are_counted_consistently():
    rec = record(faults={"corrupt": 0.05, "drop": 0.05})
    s = rec.stats
    made = s.samples + s.dropped
    assert s.bad_checksum > 0 and s.dropped > s.bad_checksum
    assert made == N  # every sample the board made is either received or counted as dropped


def test_micros_wrap_keeps_time_continuous():
    vb = C.VirtualBoard(rate_hz=RATE, board="mpu6050", realtime=False, start_us=2**32 - 50_500)
    with C.Recorder(vb, seconds=0.1) as rec:
        rec.wait(10)
    r = rec.recording()
    assert rec.stats.resets == 0 and len(r) == 100
    np.testing.assert_allclose(r.t, np.arange(100) / RATE, atol=1e-6)


def test_disconnect_keeps_every_sample_on_disk(tmp_path):
    out = tmp_path / "cut.csv"
    vb = C.VirtualBoard(rate_hz=RATE, realtime=False, faults={"disconnect": 150, "drop": [5]})
    rec = C.Recorder(vb, out=out, seconds=10).start()
    try:
        assert rec.wait(10)
        assert isinstance(rec.error, C.BoardDisconnectedError)
        streamed = load_recording(out)  # before stop(): what the streaming writer put on disk
        assert len(streamed) == 149
    finally:
        with pytest.raises(
            C.BoardDisconnectedError,
            match=f"disconnected.*every sample received \\(149 samples, 0.15 s\\) is saved in {out}",
        ):
            rec.stop()
    final = load_recording(out)
    assert len(final) == 149 and final.meta["capture"]["stats"]["dropped"] == 1


def test_streamed_file_is_flushed_while_recording(tmp_path):
    """A real-time board: the file grows while the capture runs (flushed every flush_s), not only at the end, and
    what is on disk is what was received, row for row."""
    out = tmp_path / "live.csv"
    rec = C.Recorder(C.VirtualBoard(rate_hz=200.0, board="mpu6050"), out=out, seconds=600, flush_s=0.2).start()
    try:
        deadline = time.monotonic() + 120  # a safety net: 0.2 s of flushing is all it takes
        while (not out.exists() or out.read_text().count("\n") < 2 + 100) and time.monotonic() < deadline:
            assert not rec.done.is_set(), rec.error
            time.sleep(0.05)
        streamed = out.read_text()
        running = not rec.done.is_set()
        received = rec.recording()
    finally:
        rec.stop()
    rows = streamed.split("\n")[2:-1]
    assert running and len(rows) >= 100  # on disk while the 600 s capture was still running
    assert rows == recording_text(received).split("\n")[2 : len(rows) + 2]


def test_board_that_stops_sending_mid_capture(tmp_path):
    out = tmp_path / "stalled.csv"
    with C.VirtualBoard(rate_hz=RATE, board="mpu6050", realtime=False) as vb:
        rec = C.Recorder(vb, out=out, seconds=60, no_data_s=0.5).start()
        deadline = time.monotonic() + 120  # a safety net
        while rec.stats.samples < 100 and time.monotonic() < deadline:
            time.sleep(0.01)
        rec._serial.write(b"s")  # the board stops streaming, as a crashed sketch or a loose cable would
        assert rec.wait(120)
        with pytest.raises(C.NoDataError, match=f"stopped sending.*after [0-9]+ samples.*saved in {out}"):
            rec.stop()
    assert len(load_recording(out)) == rec.stats.samples >= 100


def test_wrong_baud_names_the_expected_rate():
    with pytest.raises(C.WrongBaudError, match="wrong baud rate.*115200 baud.*open at 9600.*baud=115200"):
        record(faults={"garbage": True}, baud=9600, garbage_s=0.3)


def test_silent_board_says_check_the_sketch():
    with pytest.raises(C.NoDataError, match="nothing received.*sketch is flashed"):
        record(faults={"silent": True}, no_data_s=0.4)


def test_unknown_protocol_version_over_a_pty():
    """The board's very first line is a version-2 header: an error, not a line skipped as partial."""
    with pytest.raises(C.ProtocolVersionError, match="unknown protocol.*version 2; this kfkit reads version 1"):
        record(board_options={"protocol_version": 2})


PERMISSION_PROBE = """
import grp, os, sys
import serial
import kfkit.capture as C  # imported as root (Python itself may live where others cannot read)
os.setgroups([]); os.setgid(65534); os.setuid(65534)  # then an ordinary user outside the port's group
try:
    C.open_port(sys.argv[1])
except C.PortPermissionError as e:
    print(e)
"""


@pytest.mark.slow
def test_permission_denied_names_the_group_and_the_command():
    """A real pty owned by root:dialout, mode 660, opened by a user outside dialout (as /dev/ttyACM0 is)."""
    import grp
    import subprocess
    import sys

    with C.VirtualBoard(rate_hz=RATE, realtime=False) as vb:
        if os.geteuid() == 0:
            try:
                os.chown(vb.port, 0, grp.getgrnam("dialout").gr_gid)
            except KeyError:
                pytest.skip("no dialout group on this system")
            os.chmod(vb.port, 0o660)
            run = subprocess.run(
                [sys.executable, "-c", PERMISSION_PROBE, vb.port], capture_output=True, text=True, timeout=60
            )
            message = run.stdout.strip()
            assert message == (
                f"permission denied opening {vb.port}; serial ports belong to the group 'dialout' "
                "and you are not in it: sudo usermod -aG dialout $USER   (then log out and in again)"
            ), run.stderr
        else:  # not root: take the read/write bits off our own pty
            os.chmod(vb.port, 0)
            with pytest.raises(C.PortPermissionError, match=f"permission denied opening {vb.port}"):
                C.open_port(vb.port)


def nucleo_at(device):
    """What pyserial's comports() reports for a Nucleo's ST-LINK on ``device``."""
    from serial.tools.list_ports_common import ListPortInfo

    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.description = 0x0483, 0x374B, "STM32 STLink"
    info.hwid = "USB VID:PID=0483:374B SER=066DFF SUBSYSTEM=usb"
    return info


@pytest.mark.parametrize("port", ["auto", "hwgrep://0483:374B"])
def test_auto_and_hwgrep_find_the_board_by_its_usb_id(monkeypatch, port):
    """The same pty, announced by a mocked comports() as a Nucleo: 'auto' and hwgrep:// both open it."""
    import serial.tools.list_ports

    with C.VirtualBoard(rate_hz=RATE, realtime=False) as vb:
        monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [nucleo_at(vb.port)])
        with C.Recorder(port, seconds=0.05) as rec:
            assert rec.wait(10)
    assert rec.stats.samples == 50 and rec.header.board == "nucleo-iks02a1"
    if port == "auto":
        assert (
            rec.description == f"auto: the only known board is {vb.port} [0483:374B] ST-LINK/V2-1 "
            f"(STM32 Nucleo-64 such as the Nucleo-F411RE) → probably nucleo-iks02a1"
        )


def test_second_recorder_on_the_same_port_is_busy():
    with C.VirtualBoard(rate_hz=RATE, realtime=False) as vb, C.Recorder(vb.port, seconds=0.01) as first:
        with pytest.raises(C.PortBusyError, match="busy"):
            C.Recorder(vb.port).start()
        first.wait(5)


def test_commands_h_and_s():
    import serial

    # readline's timeout is a safety net (it returns at the newline); "stopped" = quiet for 1 s, then 1 s more
    with C.VirtualBoard(rate_hz=RATE, board="mpu6050") as vb, serial.Serial(vb.port, timeout=30) as port:
        port.write(b"h")
        assert C.parse_line(port.readline()).board == "mpu6050"  # first contact: header, then samples
        assert isinstance(C.parse_line(port.readline()), C.Sample)
        port.write(b"s")  # stop
        port.timeout = 1.0
        while port.read(4096):
            pass
        assert port.read(1) == b""
        port.write(b"h")
        port.timeout = 30
        assert isinstance(C.parse_line(port.readline()), C.Header)


# --- the noise process: one bias random walk across the simulator's 1 s chunks ---------------------------------
# Oracles: the datasheet densities N (kfkit.sensors), the configured walks K, allantools (tests/allan_oracle.py).


def rest(board, seconds, rate_hz, sim_options=None, seed=7):
    """A fast virtual recording of the board lying still, through the pty like any capture."""
    return C.capture(
        "virtual",
        seconds,
        virtual={"board": board, "rate_hz": rate_hz, "realtime": False, "seed": seed, "sim_options": sim_options},
    )


def curves_and_model(rec, sensor, chip, K):
    """Allan curves of ``rec``'s ``sensor`` (SI, sensor frame) and the model of its datasheet density and walk K."""
    x, rate = rec.sensor_si(sensor), rec.rate_hz
    taus, adev = allan_curves(x, rate)
    return taus, adev, model_adev(taus, chip.noise_density, K, rec.meta["sensors"][sensor]["sensitivity"], rate)


@pytest.mark.slow
def test_allan_deviation_shows_white_noise_then_the_walk_beyond_the_chunks():
    """5 min at 104 Hz with a strong walk (τ_min < 1 s): slope −½ below the minimum, +½ from 5 s to 30 s, far past
    the simulator's 1 s chunks (a walk restarted per chunk gives −½ there), at the level the densities give."""
    from kfkit.sensors import board as get_board

    K = {"gyr": 2e-4, "acc": 1e-3}  # rad/s/√s, m/s²/√s
    rec = rest("nucleo-iks02a1", 300.0, 104.0, {"gyro_bias_rw": K["gyr"], "accel_bias_rw": K["acc"]})
    spec = get_board("nucleo-iks02a1")
    for sensor, chip in (("gyr", spec.gyro), ("acc", spec.accel)):
        taus, adev, model = curves_and_model(rec, sensor, chip, K[sensor])
        tau_min = np.sqrt(3) * chip.noise_density / K[sensor]  # 0.8 s, 1.0 s
        assert abs(loglog_slope(taus, adev, 0.0, tau_min / 10) + 0.5) < 0.05, sensor
        assert abs(loglog_slope(taus, adev, 5.0, 30.0) - 0.5) < 0.2, sensor
        assert outside_chi2_interval(taus, adev, model, len(rec), rec.rate_hz) == [], sensor


@pytest.mark.slow
@pytest.mark.parametrize("board", ["nucleo-iks02a1", "mpu6050"])
def test_allan_deviation_of_a_long_rest_at_the_boards_densities(board):
    """40 min at rest at 12.5 Hz (the ISM330DHCX's lowest rate, as lab 02's bundled rest): every point of the Allan
    curve within its 99.9 % interval of the datasheet's white noise plus the board's walk (BIAS_RANDOM_WALK)."""
    from kfkit.sensors import board as get_board

    rec = rest(board, 2400.0, 12.5)
    spec, (K_gyro, K_accel) = get_board(board), BIAS_RANDOM_WALK[board]
    for sensor, chip, K in (("gyr", spec.gyro, K_gyro), ("acc", spec.accel, K_accel)):
        taus, adev, model = curves_and_model(rec, sensor, chip, K)
        assert outside_chi2_interval(taus, adev, model, len(rec), rec.rate_hz) == [], sensor
        assert taus.max() > 3 * np.sqrt(3) * chip.noise_density / K  # the curve reaches well past its minimum


def test_angle_random_walk_of_a_two_minute_rest_is_the_datasheets():
    """Lab 00's full stationary protocol (2 min, 104 Hz): the ARW read at τ = 1 s (kfkit.calibration) within the
    99 % chi-square interval (allantools' edf for white noise) of N, quantisation and walk included."""
    allantools = pytest.importorskip("allantools")
    from kfkit.allan import allan_deviation, angle_random_walk
    from kfkit.sensors import board as get_board

    rec = C.record_protocol("stationary", "virtual", fast=True, seed=7, prompt=None)
    assert rec.t[-1] == pytest.approx(120.0, abs=0.01)
    gyro = get_board("nucleo-iks02a1").gyro
    x = rec.sensor_si("gyr")
    taus, adev = allan_deviation(x, rec.rate_hz)
    arw = angle_random_walk(taus, adev)
    want = model_adev(
        1.0,
        gyro.noise_density,
        BIAS_RANDOM_WALK["nucleo-iks02a1"][0],
        rec.meta["sensors"]["gyr"]["sensitivity"],
        rec.rate_hz,
    )
    assert want == pytest.approx(gyro.noise_density, rel=0.01)  # at 1 s the white noise is all there is
    m = int(round(rec.rate_hz))
    edf = allantools.edf_greenhall(alpha=0, d=2, m=m, N=len(x) + 1, overlapping=True)
    lo, hi = allantools.confidence_interval(want, edf, ci=0.99)
    assert np.all((lo <= arw) & (arw <= hi)), (arw / want, lo / want, hi / want)


def read_items(port, until_quiet=1.0):
    """Parse every line a stopped board still sends, until it has been quiet for ``until_quiet`` s."""
    port.timeout, items = until_quiet, []
    while line := port.readline():
        items.append(C.parse_line(line))
    return items


def samples_before_first_att(items):
    first = next(i for i, item in enumerate(items) if isinstance(item, C.Message))
    return sum(isinstance(item, C.Sample) for item in items[:first])


def test_attitude_board_measures_the_bias_again_after_stop_and_start_as_the_sketch():
    """firmware/mpu6050_tilt_kf: header, #NOTE, 2 s of samples alone, then sample + $ATT pairs; 's' stops, and
    's' again restarts the 2 s bias measurement with new filters (the board may have moved meanwhile)."""
    import serial

    from kfkit.filters import TiltAttitude

    sketch = (Path(__file__).parents[1] / "firmware/mpu6050_tilt_kf/mpu6050_tilt_kf.ino").read_text()
    assert f'Serial.println(F("{C.virtual.ATTITUDE_NOTE.decode().rstrip()}"))' in sketch  # the sketch's words
    with (
        C.VirtualBoard(board="mpu6050", attitude=True, realtime=False, seed=5) as vb,
        serial.Serial(vb.port, timeout=30) as port,
    ):  # a safety net: readline returns at the newline
        port.write(b"h")
        assert C.parse_line(port.readline()).params["filter"] == "tilt_kf"
        assert port.readline() == C.virtual.ATTITUDE_NOTE
        before = [C.parse_line(port.readline()) for _ in range(400)]
        port.write(b"s")  # stop
        before += read_items(port)
        assert samples_before_first_att(before) == 200 and not any(isinstance(i, C.Note) for i in before)
        time.sleep(0.3)
        port.write(b"s")  # start again
        port.timeout = 30
        after = [C.parse_line(port.readline()) for _ in range(1 + 200 + 2 * 50)]  # note, bias, sample + $ATT pairs
    assert isinstance(after[0], C.Note) and "keep the board still for 2 s" in after[0].text
    assert sum(isinstance(i, C.Note) for i in after) == 1 and samples_before_first_att(after[1:]) == 200
    # the $ATT lines after the restart are those of new filters fed only the samples after it
    samples = [i for i in after if isinstance(i, C.Sample)]
    fresh = TiltAttitude("mpu6050", 100.0)
    expected = [fresh.step(s.values[2:5], s.values[5:8]) for s in samples]
    got = [i.values for i in after if isinstance(i, C.Message)]
    expected = np.degrees([e for e in expected if e is not None])[: len(got)]
    assert len(got) > 10 and np.max(np.abs(np.array(got) - expected)) <= 0.005 + 1e-9  # two decimals on the wire
    t_us = [i.t_us for i in before + after if isinstance(i, C.Sample)]
    seq = [i.seq for i in before + after if isinstance(i, C.Sample)]
    assert max(np.diff(t_us)) >= 300_000 and np.all(np.diff(seq) == 1)  # micros() ran on; seq did not restart


def test_attitude_board_after_a_reset_sends_header_note_and_measures_again():
    """A reset reboots the sketch: header, #NOTE, and 2 s of samples (200 at 100 Hz) without $ATT again."""
    vb = C.VirtualBoard(board="mpu6050", attitude=True, realtime=False, faults={"reset": [300]}, seed=5)
    with C.Recorder(vb, seconds=6.0) as rec:
        assert rec.wait(10)
    note = C.virtual.ATTITUDE_NOTE.decode().strip()[1:]
    assert rec.stats.resets == 1 and rec.stats.notes == [note, note]
    # (samples received before it, values): the first $ATT follows the 200th sample of each start
    n = rec.stats.samples
    assert [i for i, _ in rec.messages["ATT"]] == list(range(200, 301)) + list(range(500, n + 1))


def test_guided_motion_phases_reach_the_recording(tmp_path):
    motion = C.protocol_motion("six-faces", 208.0, quick=True)
    r = C.capture(
        "virtual",
        seconds=len(motion.t) / 208.0,
        out=tmp_path / "faces.csv",
        virtual=dict(motion=motion, realtime=False),
    )
    loaded = load_recording(tmp_path / "faces.csv")
    assert {p["label"] for p in loaded.phases} == {"x_up", "x_down", "y_up", "y_down", "z_up", "z_down"}
    f = loaded.body("acc")[loaded.phase("x_up")].mean(axis=0)  # x up reads +g of specific force
    np.testing.assert_allclose(f, [G, 0.0, 0.0], atol=0.3)
    assert len(r) == len(motion.t)


def test_protocol_steps_cover_the_motion():
    motion = motions.tilt_protocol(rate_hz=100.0, hold=1.0, move=0.5)
    steps = C.protocol_steps("tilt", motion)
    assert steps[0][:3] == (0.0, 1.0, "pitch_0") and steps[1][2] is None
    assert all(a[1] == pytest.approx(b[0]) for a, b in zip(steps, steps[1:]))
    assert steps[-1][1] == pytest.approx(len(motion.t) / 100.0)


def test_sphere_coverage():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(5000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    assert C.sphere_coverage(v + [0.3, -0.2, 0.1]) == 1.0  # a hard-iron offset smaller than the field
    assert C.sphere_coverage(v + [3.0, -2.0, 1.0], center=[3.0, -2.0, 1.0]) == 1.0
    assert C.sphere_coverage(np.tile([1.0, 0.0, 0.0], (100, 1)) + rng.normal(0, 1e-3, (100, 3))) == 1 / 26


def test_cli_capture_virtual_json(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["capture", "--port", "virtual", "--seconds", "0.1", "--rate", "500", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["samples"] == 50 and result["bad_lines"] == 0 and result["dropped"] == 0 and result["resets"] == 0
    assert result["out"] == str(out.resolve()) and len(load_recording(out)) == 50


def test_cli_capture_error_exit_code(tmp_path, capsys):
    assert main(["capture", "--port", "/dev/ttyNOPE", "--out", str(tmp_path / "x.csv")]) == 2
    assert "/dev/ttyNOPE not found" in capsys.readouterr().err


def test_cli_guided_protocol_on_the_virtual_board(tmp_path, capsys):
    out = tmp_path / "faces.csv"
    assert (
        main(
            [
                "capture",
                "--port",
                "virtual",
                "--protocol",
                "six-faces",
                "--quick",
                "--fast",
                "--out",
                str(out),
                "--json",
            ]
        )
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    rec = load_recording(out)
    assert result["samples"] == len(rec) == round(13.5 * 104) and result["board"] == "nucleo-iks02a1"
    assert {p["label"] for p in rec.phases} == {"x_up", "x_down", "y_up", "y_down", "z_up", "z_down"}


@pytest.mark.parametrize(
    "name, labels", [("axis-turns", {"turn_x", "turn_y", "turn_z"}), ("headings", {"heading_flat", "heading_tilted"})]
)
def test_cli_records_lab03s_protocols(tmp_path, capsys, name, labels):
    out = tmp_path / f"{name}.csv"
    assert (
        main(["capture", "--port", "virtual", "--protocol", name, "--quick", "--fast", "--out", str(out), "--json"])
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    rec = load_recording(out)
    assert result["board"] == "nucleo-iks02a1" and {p["label"] for p in rec.phases} == labels
    assert (
        main(
            [
                "capture",
                "--port",
                "virtual",
                "--protocol",
                name,
                "--board",
                "mpu6050",
                "--quick",
                "--out",
                str(tmp_path / "no.csv"),
            ]
        )
        == 2
    )
    assert "no magnetometer" in capsys.readouterr().err and not (tmp_path / "no.csv").exists()


def test_record_protocol_on_a_real_port_labels_phases_from_the_prompts(tmp_path):
    """A port that is not "virtual" gets its phases from the prompt timeline (here a pty board at rest)."""
    prompts = []
    with C.VirtualBoard(rate_hz=100.0, board="mpu6050", realtime=False) as vb:
        rec = C.record_protocol("tilt", vb.port, tmp_path / "tilt.csv", quick=True, prompt=prompts.append)
    motion = C.protocol_motion("tilt", 100.0, quick=True)
    steps = C.protocol_steps("tilt", motion)
    assert [(p["start"], p["end"], p["label"]) for p in rec.phases] == [tuple(ph) for ph in motion.phases]
    # every instruction, in order, even though the fast board outruns the ten-a-second progress calls
    assert [text.split(" s  ", 1)[1] for text in prompts] == [step[3] for step in steps] and "level" in prompts[0]


def test_lab03_protocols_on_a_real_port_keep_one_window_per_phase(tmp_path):
    """The axis turns' phases are prompted in five steps each (rest, turn, rest, back, rest) and the six headings
    share a label: the recording's windows are still the motion's, one per phase and one per rest."""
    for name in ("axis-turns", "headings"):
        with C.VirtualBoard(board="nucleo-iks02a1", realtime=False) as vb:
            rec = C.record_protocol(name, vb.port, tmp_path / f"{name}.csv", quick=True, prompt=None)
        motion = C.protocol_motion(name, 104.0, quick=True)
        assert [(p["start"], p["end"], p["label"]) for p in rec.phases] == [tuple(ph) for ph in motion.phases]


@pytest.mark.parametrize("name", C.PROTOCOLS)
@pytest.mark.parametrize("quick", [False, True])
def test_each_prompt_list_has_one_text_per_segment(name, quick):
    """A label's list of prompts is used up exactly: one text per rest or turn of its windows, in time order;
    the steps tile the recording."""
    p = C.PROTOCOLS[name]
    motion = C.protocol_motion(name, 104.0, quick=quick)
    steps = C.protocol_steps(name, motion)
    assert steps[0][0] == 0.0 and steps[-1][1] == pytest.approx(len(motion.t) / 104.0, abs=1 / 104)
    assert all(a[1] == pytest.approx(b[0]) for a, b in zip(steps, steps[1:]))
    for label, texts in p.prompts.items():
        if isinstance(texts, list):
            assert [step[3] for step in steps if step[2] == label] == texts, label
    for _, _, label, text in steps:
        assert label is None or text == p.prompts[label] or text in p.prompts[label]


def test_lab03_protocols_need_the_magnetometer():
    assert (
        C.dataset_name("axis-turns") == "03_axis_turns"
        and C.dataset_name("headings", "nucleo-iks02a1") == "03_headings"
    )
    for name in ("axis-turns", "headings", "mag-rotations"):
        with pytest.raises(ValueError, match="not recorded with the mpu6050 \\(it has no magnetometer\\)"):
            C.dataset_name(name, "mpu6050")


KFKIT = Path(sys.executable).with_name("kfkit")  # the console script pip installed beside this Python


def fresh_shell_env():
    """A new terminal's environment: no PYTHONPATH, started outside the repository."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PYTEST"))}


@pytest.mark.slow
@pytest.mark.skipif(not KFKIT.exists(), reason="the kfkit console script is not installed")
def test_kfkit_capture_from_a_fresh_shell(tmp_path):
    """`kfkit capture --port virtual --seconds S --out x.csv`, as typed in a new terminal."""
    run = subprocess.run(
        [str(KFKIT), "capture", "--port", "virtual", "--seconds", "2", "--out", "x.csv"],
        cwd=tmp_path,
        env=fresh_shell_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    assert "recording 2 s from virtual board (nucleo-iks02a1, 104 Hz) on /dev/pts/" in run.stderr
    assert "[##############################]" in run.stderr  # the progress bar reached the end
    assert run.stdout.startswith("samples        208 (t = 0 … 1.99 s): effective rate 104.00 Hz")
    assert "bad lines      0 (0 bad checksum, 0 malformed)\ndropped        0\nboard resets   0\n" in run.stdout
    assert run.stdout.endswith("saved 208 samples to x.csv\n")
    assert len(load_recording(tmp_path / "x.csv")) == 208


@pytest.mark.skipif(not KFKIT.exists(), reason="the kfkit console script is not installed")
def test_ctrl_c_keeps_what_arrived(tmp_path):
    out = tmp_path / "long.csv"
    proc = subprocess.Popen(
        [str(KFKIT), "capture", "--port", "virtual", "--seconds", "60", "--out", str(out)],
        env=fresh_shell_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while (not out.exists() or out.stat().st_size < 3000) and time.monotonic() < deadline:
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 130 and f"stopped: what arrived is saved in {out}" in err
    rec = load_recording(out)
    assert len(rec) > 20 and rec.meta["capture"]["stats"]["samples"] == len(rec)  # the final file, statistics included


# --- what was streamed is what the final file holds: the protocol's whole integer range, exactly ------------------


def test_every_accepted_value_reaches_the_final_file_exactly_and_out_of_range_lines_are_counted(tmp_path):
    """Raw lines over a pty (a Nucleo header: its mx, my, mz are float columns, NaN where mag_new = 0): counts over the
    whole int32 range, t_us across the 2³² wrap, seq across the 2¹⁶ wrap, and lines whose values lie outside the
    protocol's range (2⁵³ + 1, 10²⁰, 2³¹, a negative t_us, seq 2¹⁶), each with a valid checksum. The out-of-range lines
    are counted as malformed and nothing else; every accepted value is in the streamed file and, value for value and
    character for character, in the final one."""
    import tty

    from kfkit.capture.virtual import board_header
    from kfkit.sensors import board as get_board

    n, step_us, start_us, start_seq = 400, 9615, 2**32 - 1_000_000, 65_400  # micros() wraps 1 s in, seq at 136
    rng = np.random.default_rng(17)
    counts = rng.integers(-(2**31), 2**31, (n + 1, 9))
    counts[:4] = [
        [-(2**31)] * 9,
        [2**31 - 1] * 9,
        [2**24 + 1] * 9,
        [-(2**24) - 1] * 9,
    ]  # the edges (2^24 + 1: not float32)
    mag_new = (np.arange(n + 1) % 2 == 0).astype(int)
    good = [
        C.encode_sample(((start_us + k * step_us) % 2**32, (start_seq + k) % 2**16, *counts[k], mag_new[k]))
        for k in range(n + 1)
    ]  # the last one is past `seconds`: it ends the capture by the board's clock
    bad = [
        C.encode_sample(values)
        for values in (
            (5, 1, 2**53 + 1, 0, 0, 0, 0, 0, 0, 0, 0, 1),
            (5, 1, 10**20, 0, 0, 0, 0, 0, 0, 0, 0, 1),
            (5, 1, 0, 0, 0, 0, 0, 0, 2**31, 0, 0, 1),
            (5, 1, 0, 0, 0, 0, 0, 0, 0, 0, -(2**31) - 1, 1),
            (-5, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1),
            (5, 2**16, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1),
            (2**32, 1, *[0] * 9, 1),
        )
    ]
    stream = bytearray(board_header(get_board("nucleo-iks02a1"), 104.0))
    for k, line in enumerate(good):
        stream += line + (bad[k // 50] if k % 50 == 25 and k // 50 < len(bad) else b"")  # 7 bad lines among them
    out = tmp_path / "exact.csv"
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        rec = C.Recorder(os.ttyname(slave), out=out, seconds=(n - 0.5) * step_us * 1e-6).start()
        try:
            os.write(master, bytes(stream))  # the recorder reads concurrently
            assert rec.wait(120), "the capture did not end by the board's clock"  # a safety net
            streamed = out.read_text()  # flushed when the reader ended, not yet rewritten
        finally:
            rec.stop()
    finally:
        os.close(master)
        os.close(slave)
    s = rec.stats
    assert (s.samples, s.malformed, s.bad_checksum, s.dropped, s.resets) == (n, len(bad), 0, 0, 0)
    final = out.read_text()
    assert final.split("\n")[2:] == streamed.split("\n")[2:]  # the rewrite changed the metadata only
    for text in (streamed, final):
        assert "9007199254740993" not in text and "100000000000000000000" not in text
    for r in (load_recording(out), rec.recording()):
        np.testing.assert_array_equal(r["seq"], (start_seq + np.arange(n)) % 2**16)
        np.testing.assert_array_equal(
            np.column_stack([r[c] for c in ("ax", "ay", "az", "gx", "gy", "gz")]), counts[:n, :6]
        )
        mag, fresh = np.column_stack([r[c] for c in ("mx", "my", "mz")]), mag_new[:n] == 1
        np.testing.assert_array_equal(mag[fresh], counts[:n][fresh, 6:].astype(float))  # exact: |v| < 2^53
        assert np.isnan(mag[~fresh]).all()
        np.testing.assert_allclose(r.t, np.round(np.arange(n) * step_us * 1e-6, 6), rtol=0, atol=1e-9)


# --- kfkit capture when a capture fails: one JSON object, or the statistics and where the data is ----------------


def run_cli(capsys, port, out, *extra):
    code = main(["capture", "--port", port, "--seconds", "60", "--out", str(out), *extra])
    return code, capsys.readouterr()


CLI_FAILURES = {  # name: (board options, error class, words of its message, samples that arrive)
    "no data": ({"faults": {"silent": True}}, "NoDataError", "nothing received", 0),
    "stall mid-capture": ({"faults": {"stall": 120}}, "NoDataError", "stopped sending .* after 120 samples", 120),
    "disconnect": ({"faults": {"disconnect": 150}}, "BoardDisconnectedError", "disconnected", 150),
    "unknown protocol version": ({"protocol_version": 2}, "ProtocolVersionError", "unknown protocol", 0),
}


#: the cases that wait out the capture's 3 s of silence: their human form is in the full suite only
WAITS = ("no data", "stall mid-capture")


@pytest.mark.parametrize(
    "case, as_json",
    [
        pytest.param(case, as_json, id=f"{case}-{'json' if as_json else 'human'}", marks=slow)
        for case in CLI_FAILURES
        for as_json, slow in ((True, ()), (False, pytest.mark.slow if case in WAITS else ()))
    ],
)
def test_cli_capture_failure_still_reports_statistics_and_where_the_data_is(tmp_path, capsys, case, as_json):
    board_options, error_type, words, samples = CLI_FAILURES[case]
    out = tmp_path / "failed.csv"
    with C.VirtualBoard(rate_hz=RATE, board="mpu6050", realtime=False, **board_options) as vb:
        code, printed = run_cli(capsys, vb.port, out, *(["--json"] if as_json else []))
    assert code == 2
    saved = samples > 0
    assert out.exists() == saved and (not saved or len(load_recording(out)) == samples)
    if as_json:
        (line,) = printed.out.splitlines()  # exactly one JSON object, nothing else on stdout
        result = json.loads(line)
        assert result["error_type"] == error_type and re.search(words, result["error"]), result["error"]
        assert result["samples"] == samples and result["bad_lines"] == 0 and result["port"] == vb.port
        assert result["out"] == (str(out.resolve()) if saved else None)
        assert result["board"] == (None if case in ("no data", "unknown protocol version") else "mpu6050")
        if saved:
            assert f"is saved in {out.resolve()}" in result["error"]
            assert result["clock_rate_hz"] == load_recording(out).rate_hz == RATE
    else:
        assert re.search(f"capture failed: .*{words}", printed.err)
        assert printed.out.startswith(f"samples        {samples}") and "bad lines      0" in printed.out
        assert printed.out.splitlines()[-1] == (
            f"saved {samples} samples to {out}"
            if saved
            else f"nothing saved: no samples arrived, {out} was not written"
        )


def fail_at(n_fail):
    """An ``extra_lines`` hook of the virtual board that raises at sample ``n_fail``: its thread fails mid-capture."""

    def hook(board, n, euler):
        if n == n_fail:
            raise ZeroDivisionError("division by zero (a failing simulation)")

    return hook


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "human"])
@pytest.mark.parametrize("reached", ["--port virtual", "its pty"])
def test_a_board_whose_thread_fails_mid_capture_gives_one_answer_and_keeps_what_arrived(
    tmp_path, capsys, monkeypatch, reached, as_json
):
    """The virtual board's thread raising (a bug in what it plays) used to escape as a thread traceback on stderr and
    end the capture 3 s later as "the board stopped sending". Now the board sends what it made and closes its port:
    the capture ends at once with the 100 samples made before the failure on disk, and says why: the board's error
    when the recorder made the board (--port virtual), a disconnect when it only has the board's pty."""
    escaped = []
    monkeypatch.setattr(threading, "excepthook", escaped.append)  # what would print a thread's traceback
    out, boards = tmp_path / "failed.csv", []

    def failing_board(**options):
        boards.append(C.VirtualBoard(**{**options, "rate_hz": RATE}, extra_lines=[fail_at(100)]))
        return boards[-1]

    monkeypatch.setitem(C.NAMED_PORTS, "virtual", ports_module.NamedPort("a failing virtual board", failing_board))
    if reached == "--port virtual":
        code, printed = run_cli(capsys, "virtual", out, "--fast", *(["--json"] if as_json else []))
        why, error_type = r"virtual board .* stopped on an error \(ZeroDivisionError: division by zero", "CaptureError"
    else:
        with failing_board(board="mpu6050", realtime=False) as vb:
            code, printed = run_cli(capsys, vb.port, out, *(["--json"] if as_json else []))
        why, error_type = "the board disconnected", "BoardDisconnectedError"
    assert code == 2 and escaped == [] and "Traceback" not in printed.err
    assert isinstance(boards[0].error, ZeroDivisionError) and len(load_recording(out)) == 100
    if as_json:
        (line,) = printed.out.splitlines()
        result = json.loads(line)
        assert result["error_type"] == error_type and result["samples"] == 100 and result["out"] == str(out.resolve())
        assert re.search(f"{why}.*every sample received .* is saved in", result["error"]), result["error"]
    else:
        assert re.search(f"capture failed: {why}", printed.err)
        assert printed.out.splitlines()[-1] == f"saved 100 samples to {out}"


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "human"])
def test_cli_capture_port_not_found_reports_too(tmp_path, capsys, as_json):
    out = tmp_path / "x.csv"
    code, printed = run_cli(capsys, "/dev/ttyNOPE", out, *(["--json"] if as_json else []))
    assert code == 2 and not out.exists()
    if as_json:
        result = json.loads(printed.out)
        assert result["error_type"] == "PortNotFoundError" and "/dev/ttyNOPE not found" in result["error"]
        assert (result["samples"], result["out"], result["board"], result["port"]) == (0, None, None, "/dev/ttyNOPE")
    else:
        assert "capture failed: port /dev/ttyNOPE not found" in printed.err
        assert printed.out == f"nothing saved: no samples arrived, {out} was not written\n"


def test_cli_protocol_that_the_board_cannot_record_reports_in_json(tmp_path, capsys):
    code, printed = run_cli(
        capsys, "virtual", tmp_path / "x.csv", "--protocol", "headings", "--board", "mpu6050", "--json"
    )
    result = json.loads(printed.out)
    assert code == 2 and result["error_type"] == "ValueError" and "no magnetometer" in result["error"]
