"""Hardware in the loop on an emulated Uno: the real mpu6050_logger and mpu6050_tilt_kf images.

Each sketch is built for the ATmega328P with avr-gcc and the Arduino AVR core (tests/arduino_host.uno_image) and run
in simavr with an emulated MPU6050 on the TWI bus (firmware/emulator/uno_mpu6050.c, through
kfkit.capture.emulated_uno.EmulatedUno) that plays a kit recording's counts at the rate the sketch configures; the
UART is a pseudo-terminal that ``kfkit capture`` records. The oracles: the emulator's own log of every burst the
sensor served (AVR cycle, frame, counts), the recording's counts, the AVR's cycle count for time (16 per µs, never
the wall clock: simavr runs faster or slower than real time, and waits while the pty is full), kfkit's Python
filter on the same counts with the settings read from the sketch's RAM, and the firmware README's promises for
sensor faults.

Needs Debian's gcc-avr, avr-libc, arduino-core-avr, simavr and libsimavr-dev (each test skips naming them; .ci/run
installs them). The Nucleo logger is not run here: no emulator on these machines models the STM32F411's I²C
peripheral with an ISM330DHCX and an IIS2MDC on it, so it is proven by its real build (test_firmware_stm32.py) and by
the protocol tests on the host (test_firmware_protocol.py), not by running.
"""

import json
import subprocess
import sys
import time
from dataclasses import dataclass

import arduino_host
import numpy as np
import pytest
import serial

from kfkit import datasets
from kfkit.capture import CaptureError, Recorder, Sample, parse_line
from kfkit.capture import emulated_uno as E
from kfkit.cli import main
from kfkit.filters import TiltAttitude, TiltBiasKF, TiltBiasKFSettings, tilt
from kfkit.io import Recording, load_recording
from kfkit.labs import lab05

RATE = 100.0  # what the sketches set: SMPLRT_DIV 9 with the DLPF on, 1 kHz / 10
CYCLES_PER_US = 16  # an Uno's 16 MHz crystal
#: firmware/tilt_kf's TiltKf as avr-gcc lays it out: nothing is aligned on the AVR, an enum is an int (2 bytes)
TILT_KF = np.dtype(
    [
        ("qAngle", "<f4"),
        ("qBias", "<f4"),
        ("r", "<f4"),
        ("gate", "<i2"),
        ("inflation", "<f4"),
        ("initialBiasVariance", "<f4"),
        ("samplePeriod", "<f4"),
        ("angle", "<f4"),
        ("bias", "<f4"),
        ("p00", "<f4"),
        ("p01", "<f4"),
        ("p11", "<f4"),
        ("innovation", "<f4"),
        ("innovationVariance", "<f4"),
        ("updated", "u1"),
    ]
)


@pytest.fixture(scope="module")
def toolchain():
    """Both images and the emulator, built once (kfkit's cache); skips naming the packages when one is missing."""
    images = {sketch: arduino_host.uno_image(sketch) for sketch in E.SKETCHES}
    try:
        E.emulator_program()
    except E.EmulatorUnavailable as e:
        pytest.skip(str(e))
    return images


@pytest.fixture(scope="module")
def recording():
    return datasets.load("05_tilt_protocol")


@pytest.fixture(scope="module")
def frames(recording):
    return E.recording_frames(recording)


@dataclass
class EmulatorLog:
    """The emulator's event log (firmware/emulator/README.md): reads (n, 8) = cycle, frame, ax ay az gx gy gz; the
    RAM it watched at each read (n, watches) bytes; register writes (cycle, register, value); rates; faults; NACKs."""

    reads: np.ndarray
    watched: list
    writes: list
    rates: list
    faults: list
    nacks: int


def read_log(path) -> EmulatorLog:
    reads, watched, writes, rates, faults, nacks = [], [], [], [], [], 0
    for line in path.read_text().splitlines():
        kind, *fields = line.split()
        if kind == "read":
            reads.append([int(v) for v in fields[:8]])
            watched.append([bytes.fromhex(h) for h in fields[8:]])
        elif kind == "write":
            writes.append((int(fields[0]), int(fields[1], 16), int(fields[2], 16)))
        elif kind == "rate":
            rates.append(float(fields[1]))
        elif kind == "fault":
            faults.append((int(fields[0]), fields[1]))
        nacks += kind == "nack"
    return EmulatorLog(np.array(reads, dtype=np.int64).reshape(-1, 8), watched, writes, rates, faults, nacks)


