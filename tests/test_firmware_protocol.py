"""The firmware against kfkit: the line encoder (firmware/common/kfkit_protocol.h) compiled with gcc,
and both logger sketches built on the host with g++ against stand-ins declaring the real Arduino and
ST library APIs (tests/arduino_host.py), their output recorded by kfkit over a pseudo-terminal."""

import os
import re
import shutil
import subprocess
import time
import tty

import arduino_host
import numpy as np
import pytest

import kfkit.capture as C
from kfkit.sensors import board as get_board

FIRMWARE = arduino_host.FIRMWARE
PROGRAM = r"""
#include <stdio.h>
#include <string.h>
#include "kfkit_protocol.h"

/* stdin: "H board rate fields extra" | "S t_us seq n v1 … vn" | "M tag n x100_1 … x100_n" | "O" (overflow) */
int main(void) {
    char kind;
    kfkit_line line;
    while (scanf(" %c", &kind) == 1) {
        size_t n = 0;
        if (kind == 'H') {
            char board[32], rate[16], fields[96], extra[96];
            if (scanf("%31s %15s %95s %95s", board, rate, fields, extra) != 4) return 2;
            n = kfkit_header(&line, board, rate, fields, strcmp(extra, "-") ? extra : NULL);
        } else if (kind == 'S') {
            unsigned long t_us; unsigned seq; size_t count, i; long v; int32_t values[16];
            if (scanf("%lu %u %zu", &t_us, &seq, &count) != 3 || count > 16) return 2;
            for (i = 0; i < count; i++) { if (scanf("%ld", &v) != 1) return 2; values[i] = (int32_t)v; }
            n = kfkit_sample(&line, (uint32_t)t_us, (uint16_t)seq, values, count);
        } else if (kind == 'M') {
            char tag[8]; size_t count, i; long v;
            if (scanf("%7s %zu", tag, &count) != 2) return 2;
            kfkit_begin_sample(&line);
            kfkit_add_text(&line, tag);
            for (i = 0; i < count; i++) { if (scanf("%ld", &v) != 1) return 2; kfkit_add_fixed(&line, (int32_t)v, 2); }
            n = kfkit_end(&line);
        } else if (kind == 'O') {
            int32_t values[16];
            memset(values, 0x80, sizeof values); /* -2139062144: 11 characters each, too long for a line */
            n = kfkit_sample(&line, 4294967295u, 65535u, values, 16);
            printf("overflow length %zu\n", n);
            continue;
        }
        fwrite(line.text, 1, n, stdout);
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def encoder(tmp_path_factory):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed: the firmware encoder is not host-tested here")
    folder = tmp_path_factory.mktemp("firmware")
    (folder / "main.c").write_text(PROGRAM)
    exe = folder / "encoder"
    subprocess.run(
        [
            gcc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Wpedantic",
            "-Werror",
            "-I",
            str(FIRMWARE / "common"),
            str(folder / "main.c"),
            "-o",
            str(exe),
        ],
        check=True,
        capture_output=True,
        text=True,
    )

    def run(commands: str) -> list[bytes]:
        out = subprocess.run([str(exe)], input=commands.encode(), capture_output=True, check=True).stdout
        return out.splitlines(keepends=True)

    return run


def random_samples(count=300, seed=7):
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(count):
        n = int(rng.integers(0, 11))
        values = [int(v) for v in rng.integers(-(2**31), 2**31, n)]
        rows.append((int(rng.integers(0, 2**32)), int(rng.integers(0, 2**16)), values))
    rows.append((4294967295, 65535, [-(2**31), 2**31 - 1, 0, -1, 32767, -32768]))
    rows.append((0, 0, []))
    return rows


def test_headers_parse(encoder):
    lines = encoder(
        "H mpu6050 100 t_us|seq|ax|ay|az|gx|gy|gz accel_fs_g=2,gyro_fs_dps=250\n"
        "H nucleo-iks02a1 104 t_us|seq|ax|ay|az|gx|gy|gz|mx|my|mz|mag_new -\n"
    )
    first, second = (C.parse_line(line) for line in lines)
    assert (
        lines[0]
        == b"#KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250\n"
    )
    assert first.board == "mpu6050" and first.params["accel_fs_g"] == "2"
    assert second.fields[-1] == "mag_new" and second.rate_hz == 104.0


def test_samples_round_trip_and_match_the_python_encoder(encoder):
    rows = random_samples()
    commands = "".join(f"S {t} {s} {len(v)} {' '.join(map(str, v))}\n" for t, s, v in rows)
    lines = encoder(commands)
    assert len(lines) == len(rows)
    for line, (t, s, v) in zip(lines, rows):
        assert C.parse_line(line) == C.Sample((t, s, *v))
        assert line == C.encode_sample((t, s, *v))


def test_every_byte_flip_is_rejected(encoder):
    lines = encoder("".join(f"S {t} {s} {len(v)} {' '.join(map(str, v))}\n" for t, s, v in random_samples(40, seed=3)))
    for line in lines:
        body = line.rstrip(b"\n")  # the newline frames the line; every byte before it is checked
        for i in range(len(body)):
            for bit in range(8):
                flipped = body[:i] + bytes([body[i] ^ (1 << bit)]) + body[i + 1 :]
                if b"\n" in flipped:
                    continue  # a new line break splits the line in two: each part is rejected on its own
                assert isinstance(C.parse_line(flipped), C.BadLine), (line, i, bit)


def test_tagged_fixed_point_messages(encoder):
    (line,) = encoder("M ATT 3 1250 -325 -5\n")
    assert line == b"$ATT,12.50,-3.25,-0.05*%02X\n" % C.checksum(b"ATT,12.50,-3.25,-0.05")
    assert C.parse_line(line) == C.Message("ATT", (12.5, -3.25, -0.05))


def test_overflow_is_refused_not_truncated(encoder):
    assert encoder("O\n") == [b"overflow length 0\n"]


SKETCHES = {"mpu6050": "mpu6050_logger", "nucleo-iks02a1": "nucleo_iks02a1_logger"}


def sketch_header(folder: str) -> bytes:
    """The header a sketch sends, from its #define KFKIT_* lines (what kfkitSendHeader prints)."""
    text = (FIRMWARE / folder / f"{folder}.ino").read_text()
    macros = dict(re.findall(r'#define (KFKIT_\w+) "([^"]*)"', text))
    return "#KFKIT,1,board={KFKIT_BOARD},rate_hz={KFKIT_RATE_HZ},fields={KFKIT_FIELDS},{KFKIT_HEADER_EXTRA}\n".format(
        **macros
    ).encode()


