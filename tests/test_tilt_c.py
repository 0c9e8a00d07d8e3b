"""firmware/tilt_kf (C99, float32) against the Python reference kfkit.filters.TiltBiasKF.

gcc compiles tilt_kf.c into a shared library, ctypes runs it on the bundled recording; the angles
must match the float64 reference within 1e-4 rad. Skipped when gcc is not installed.
"""
import ctypes
import shutil
import subprocess

import numpy as np
import pytest

from kfkit import datasets
from kfkit.datasets import KIT_ROOT
from kfkit.filters import TiltBiasKF, accel_static_ok, tilt
from kfkit.frames import G, accel_tilt

SOURCE = KIT_ROOT / "firmware" / "tilt_kf" / "tilt_kf.c"
TOLERANCE = tilt.DEFAULT_EPS / G  # static gate |‖f‖ − g|, in units of g (C); × G in m/s² (Python)
GATES = {"none": 0, "skip": 1, "inflate": 2}


class Settings(ctypes.Structure):
    _fields_ = [("qAngle", ctypes.c_float), ("qBias", ctypes.c_float), ("r", ctypes.c_float),
                ("gate", ctypes.c_int), ("inflation", ctypes.c_float), ("initialBiasVariance", ctypes.c_float)]


class TiltKf(ctypes.Structure):
    _fields_ = [("settings", Settings), ("samplePeriod", ctypes.c_float), ("angle", ctypes.c_float),
                ("bias", ctypes.c_float), ("p00", ctypes.c_float), ("p01", ctypes.c_float), ("p11", ctypes.c_float),
                ("innovation", ctypes.c_float), ("innovationVariance", ctypes.c_float), ("updated", ctypes.c_bool)]


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed: the C filter's host test needs it")
    out = tmp_path_factory.mktemp("tilt_kf") / "libtilt_kf.so"
    subprocess.run([gcc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-shared", "-fPIC",
                    str(SOURCE), "-o", str(out), "-lm"], check=True, capture_output=True, text=True)
    lib = ctypes.CDLL(str(out))
    f, p = ctypes.c_float, ctypes.POINTER(TiltKf)
    lib.TiltKfInitialise.argtypes = [p, f, ctypes.POINTER(Settings)]
    lib.TiltKfReset.argtypes = [p, f, f]
    lib.TiltKfUpdate.argtypes = [p, f, f, ctypes.c_bool]
    for name in ("TiltKfAccelerometerRoll", "TiltKfAccelerometerPitch"):
        getattr(lib, name).argtypes, getattr(lib, name).restype = [f, f, f], f
    lib.TiltKfAccelerometerStatic.argtypes, lib.TiltKfAccelerometerStatic.restype = [f, f, f, f], ctypes.c_bool
    return lib


def default_settings(lib):
    """A writable copy of the C defaults (the original is const, in read-only memory)."""
    return Settings.from_buffer_copy(Settings.in_dll(lib, "tiltKfDefaultSettings"))


def run_c(lib, settings, dt, gyro, accel_angle, static_ok):
    kf = TiltKf()
    lib.TiltKfInitialise(ctypes.byref(kf), dt, ctypes.byref(settings))
    lib.TiltKfReset(ctypes.byref(kf), float(accel_angle[0]), 0.0)
    out = np.empty((len(gyro), 2))
    for k, (w, z, ok) in enumerate(zip(gyro.tolist(), accel_angle.tolist(), static_ok.tolist())):
        lib.TiltKfUpdate(ctypes.byref(kf), w, z, ok)
        out[k] = kf.angle, kf.bias
    return out


@pytest.fixture(scope="module")
def recording():
    rec = datasets.load("05_tilt_protocol")
    acc, gyr = rec.body("acc"), rec.body("gyr")
    roll, pitch = accel_tilt(acc)
    return {"dt": 1.0 / rec.rate_hz, "acc": acc, "ok": accel_static_ok(acc, TOLERANCE * G),
            "roll": (gyr[:, 0], roll), "pitch": (gyr[:, 1], pitch)}