def counts(rec) -> np.ndarray:
    return np.column_stack([rec.counts("acc"), rec.counts("gyr")])


def capture_cli(port, seconds, out, timeout=300):
    """``kfkit capture --port <port> --seconds <seconds> --out <out> --json`` as a student runs it: (exit code,
    JSON)."""
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "kfkit",
            "capture",
            "--port",
            str(port),
            "--seconds",
            str(seconds),
            "--out",
            str(out),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return done.returncode, json.loads(done.stdout)


def assert_served_exactly(captured, served):
    """Every burst the emulated sensor served arrives, in order, with its counts and consecutive seq numbers."""
    np.testing.assert_array_equal(counts(captured), served[:, 2:])
    np.testing.assert_array_equal(captured["seq"], np.arange(len(served)))


def with_phases(captured, source, first_frame):
    """The capture with the phases of the recording it played (shifted to the frame its first sample read)."""
    shift, end = first_frame / RATE, captured.t[-1] + 1 / RATE
    phases = [
        {**p, "start": max(p["start"] - shift, 0.0), "end": min(p["end"] - shift, end)}
        for p in source.phases
        if p["end"] - shift > 0 and p["start"] - shift < end
    ]
    return Recording({**captured.meta, "phases": phases}, captured.data, captured.path)


def test_kfkit_capture_records_every_sample_the_emulated_sensor_produced(toolchain, frames, recording, tmp_path):
    """mpu6050_logger on the emulated Uno, recorded by ``kfkit capture --port <pty>``: 4 s of 05_tilt_protocol."""
    log, out = tmp_path / "emulator.log", tmp_path / "capture.csv"
    with E.EmulatedUno("mpu6050_logger", frames[:450], loop=False, log=log) as uno:
        code, stats = capture_cli(uno.port, 4.0, out)
    events = read_log(log)
    assert code == 0, stats["error"]
    n = 400  # samples at t = 0 … 3.99 s: the next one (t = 4 s) ends the capture
    assert (stats["samples"], stats["bad_lines"], stats["dropped"], stats["resets"], stats["notes"]) == (n, 0, 0, 0, [])
    captured = load_recording(out)
    served = events.reads[:n]
    assert_served_exactly(captured, served)
    # the sensor sampled the recording at its own rate, as the sketch configured it: one new frame per read, in order
    assert events.rates[-1] == RATE and [w[1:] for w in events.writes] == [
        (0x6B, 0x01),
        (0x1A, 0x03),
        (0x19, 0x09),
        (0x1B, 0x00),
        (0x1C, 0x00),
    ]
    first = int(served[0, 1])
    np.testing.assert_array_equal(served[:, 1], first + np.arange(n))
    np.testing.assert_array_equal(served[:, 2:], frames[first : first + n])
    # time is the board's: t_us steps of exactly 10 000 µs of the emulated clock, no jitter, the clock's rate 100 Hz;
    # and the AVR read each sample at its t on that clock (its cycle count, from the first read) to within 0.1 ms
    assert (stats["clock_rate_hz"], stats["dt_mean_us"], stats["jitter_us"]) == (RATE, 10000.0, 0.0)
    np.testing.assert_array_equal(np.round(captured.t * 1e6), np.arange(n) * 10000)
    read_us = (served[:, 0] - served[0, 0]) / CYCLES_PER_US
    assert np.max(np.abs(read_us - captured.t * 1e6)) < 100
    # the file runs through lab 05: its reference pipeline (the phases are the recording's) and filter hold the 0° hold
    tilt_rec = with_phases(captured, recording, first)
    _, still, faces = lab05.bundled()
    axes, dt, r, q0 = lab05.pipeline_inputs(tilt_rec, still, faces)
    w, z, ok, known = axes["pitch"]
    run = TiltBiasKF(dt, q_angle=q0, q_bias=lab05.Q_BIAS_RATIO * q0, r=r).run(w, z, ok)
    assert dt == 1 / RATE and np.isfinite(known).sum() >= 190  # the 2 s pitch_0 hold
    assert np.degrees(lab05.static_rmse(run.angle, known)) < 0.5