@pytest.mark.parametrize("board", SKETCHES)
def test_sketch_headers_match_the_virtual_board(board):
    from kfkit.capture.virtual import board_header
    from kfkit.sensors import board as get_board

    b = get_board(board)
    assert sketch_header(SKETCHES[board]) == board_header(b, b.rate_hz)


@pytest.mark.parametrize("folder", SKETCHES.values())
def test_readme_example_lines_parse(folder):
    text = (FIRMWARE / folder / "README.md").read_text()
    lines = [line for line in text.splitlines() if line.startswith(("$", "#KFKIT"))]
    header = C.parse_line(lines[0].encode())
    assert isinstance(header, C.Header) and len(lines) >= 3
    for line in lines[1:]:
        sample = C.parse_line(line.encode())
        assert isinstance(sample, C.Sample) and len(sample.values) == len(header.fields), line


HOST_STREAM = r"""
#include <Arduino.h>
class StringStream : public Stream {  /* host-only: input from a string, as if typed by the host */
  public:
    explicit StringStream(const char *input) : next(input) {}
    int available() { return *next ? 1 : 0; }
    int read() { return *next ? *next++ : -1; }
    int peek() { return *next ? *next : -1; }
  private:
    const char *next;
};
"""
ARDUINO_PROGRAM = r"""
#define KFKIT_BOARD "nucleo-iks02a1"
#include <kfkit_protocol.h>
#include "host_stream.h"
int main() {
    StringStream serial("xh");  /* an unknown command, then 'h' */
    bool streaming = true;
    if (kfkitHandleCommands(serial, &streaming) || !streaming) return 3;
    const int32_t sample[8] = {(int32_t)4294967000u, 65535, -32768, 32767, 0, 1, -1, 2};
    kfkitSendSample(serial, sample, 8);
    const float attitude[2] = {12.345f, -0.004f};
    kfkitSendMessage(serial, "ATT", attitude, 2);
    StringStream stop("s");
    if (!kfkitHandleCommands(stop, &streaming) || streaming) return 4;
    return 0;
}
"""


def test_arduino_helpers_with_the_stand_in_core(tmp_path):
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed")
    (tmp_path / "Arduino.h").write_text(arduino_host.ARDUINO_H)
    (tmp_path / "host_stream.h").write_text(HOST_STREAM)
    (tmp_path / "main.cpp").write_text(ARDUINO_PROGRAM)
    exe = tmp_path / "arduino"
    subprocess.run(
        [
            gxx,
            "-std=c++11",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-DARDUINO=10819",
            "-I",
            str(tmp_path),
            "-I",
            str(FIRMWARE / "common"),
            str(tmp_path / "main.cpp"),
            "-o",
            str(exe),
        ],
        check=True,
    )
    header, sample, message = (
        C.parse_line(line) for line in subprocess.run([str(exe)], capture_output=True, check=True).stdout.splitlines()
    )
    assert header.board == "nucleo-iks02a1" and header.fields[2] == "ax"
    assert sample.values == (4294967000, 65535, -32768, 32767, 0, 1, -1, 2)  # t_us sent unsigned
    assert message == C.Message("ATT", (12.35, -0.0))


