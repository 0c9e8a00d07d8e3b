"""firmware/tilt_kf (C99, float32) against the Python reference kfkit.filters.TiltBiasKF.

gcc compiles tilt_kf.c into a shared library, ctypes runs it on the whole bundled recording; the angles
must match the float64 reference within 1e-4 rad. The sketch runs on the host against Arduino stand-ins,
and is compiled for an Uno with avr-gcc and the Arduino AVR core. Each part skips without its compiler.
"""

import ctypes
import shutil
import subprocess

import arduino_host
import numpy as np
import pytest

from kfkit import datasets
from kfkit.capture.emulated_uno import UNO_FLASH, UNO_RAM
from kfkit.filters import TiltBiasKF, accel_static_ok, tilt
from kfkit.frames import G, accel_tilt
from kfkit.paths import KIT_ROOT

SOURCE = KIT_ROOT / "firmware" / "tilt_kf" / "tilt_kf.c"
TOLERANCE = tilt.DEFAULT_EPS / G  # static gate |‖f‖ − g|, in units of g (C); × G in m/s² (Python)
GATES = {"none": 0, "skip": 1, "inflate": 2}


class Settings(ctypes.Structure):
    _fields_ = [
        ("qAngle", ctypes.c_float),
        ("qBias", ctypes.c_float),
        ("r", ctypes.c_float),
        ("gate", ctypes.c_int),
        ("inflation", ctypes.c_float),
        ("initialBiasVariance", ctypes.c_float),
    ]


class TiltKf(ctypes.Structure):
    _fields_ = [
        ("settings", Settings),
        ("samplePeriod", ctypes.c_float),
        ("angle", ctypes.c_float),
        ("bias", ctypes.c_float),
        ("p00", ctypes.c_float),
        ("p01", ctypes.c_float),
        ("p11", ctypes.c_float),
        ("innovation", ctypes.c_float),
        ("innovationVariance", ctypes.c_float),
        ("updated", ctypes.c_bool),
    ]


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed: the C filter's host test needs it")
    out = tmp_path_factory.mktemp("tilt_kf") / "libtilt_kf.so"
    subprocess.run(
        [
            gcc,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-Wpedantic",
            "-Werror",
            "-shared",
            "-fPIC",
            str(SOURCE),
            "-o",
            str(out),
            "-lm",
        ],
        check=True,
        capture_output=True,
        text=True,
    )
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
    return {
        "dt": 1.0 / rec.rate_hz,
        "acc": acc,
        "ok": accel_static_ok(acc, TOLERANCE * G),
        "roll": (gyr[:, 0], roll),
        "pitch": (gyr[:, 1], pitch),
    }


@pytest.mark.parametrize("gate", ["skip", "inflate", "none"])
@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_c_filter_matches_python_on_the_bundled_recording(lib, recording, axis, gate):
    settings = default_settings(lib)
    settings.gate = GATES[gate]
    gyro, angle = recording[axis]
    python = TiltBiasKF(
        recording["dt"],
        q_angle=settings.qAngle,
        q_bias=settings.qBias,
        r=settings.r,
        accel_gating=gate,
        accel_inflation=settings.inflation,
        P0=np.diag([settings.r, settings.initialBiasVariance]),
    ).run(gyro, angle, recording["ok"])
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
    d = tilt.TiltBiasKFSettings()
    np.testing.assert_allclose(got, [d.q_angle, d.q_bias, d.r, d.accel_inflation, 0.1**2], rtol=1e-6)
    assert s.gate == GATES[d.accel_gating]


def test_c_filter_skips_a_nan_accel_angle(lib):
    settings = default_settings(lib)
    kf = TiltKf()
    lib.TiltKfInitialise(ctypes.byref(kf), 0.01, ctypes.byref(settings))
    lib.TiltKfUpdate(ctypes.byref(kf), 1.0, float("nan"), True)
    assert kf.angle == pytest.approx(0.01) and not kf.updated


# --- the Arduino sketch itself, on the host -------------------------------------------------------------
# The .ino compiled with g++ against the kit's Arduino/Wire stand-ins (tests/arduino_host.py), which play the
# bundled recording's counts as MPU6050 registers and collect what Serial sends.

SKETCH = KIT_ROOT / "firmware" / "mpu6050_tilt_kf" / "mpu6050_tilt_kf.ino"