def wait_until(condition, what, timeout=120.0):
    """Poll ``condition`` until it holds (an event: how long it takes does not matter, the timeout only ends a hang)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def process_state(pid) -> str:
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0]


def test_a_reader_that_falls_behind_loses_nothing(toolchain, frames, tmp_path):
    """The emulator's choice: when the pty is full (≈ 20 KB unread) it waits, and the AVR with it (its clock is the
    cycle count), rather than drop bytes. The reader here reads nothing until the emulator sleeps in that wait (the
    only place it sleeps once running), then everything: every line arrives whole, on the board's unbroken clock."""
    log = tmp_path / "emulator.log"
    with (
        E.EmulatedUno("mpu6050_logger", frames, loop=False, log=log) as uno,
        serial.Serial(uno.port, 115200, timeout=0.2) as port,
    ):
        port.write(b"h")
        wait_until(lambda: port.in_waiting > 0, "the first bytes")
        wait_until(lambda: process_state(uno.process.pid) == "S", "the emulator to block on the full pty")
        received = b""
        while received.count(b"\n") < 600:
            received += port.read(4096)
    events = read_log(log)
    items = [parse_line(line) for line in received.splitlines()[:600]]
    samples = [item for item in items if isinstance(item, Sample)]
    assert len(samples) == len(items) - 1 > 550  # the header, then nothing but whole sample lines
    values = np.array([s.values for s in samples])
    np.testing.assert_array_equal(values[:, 1], np.arange(len(samples)))
    np.testing.assert_array_equal(np.diff(values[:, 0]), 10000)
    np.testing.assert_array_equal(values[:, 2:], events.reads[: len(samples), 2:])


@pytest.mark.slow
def test_the_tilt_sketch_filter_equals_python_over_a_whole_recording(toolchain, frames, recording, tmp_path):
    """mpu6050_tilt_kf on the emulated Uno over the whole 05_tilt_protocol (36 s, every gate): its two TiltKf
    states, read from the AVR's RAM before each sensor read, against kfkit's Python twin (TiltAttitude: TiltBiasKF
    per axis) on the very counts that arrived, with the settings read from that RAM (the sketch's tiltKfDefaultSettings,
    whatever they are now); its $ATT lines against those states. This holds the sketch's own integration: the scaling
    to g and rad/s, the sensor-to-body axes, the bias start, the gates, the 10 ms period, the serial format."""
    image, log = toolchain["mpu6050_tilt_kf"], tmp_path / "emulator.log"
    symbols = {name: arduino_host.avr_symbol(image.elf, name) for name in ("rollKf", "pitchKf")}
    assert {size for _, size in symbols.values()} == {TILT_KF.itemsize}  # 55 bytes: the layout above is the image's
    with E.EmulatedUno("mpu6050_tilt_kf", frames, loop=False, log=log, watch=list(symbols.values())) as uno:
        rec = Recorder(uno.port, seconds=(len(frames) - 2) / RATE)
        captured = rec.run()
    events = read_log(log)
    n = len(captured)
    assert (rec.stats.bad_lines, rec.stats.dropped, rec.stats.jitter_us, rec.clock_rate_hz()) == (0, 0, 0.0, RATE)
    assert_served_exactly(captured, events.reads[:n])
    # state j (after sample j) is what the RAM held before read j + 1
    roll, pitch = (np.frombuffer(b"".join(w[i] for w in events.watched[1 : n + 1]), TILT_KF) for i in (0, 1))
    s = roll[0]
    settings = TiltBiasKFSettings(
        q_angle=float(s["qAngle"]),
        q_bias=float(s["qBias"]),
        r=float(s["r"]),
        accel_gating=tilt.GATINGS[int(s["gate"])],
        accel_inflation=float(s["inflation"]),
    )
    assert all(np.array_equal(roll[f], pitch[f]) for f in TILT_KF.names[:7])  # both axes: one setting, unchanged
    assert s["samplePeriod"] == np.float32(1 / RATE)
    assert s["initialBiasVariance"] == np.float32(0.1**2)  # what TiltBiasKF.reset gives P11 (the Python twin's start)
    twin = TiltAttitude("mpu6050", rate_hz=rec.clock_rate_hz(), settings=settings)
    python = []
    for acc, gyr in zip(counts(captured)[:, :3], counts(captured)[:, 3:]):
        twin.step(acc, gyr)
        python.append([kf.state.x for kf in twin.kfs] if twin.gyro_bias is not None else np.full((2, 2), np.nan))
    python = np.array(python)  # (n, axis, [angle, bias])
    running = np.isfinite(python[:, 0, 0])
    assert running.sum() == n - 199  # the first 2 s measure the bias
    board = np.stack([np.column_stack([kf["angle"], kf["bias"]]) for kf in (roll, pitch)], axis=1)
    angle_error = np.abs(board[running, :, 0] - python[running, :, 0])
    bias_error = np.abs(board[running, :, 1] - python[running, :, 1])
    print(
        f"on-board filter vs Python over {running.sum()} samples: angle ≤ {angle_error.max():.2e} rad, "
        f"bias ≤ {bias_error.max():.2e} rad/s"
    )
    # float32 (avr-libc) against float64: with the shipped tuning (the gyro's own noise) 4.5e-6 rad and 9.5e-6 rad/s at
    # most, in the first seconds while the bias state's variance is still large; 1.1e-6 rad and 2.7e-7 rad/s from
    # 12 s on
    assert angle_error.max() < 1e-5 and bias_error.max() < 2e-5
    assert angle_error[1000:].max() < 2e-6 and bias_error[1000:].max() < 1e-6
    assert np.abs(python[running, 1, 0]).max() > 1.5  # the recording does reach 90°: not a test of zeros
    # the gates were exercised: updates and coasting on both axes
    assert {0, 1} <= set(roll["updated"][running]) and {0, 1} <= set(pitch["updated"][running])
    # the $ATT line after each sample prints those angles in degrees, two decimals
    att = rec.messages["ATT"]
    assert [index for index, _ in att] == list(np.flatnonzero(running) + 1)  # after sample j, before sample j + 1
    printed = np.array([values for _, values in att])
    assert np.max(np.abs(printed - np.degrees(board[running, :, 0]))) <= 0.005 + 1e-4