# --- the logger sketches, built on the host against the Arduino and ST API stand-ins -----------------------
def record_over_pty(stream: bytes, samples: int):
    """Play a sketch's output into a pseudo-terminal and record it with kfkit's Recorder, as from a board."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        rec = C.Recorder(os.ttyname(slave), no_data_s=5.0).start()
        try:
            os.write(master, stream)  # the recorder reads concurrently; a pty holds a few kB at a time
            deadline = time.monotonic() + 20
            while rec.stats.samples < samples and rec.error is None and time.monotonic() < deadline:
                time.sleep(0.02)
        finally:
            rec.stop()
    finally:
        os.close(master)
        os.close(slave)
    return rec


def motion_counts(board, seconds, seed):
    """Raw counts of the board tilting by hand (kfkit's simulator), one frame per sample, mag on every row."""
    from kfkit import motions, sim

    b = get_board(board)
    motion = motions.tilt_protocol(rate_hz=b.rate_hz, hold=seconds / 8, move=seconds / 8, seed=seed)
    rec = sim.simulate_imu(motion, board=b, seed=seed, mag_rate_hz=b.rate_hz)
    sensors = ("acc", "gyr", "mag") if b.mag is not None else ("acc", "gyr")
    return np.column_stack([rec.counts(s) for s in sensors]).astype(int)


def test_mpu6050_logger_configures_the_chip_and_streams_every_sample(tmp_path):
    sketch = FIRMWARE / "mpu6050_logger" / "mpu6050_logger.ino"
    exe = arduino_host.build_sketch(sketch, tmp_path)
    frames = motion_counts("mpu6050", 8.0, seed=11)
    start = 2**32 - 3_000_000  # micros() wraps 3 s into the run
    lines, config = arduino_host.run_sketch(exe, frames, "--start-us", start, "4000000:h")
    # MPU-6000/6050 register map (RM-MPU-6000A-00 rev 4.2): PWR_MGMT_1 clock = PLL x gyro, DLPF_CFG 3,
    # SMPLRT_DIV 9 (1 kHz / 10 = 100 Hz), GYRO_CONFIG FS_SEL 0 (±250 °/s), ACCEL_CONFIG AFS_SEL 0 (±2 g)
    for reg, value in ((0x6B, 0x01), (0x1A, 0x03), (0x19, 0x09), (0x1B, 0x00), (0x1C, 0x00)):
        assert f"MPU6050 write 0x{reg:02X} = 0x{value:02X}" in config
    assert "Serial.begin 115200" in config
    header = C.parse_line(lines[0])
    assert header.params["accel_fs_g"] == "2" and header.params["gyro_fs_dps"] == "250" and header.rate_hz == 100.0
    assert sum(isinstance(C.parse_line(line), C.Header) for line in lines) == 2  # at start, and on 'h'
    rec = record_over_pty(b"".join(lines), len(frames))
    s = rec.stats
    assert (s.samples, s.bad_lines, s.dropped, s.resets) == (len(frames), 0, 0, 0)
    r = rec.recording()
    np.testing.assert_array_equal(np.column_stack([r.counts("acc"), r.counts("gyr")]), frames)
    np.testing.assert_allclose(r.t, np.arange(len(frames)) * 0.01, atol=1e-9)  # 100 Hz across the wrap
    assert s.jitter_us == 0.0


def test_mpu6050_logger_builds_for_the_arduino_uno():
    """The real thing: avr-gcc with the Arduino AVR core and Wire library (Debian's arduino-core-avr),
    every warning an error, linked; it must fit the ATmega328P (32 KB flash less the 512 B bootloader, 2 KB RAM).
    It runs on an emulated Uno in tests/test_firmware_emulated_uno.py."""
    image = arduino_host.uno_image("mpu6050_logger")
    assert 0 < image.flash < 32_256 and 0 < image.ram < 1_500  # RAM: leave room for the stack


def test_mpu6050_logger_reports_a_missing_or_wrong_chip(tmp_path):
    exe = arduino_host.build_sketch(FIRMWARE / "mpu6050_logger" / "mpu6050_logger.ino", tmp_path)
    lines, _ = arduino_host.run_sketch(exe, [[0] * 6], "--who-am-i", "0x70", "--max-us", 2_500_000)
    notes = [C.parse_line(line) for line in lines]
    assert len(notes) == 3 and all(isinstance(n, C.Note) for n in notes)  # once a second
    assert "WHO_AM_I 0x70" in notes[0].text and notes[0].text.startswith("ERROR,")


def test_a_board_that_only_reports_its_missing_chip_is_not_taken_for_a_wrong_baud_rate(tmp_path):
    """What the sketch sends without its sensor ('#ERROR' notes, nothing else) reaches kfkit's capture as the board's
    own words: NoDataError quoting them (each once), not "wrong baud rate" (notes are protocol v1 lines)."""
    exe = arduino_host.build_sketch(FIRMWARE / "mpu6050_logger" / "mpu6050_logger.ino", tmp_path)
    lines, _ = arduino_host.run_sketch(exe, [[0] * 6], "--who-am-i", "0x70", "--max-us", 2_500_000)
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        rec = C.Recorder(os.ttyname(slave), out=tmp_path / "x.csv", no_data_s=1.0, garbage_s=1.0).start()
        os.write(master, b"".join(lines))
        assert rec.wait(30)  # it ends by itself
        rec.stop(raise_error=False)
    finally:
        os.close(master)
        os.close(slave)
    assert isinstance(rec.error, C.NoDataError) and rec.stats.samples == 0 and not (tmp_path / "x.csv").exists()
    message = str(rec.error)
    assert "only notes from the board" in message and message.count("WHO_AM_I 0x70") == 1


def test_mpu6050_logger_stop_and_start(tmp_path):
    exe = arduino_host.build_sketch(FIRMWARE / "mpu6050_logger" / "mpu6050_logger.ino", tmp_path)
    frames = np.zeros((50, 6), dtype=int)
    lines, _ = arduino_host.run_sketch(exe, frames, "100000:s", "300000:s")
    t_us = [item.t_us for item in map(C.parse_line, lines) if isinstance(item, C.Sample)]
    # the last sample before 's' at 100 ms is the one of 90 ms; the next 's' at 300 ms restarts the schedule there
    assert len(t_us) == 50 and t_us[9:11] == [90_000, 300_000] and set(np.diff(t_us[10:])) == {10_000}


def test_nucleo_logger_matches_its_header_and_streams_every_sample(tmp_path):
    sketch = FIRMWARE / "nucleo_iks02a1_logger" / "nucleo_iks02a1_logger.ino"
    exe = arduino_host.build_sketch(sketch, tmp_path)
    frames = motion_counts("nucleo-iks02a1", 8.0, seed=12)
    lines, config = arduino_host.run_sketch(exe, frames, "--start-us", 2**32 - 2_000_000)
    header = C.parse_line(lines[0])
    final = config.strip().splitlines()
    acc_gyr = next(line for line in reversed(final) if line.startswith("ISM330DHCX"))
    mag = next(line for line in reversed(final) if line.startswith("IIS2MDC"))
    # what the sketch set through ST's API is what its header tells kfkit
    assert "address=0xD7" in acc_gyr  # ISM330DHCX_I2C_ADD_H: SA0 high on the X-NUCLEO-IKS02A1
    assert (
        f"acc on=1 fs={header.params['accel_fs_g']} odr=104 gyro on=1 fs={header.params['gyro_fs_dps']} odr=104"
        in acc_gyr
    )
    assert mag == f"IIS2MDC on=1 odr={header.params['mag_rate_hz']}" and header.rate_hz == 104.0
    samples = [item for item in map(C.parse_line, lines) if isinstance(item, C.Sample)]
    t_us = np.array([s.t_us for s in samples], dtype=np.int64)
    steps = np.diff(t_us) % 2**32
    assert set(steps) == {9615, 9616} and (t_us[104] - t_us[0]) % 2**32 == 1_000_000  # exactly 104 Hz on average
    rec = record_over_pty(b"".join(lines), len(frames))
    s = rec.stats
    assert (s.samples, s.bad_lines, s.dropped, s.resets) == (len(frames), 0, 0, 0)
    r = rec.recording()
    np.testing.assert_array_equal(np.column_stack([r.counts("acc"), r.counts("gyr")]), frames[:, :6])
    fresh = np.isfinite(r["mx"])
    np.testing.assert_array_equal(r.counts("mag")[fresh], frames[fresh, 6:])  # a new reading is that sample's
    assert 0.45 < fresh.mean() < 0.52  # 50 Hz of 104 Hz lines
    np.testing.assert_allclose(r.t[-1], (len(frames) - 1) / 104.0, atol=1e-5)  # across the micros() wrap