@pytest.mark.parametrize("gate", ["skip", "inflate", "none"])
@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_c_filter_matches_python_on_the_bundled_recording(lib, recording, axis, gate):
    settings = default_settings(lib)
    settings.gate = GATES[gate]
    gyro, angle = recording[axis]
    python = TiltBiasKF(recording["dt"], settings.qAngle, settings.qBias, settings.r, gate=gate,
                        inflation=settings.inflation).run(
        gyro, angle, recording["ok"], P0=np.diag([settings.r, settings.initialBiasVariance]))
    c = run_c(lib, settings, recording["dt"], gyro, angle, recording["ok"])
    assert np.max(np.abs(c[:, 0] - python.angle)) < 1e-4
    assert np.max(np.abs(c[:, 1] - python.bias)) < 1e-5
    assert np.max(np.abs(python.angle)) > 1.5  # the record does reach 90°: not a test of zeros


def test_c_accelerometer_tilt_and_gate_match_python(lib, recording):
    f_g = (recording["acc"] / G).astype(np.float32)
    roll, pitch = accel_tilt(f_g.astype(float))
    c_roll = np.array([lib.TiltKfAccelerometerRoll(*row) for row in f_g.tolist()])
    c_pitch = np.array([lib.TiltKfAccelerometerPitch(*row) for row in f_g.tolist()])
    assert np.max(np.abs(c_roll - roll)) < 1e-5 and np.max(np.abs(c_pitch - pitch)) < 1e-5
    c_ok = np.array([lib.TiltKfAccelerometerStatic(*row, TOLERANCE) for row in f_g.tolist()])
    norm_error = np.abs(np.linalg.norm(f_g.astype(float), axis=1) - 1.0)
    clear = np.abs(norm_error - TOLERANCE) > 1e-6  # float32 may round either way right at the threshold
    assert np.array_equal(c_ok[clear], norm_error[clear] < TOLERANCE)
    assert 0.2 < c_ok.mean() < 0.95  # the turns are gated, the holds are not


def test_c_defaults_are_the_python_defaults(lib):
    s = default_settings(lib)
    got = [s.qAngle, s.qBias, s.r, s.inflation, s.initialBiasVariance]
    np.testing.assert_allclose(got, [tilt.DEFAULT_Q_ANGLE, tilt.DEFAULT_Q_BIAS, tilt.DEFAULT_R, 100.0, 0.1 ** 2], rtol=1e-6)
    assert s.gate == GATES["skip"]


def test_c_filter_skips_a_nan_accel_angle(lib):
    settings = default_settings(lib)
    kf = TiltKf()
    lib.TiltKfInitialise(ctypes.byref(kf), 0.01, ctypes.byref(settings))
    lib.TiltKfUpdate(ctypes.byref(kf), 1.0, float("nan"), True)
    assert kf.angle == pytest.approx(0.01) and not kf.updated


# --- the Arduino sketch itself, on the host -------------------------------------------------------------
# The .ino cannot be built for AVR here; it is compiled with g++ against minimal stand-ins for Arduino.h
# and Wire.h that play the bundled recording's counts as MPU6050 registers and collect what Serial sends.

ARDUINO_STUB = r"""
#pragma once
#include <stdint.h>
#include <stddef.h>
#include <math.h>
#include <stdio.h>
#define F(x) (x)
struct Print {
    size_t write(const uint8_t *data, size_t n) { return fwrite(data, 1, n, stdout); }
};
struct Stream : Print {  /* no host input: the sketch streams from the start */
    int available() { return 0; }
    int read() { return -1; }
};
struct HardwareSerial : Stream {
    void begin(unsigned long) {}
    void println(const char *text) { printf("%s\n", text); }
};
extern HardwareSerial Serial;
unsigned long micros();
void delay(unsigned long);
"""

WIRE_STUB = r"""
#pragma once
#include <stdint.h>
struct TwoWire {
    void begin() {}
    void setClock(long) {}
    void beginTransmission(uint8_t) { expectRegister = 1; }
    size_t write(uint8_t value) { if (expectRegister) { reg = value; expectRegister = 0; } return 1; }
    uint8_t endTransmission(bool = true) { return 0; }
    uint8_t requestFrom(uint8_t, uint8_t count);
    int read();
    uint8_t reg = 0, expectRegister = 0, buffer[14] = {0}, position = 0;
};
extern TwoWire Wire;
"""