# --- sensor faults: what firmware/mpu6050_logger/README.md promises ---------------------------------------------


def test_a_missing_sensor_is_said_on_the_serial_line_and_reported_by_the_capture(toolchain, frames, tmp_path):
    """NACK from power-on: the sketch says '#ERROR,no MPU6050 answers at 0x68…' once a second and sends nothing else;
    ``kfkit capture`` fails with that message, saves no file."""
    log, out = tmp_path / "emulator.log", tmp_path / "capture.csv"
    with E.EmulatedUno("mpu6050_logger", frames[:100], loop=False, log=log, faults=["nack@0"]) as uno:
        code, stats = capture_cli(uno.port, 2.0, out)
    events = read_log(log)
    assert code == 2 and stats["error_type"] == "NoDataError" and stats["samples"] == 0 and not out.exists()
    assert "no MPU6050 answers at 0x68: check VCC, GND, SDA (A4), SCL (A5)" in stats["error"]
    assert stats["notes"] and all(note.startswith("ERROR,no MPU6050 answers at 0x68") for note in stats["notes"])
    assert events.nacks >= 1 and len(events.reads) == 0 and not events.writes


def record_with_fault(fault, frames, tmp_path):
    """2.5 s of mpu6050_logger on the emulated Uno with ``fault``: (the Recorder, its Recording, the emulator's log)."""
    log = tmp_path / "emulator.log"
    with E.EmulatedUno("mpu6050_logger", frames[:400], loop=False, log=log, faults=[fault]) as uno:
        rec = Recorder(uno.port, seconds=2.5)
        captured = rec.run()
    return rec, captured, read_log(log)


def test_a_stuck_bus_costs_the_samples_it_lasts_and_the_logger_carries_on(toolchain, frames, tmp_path):
    """The bus hangs for 0.3 s from 1 s: each transfer gives up after Wire's 25 ms timeout ('#ERROR,MPU6050 read
    failed'), the sketch skips the slots the stall passed, counting them in seq, and carries on when the bus is
    free; kfkit counts the missing slots as dropped and the clock stays exact."""
    rec, captured, events = record_with_fault("stuck@1+0.3", frames, tmp_path)
    s = rec.stats
    failures = len(s.notes)
    assert set(s.notes) == {"ERROR,MPU6050 read failed"} and 300 / 25 - 1 <= failures <= 300 / 25 + 1
    ((_, t_first, missing),) = s.drops  # one gap, starting at the slot the bus stuck in
    assert t_first == pytest.approx(1.0, abs=0.01) and 30 <= missing <= 32 and s.dropped == missing
    assert (s.bad_lines, s.resets, s.jitter_us, rec.clock_rate_hz()) == (0, 0, 0.0, RATE)
    assert s.samples + missing == 250 and captured.t[-1] == pytest.approx(2.49)  # and then to the end
    np.testing.assert_array_equal(np.round(captured.t * 1e6) % 10000, 0)  # the grid holds across the stall
    np.testing.assert_array_equal(counts(captured), events.reads[: s.samples, 2:])  # every sample served arrives
    stuck = (events.reads[:, 0] >= 16_000_000) & (events.reads[:, 0] < 20_800_000)
    assert not stuck.any()  # nothing was read while the bus hung