@pytest.fixture(scope="module")
def sketch_exe(tmp_path_factory):
    return arduino_host.build_sketch(
        SKETCH, tmp_path_factory.mktemp("sketch"), include=[SOURCE.parent], sources=[SOURCE]
    )


@pytest.fixture(scope="module")
def sketch_output(sketch_exe):
    rec = datasets.load("05_tilt_protocol")
    counts = np.column_stack([rec.counts("acc"), rec.counts("gyr")]).astype(int)
    lines, _ = arduino_host.run_sketch(sketch_exe, counts, "--max-us", int(rec.t[-1] * 1e6) + 5_000_000)
    return rec, counts, lines


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
    python = [twin.step(row[:3], row[3:]) for row in counts]
    expected = np.degrees(np.array([p for p in python if p is not None]))
    assert att.shape == expected.shape
    # the sketch prints two decimals; float32 vs float64 adds < 1e-3° (in the first seconds, while the bias state's
    # variance is still large: 3.5e-4° measured with the shipped tuning)
    assert np.max(np.abs(att - expected)) <= 0.006


def test_sketch_measures_the_bias_again_after_a_stop_and_start(sketch_exe):
    """'s' stops the stream; the board may move meanwhile, so 's' again restarts the 2 s bias measurement."""
    from kfkit.capture import Message, Note, Sample, parse_line

    counts = np.column_stack([datasets.load("05_stationary").counts(k) for k in ("acc", "gyr")]).astype(int)
    lines, _ = arduino_host.run_sketch(sketch_exe, counts, "4000000:s", "4500000:s")
    items = [parse_line(line) for line in lines]
    notes = [i for i, item in enumerate(items) if isinstance(item, Note) and "keep the board still" in item.text]
    assert len(notes) == 2  # at start, and again after the restart
    after = items[notes[1] + 1 :]
    first_att = next(i for i, item in enumerate(after) if isinstance(item, Message))
    assert sum(isinstance(item, Sample) for item in after[:first_att]) == 200  # 2 s of samples, no $ATT
    t_us = [item.t_us for item in items if isinstance(item, Sample)]
    assert max(np.diff(t_us)) >= 500000  # the pause shows as a gap in the board's clock, not as lost samples


def test_sketch_without_an_mpu6050_says_so_and_sends_no_samples(sketch_exe):
    lines, _ = arduino_host.run_sketch(sketch_exe, [[0] * 6], "--who-am-i", "0x70", "--max-us", 3_000_000)
    assert sum(b"#ERROR,the chip at 0x68 has WHO_AM_I 0x70" in line for line in lines) >= 3  # once a second for 3 s
    assert not any(line.startswith((b"$", b"#KFKIT")) for line in lines)


def test_virtual_board_speaks_like_the_sketch(sketch_output):
    """What `kfkit demo tilt --port virtual` reads stands in for the board: the same header, and $ATT lines
    on the same schedule (none during the 2 s bias start, then one after every sample; the virtual side of
    it is tests/test_tilt_demo.py::test_virtual_board_emits_att_lines_that_track_the_truth)."""
    from kfkit.capture import Message, Sample, VirtualBoard, parse_line

    _, _, lines = sketch_output
    assert VirtualBoard(board="mpu6050", attitude=True).header == lines[0]
    kinds = [type(parse_line(line)) for line in lines[2:]]  # after the header and the #NOTE
    assert kinds[:200] == [Sample] * 200 and kinds[200:204] == [Message, Sample, Message, Sample]


# --- the sketch for the real board: avr-gcc and the Arduino AVR core ---------------------------------------
# Debian's gcc-avr, avr-libc and arduino-core-avr (the core and Wire that arduino-cli's arduino:avr installs), built
# by kfkit (tests/arduino_host.uno_image); the image runs on an emulated Uno in tests/test_firmware_emulated_uno.py.


@pytest.mark.slow
def test_sketch_compiles_for_an_uno_and_fits():
    image = arduino_host.uno_image("mpu6050_tilt_kf")
    assert image.flash < UNO_FLASH / 2  # ≈ 13 KB of 31.5 KB
    assert image.ram < UNO_RAM / 2  # static RAM ≈ 0.7 KB of 2 KB: the rest is stack (no allocation)