HOST_MAIN = r"""
#include "Arduino.h"
#include "Wire.h"
#include <stdlib.h>
HardwareSerial Serial;
TwoWire Wire;
static unsigned long now = 0;
unsigned long micros() { return now; }
void delay(unsigned long ms) { now += 1000ul * ms; }
static int16_t frames[20000][7];
static long frameCount = 0, next = 0;
uint8_t TwoWire::requestFrom(uint8_t, uint8_t count) {
    position = 0;
    if (reg == 0x75) { buffer[0] = 0x68; return count; }
    if (reg == 0x3B && next < frameCount) {
        for (int i = 0; i < 7; i++) { buffer[2 * i] = (uint8_t)((uint16_t)frames[next][i] >> 8); buffer[2 * i + 1] = (uint8_t)(frames[next][i] & 0xFF); }
        next++;
        return count;
    }
    return 0;
}
int TwoWire::read() { return buffer[position++]; }
void setup();
void loop();
int main() {
    int ax, ay, az, gx, gy, gz;
    while (frameCount < 20000 && scanf("%d %d %d %d %d %d", &ax, &ay, &az, &gx, &gy, &gz) == 6) {
        int16_t row[7] = {(int16_t)ax, (int16_t)ay, (int16_t)az, 0, (int16_t)gx, (int16_t)gy, (int16_t)gz};
        for (int i = 0; i < 7; i++) frames[frameCount][i] = row[i];
        frameCount++;
    }
    setup();
    while (next < frameCount) { loop(); now += 500; }  /* 20 loop() calls per 10 ms sample period */
    return 0;
}
"""


@pytest.fixture(scope="module")
def sketch_output(tmp_path_factory):
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed: the sketch's host run needs it")
    work = tmp_path_factory.mktemp("sketch")
    (work / "Arduino.h").write_text(ARDUINO_STUB)
    (work / "Wire.h").write_text(WIRE_STUB)
    (work / "host_main.cpp").write_text(HOST_MAIN)
    sketch = KIT_ROOT / "firmware" / "mpu6050_tilt_kf" / "mpu6050_tilt_kf.ino"
    exe = work / "sketch"
    subprocess.run([gxx, "-std=c++11", "-O1", "-Wall", "-DARDUINO=10819", f"-I{work}",
                    f"-I{KIT_ROOT / 'firmware' / 'common'}", f"-I{KIT_ROOT / 'firmware' / 'tilt_kf'}",
                    "-x", "c++", str(sketch), "-x", "c++", str(work / "host_main.cpp"), "-x", "c", str(SOURCE),
                    "-o", str(exe), "-lm"], check=True, capture_output=True, text=True)
    rec = datasets.load("05_tilt_protocol")
    counts = np.column_stack([rec.counts("acc"), rec.counts("gyr")]).astype(int)
    feed = "\n".join(" ".join(map(str, row)) for row in counts.tolist()) + "\n"
    run = subprocess.run([str(exe)], input=feed, capture_output=True, text=True, check=True, timeout=60)
    return rec, counts, run.stdout.encode().splitlines(keepends=True)


def test_sketch_streams_valid_protocol_lines(sketch_output):
    from kfkit.capture import Header, Message, Note, Sample, parse_line

    rec, counts, lines = sketch_output
    items = [parse_line(line) for line in lines]
    assert isinstance(items[0], Header) and items[0].board == "mpu6050" and items[0].rate_hz == 100.0
    assert items[0].params["messages"] == "ATT"
    assert isinstance(items[1], Note) and "keep the board still" in items[1].text
    samples = [i for i in items if isinstance(i, Sample)]
    assert [s.values[2:] for s in samples] == [tuple(row) for row in counts.tolist()]  # every raw sample, in order
    assert np.all(np.diff([s.t_us for s in samples]) == 10000)  # the micros() schedule: exactly 100 Hz
    assert sum(isinstance(i, Message) for i in items) == len(rec) - 199  # none during the 2 s bias start


def test_sketch_attitude_matches_the_python_twin(sketch_output):
    from kfkit.capture import Message, parse_line
    from kfkit.filters import TiltAttitude

    rec, counts, lines = sketch_output
    att = np.array([i.values for i in map(parse_line, lines) if isinstance(i, Message) and i.tag == "ATT"])
    twin = TiltAttitude("mpu6050", 100.0)
    python = [twin.update(row[:3], row[3:]) for row in counts]
    expected = np.degrees(np.array([p for p in python if p is not None]))
    assert att.shape == expected.shape
    # the sketch prints two decimals; float32 vs float64 adds < 1e-4°
    assert np.max(np.abs(att - expected)) <= 0.0051