def test_a_sensor_reset_is_noticed_and_the_sensor_configured_again(toolchain, frames, tmp_path):
    """The MPU6050 resets at 1 s (its registers back to power-on: asleep, reading zeros): the next read sees
    PWR_MGMT_1 = 0x40, the sketch says '#ERROR,MPU6050 was reset…', configures it again and drops that one sample;
    no zero sample reaches the recording."""
    rec, captured, events = record_with_fault("reset@1", frames, tmp_path)
    s = rec.stats
    assert s.notes == ["ERROR,MPU6050 was reset (power glitch or loose VCC?): configured again"]
    ((_, t_first, missing),) = s.drops
    assert missing == 1 and t_first == pytest.approx(1.0, abs=0.011) and s.samples == 249
    ((reset_at, kind),) = events.faults
    assert kind == "reset" and reset_at == 16_000_000
    boot = [w[1:] for w in events.writes if w[0] < reset_at]
    assert [w[1:] for w in events.writes if w[0] > reset_at] == boot  # the same configuration again
    asleep = events.reads[:, 1] < 0
    assert asleep.sum() == 1 and not np.any(events.reads[asleep, 2:])  # one read of zeros, the one dropped
    np.testing.assert_array_equal(counts(captured), events.reads[~asleep][: s.samples, 2:])
    assert np.all(np.abs(counts(captured)[:, 2]) > 8000)  # az ≈ ±1 g throughout: no zero sample recorded
    assert (s.jitter_us, rec.clock_rate_hz()) == (0.0, RATE)


# --- kfkit capture --port emulated-uno: lab 00 without a board ----------------------------------------------------


def test_kfkit_capture_runs_the_emulated_uno_by_name(toolchain, frames, tmp_path):
    out = tmp_path / "emulated.csv"
    code, stats = capture_cli("emulated-uno", 2.0, out)
    assert code == 0, stats["error"]
    assert (stats["samples"], stats["board"], stats["dropped"], stats["clock_rate_hz"]) == (200, "mpu6050", 0, RATE)
    captured = load_recording(out)
    got = counts(captured)
    first = next(k for k in range(5) if np.array_equal(got, frames[k : k + 200]))  # the bundled tilt protocol, in order
    assert first <= 1 and captured.meta["source"] == E.EmulatedUno.source


def test_emulated_uno_without_its_packages_says_what_to_install(monkeypatch, tmp_path, capsys):
    """No toolchain needed: a missing piece is named with the command that installs it, and nothing is saved."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # nothing built yet
    with monkeypatch.context() as m:
        m.setattr(E, "SIMAVR_INCLUDE", tmp_path / "no-simavr")
        with pytest.raises(E.EmulatorUnavailable, match="apt-get install gcc simavr libsimavr-dev"):
            E.EmulatedUno().start()
    monkeypatch.setenv("KFKIT_ARDUINO_AVR", str(tmp_path / "no-core"))
    monkeypatch.setattr(E, "emulator_program", lambda: tmp_path / "uno_mpu6050")  # as if built: the AVR core is missing
    out = tmp_path / "x.csv"
    assert main(["capture", "--port", "emulated-uno", "--seconds", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "capture failed" in err and "apt-get install gcc-avr avr-libc arduino-core-avr" in err
    assert "KFKIT_ARDUINO_AVR" in err and not out.exists()


def test_emulated_uno_refuses_what_it_cannot_play(toolchain):
    with pytest.raises(ValueError, match="runs one of mpu6050_logger, mpu6050_tilt_kf"):
        E.EmulatedUno("nucleo_iks02a1_logger")
    with pytest.raises(ValueError, match=r"\(N, 6\) counts"):
        E.EmulatedUno(frames=np.zeros((10, 9), int))
    with pytest.raises(ValueError, match="int16"):
        E.EmulatedUno(frames=np.full((10, 6), 40000))
    with pytest.raises(ValueError, match="plays MPU6050 counts at the 100 Hz.*02_stationary.csv is nucleo-iks02a1"):
        E.EmulatedUno(frames=datasets.load("02_stationary"))
    with pytest.raises(CaptureError, match="the kinds are nack, stuck and reset"):
        E.EmulatedUno(faults=["wobble@1"]).start()
