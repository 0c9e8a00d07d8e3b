"""The firmware's line encoder (firmware/common/kfkit_protocol.h), compiled with gcc, against kfkit's parser."""
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import kfkit.capture as C

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"
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
    subprocess.run([gcc, "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-I", str(FIRMWARE / "common"),
                    str(folder / "main.c"), "-o", str(exe)], check=True, capture_output=True, text=True)

    def run(commands: str) -> list[bytes]:
        out = subprocess.run([str(exe)], input=commands.encode(), capture_output=True, check=True).stdout
        return out.splitlines(keepends=True)
    return run


def random_samples(count=300, seed=7):
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(count):
        n = int(rng.integers(0, 11))
        values = [int(v) for v in rng.integers(-2**31, 2**31, n)]
        rows.append((int(rng.integers(0, 2**32)), int(rng.integers(0, 2**16)), values))
    rows.append((4294967295, 65535, [-2**31, 2**31 - 1, 0, -1, 32767, -32768]))
    rows.append((0, 0, []))
    return rows


def test_headers_parse(encoder):
    lines = encoder("H mpu6050 100 t_us|seq|ax|ay|az|gx|gy|gz accel_fs_g=2,gyro_fs_dps=250\n"
                    "H nucleo-iks02a1 104 t_us|seq|ax|ay|az|gx|gy|gz|mx|my|mz|mag_new -\n")
    first, second = (C.parse_line(line) for line in lines)
    assert lines[0] == b"#KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250\n"
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
                flipped = body[:i] + bytes([body[i] ^ (1 << bit)]) + body[i + 1:]
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
    return ("#KFKIT,1,board={KFKIT_BOARD},rate_hz={KFKIT_RATE_HZ},fields={KFKIT_FIELDS},{KFKIT_HEADER_EXTRA}\n"
            .format(**macros).encode())


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


ARDUINO_STUB = r"""
#include <stdint.h>
#include <stdio.h>
#include <math.h>
class Print {
  public:
    size_t write(const uint8_t *buffer, size_t size) { return fwrite(buffer, 1, size, stdout); }
};
class Stream : public Print {  // input from a string, as if typed by the host
  public:
    explicit Stream(const char *input) : next(input) {}
    int available() { return *next ? 1 : 0; }
    int read() { return *next ? *next++ : -1; }
  private:
    const char *next;
};
"""
ARDUINO_PROGRAM = r"""
#define KFKIT_BOARD "nucleo-iks02a1"
#include <kfkit_protocol.h>
int main() {
    Stream serial("xh");  /* an unknown command, then 'h' */
    bool streaming = true;
    if (kfkitHandleCommands(serial, &streaming) || !streaming) return 3;
    const int32_t sample[8] = {(int32_t)4294967000u, 65535, -32768, 32767, 0, 1, -1, 2};
    kfkitSendSample(serial, sample, 8);
    const float attitude[2] = {12.345f, -0.004f};
    kfkitSendMessage(serial, "ATT", attitude, 2);
    Stream stop("s");
    if (!kfkitHandleCommands(stop, &streaming) || streaming) return 4;
    return 0;
}
"""


def test_arduino_helpers_with_a_stub_print(tmp_path):
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed")
    (tmp_path / "Arduino.h").write_text(ARDUINO_STUB)
    (tmp_path / "main.cpp").write_text(ARDUINO_PROGRAM)
    exe = tmp_path / "arduino"
    subprocess.run([gxx, "-std=c++11", "-Wall", "-Wextra", "-Werror", "-DARDUINO=10819", "-I", str(tmp_path),
                    "-I", str(FIRMWARE / "common"), str(tmp_path / "main.cpp"), "-o", str(exe)], check=True)
    header, sample, message = (C.parse_line(line) for line in subprocess.run([str(exe)], capture_output=True,
                                                                             check=True).stdout.splitlines())
    assert header.board == "nucleo-iks02a1" and header.fields[2] == "ax"
    assert sample.values == (4294967000, 65535, -32768, 32767, 0, 1, -1, 2)  # t_us sent unsigned
    assert message == C.Message("ATT", (12.35, -0.0))
