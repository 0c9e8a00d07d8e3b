"""kfkit.sensors: datasheet arithmetic (done here, independently), counts ↔ SI, boards."""

import dataclasses
import math

import numpy as np
import pytest

from kfkit import sensors
from kfkit.sensors import (
    BOARDS,
    MPU6050_GY521,
    NUCLEO_IKS02A1,
    board,
    counts_to_si,
    iis2mdc_mag,
    ism330dhcx_accel,
    ism330dhcx_gyro,
    mpu6050_accel,
    mpu6050_gyro,
)

g = 9.80665
deg = math.pi / 180

# (spec, SI per LSB worked out from the datasheet figure, full scale in SI)
DATASHEET = {
    "mpu_acc_2g": (mpu6050_accel(2), g / 16384, 2 * g),  # 16384 LSB/g
    "mpu_acc_16g": (mpu6050_accel(16), g / 2048, 16 * g),  # 2048 LSB/g
    "mpu_gyr_250": (mpu6050_gyro(250), deg / 131, 250 * deg),  # 131 LSB/(°/s)
    "mpu_gyr_2000": (mpu6050_gyro(2000), deg / 16.4, 2000 * deg),
    "ism_acc_4g": (ism330dhcx_accel(4), 0.122e-3 * g, 4 * g),  # 0.122 mg/LSB
    "ism_acc_2g": (ism330dhcx_accel(2), 0.061e-3 * g, 2 * g),
    "ism_gyr_500": (ism330dhcx_gyro(500), 17.5e-3 * deg, 500 * deg),  # 17.5 mdps/LSB
    "ism_gyr_2000": (ism330dhcx_gyro(2000), 70e-3 * deg, 2000 * deg),
    "iis2mdc": (iis2mdc_mag(), 0.15, 5000.0),  # 1.5 mgauss/LSB = 0.15 µT; ±50 G
}
SPECS = list(DATASHEET.values())
IDS = list(DATASHEET)


@pytest.mark.parametrize("spec, lsb, fs", SPECS, ids=IDS)
def test_sensitivity_and_full_scale_match_datasheet(spec, lsb, fs):
    assert spec.sensitivity == pytest.approx(lsb, rel=1e-12)
    assert spec.full_scale == pytest.approx(fs, rel=1e-12)


def test_noise_std_is_density_times_sqrt_rate():
    gyr = ism330dhcx_gyro(500)
    assert gyr.noise_std(104.0) == pytest.approx(5e-3 * deg * math.sqrt(104.0), rel=1e-12)  # 5 mdps/√Hz
    acc = mpu6050_accel(2)
    assert acc.noise_std(400.0) == pytest.approx(400e-6 * g * 20.0, rel=1e-12)  # 400 µg/√Hz
    assert acc.noise_std(4 * 400.0) == pytest.approx(2 * acc.noise_std(400.0), rel=1e-12)


def test_noise_std_uses_rms_when_no_density():
    mag = iis2mdc_mag()
    assert mag.noise_std(10.0) == mag.noise_std(100.0) == pytest.approx(0.3)  # 3 mgauss = 0.3 µT


@pytest.mark.parametrize("spec, lsb, fs", SPECS, ids=IDS)
def test_to_counts_round_trip_within_half_lsb(spec, lsb, fs):
    in_range = min(fs, 32767 * lsb)  # the IIS2MDC's ±50 gauss is beyond its int16 register
    x = np.random.default_rng(0).uniform(-0.99 * in_range, 0.99 * in_range, 2000)
    counts = spec.to_counts(x)
    assert np.issubdtype(counts.dtype, np.integer)
    assert np.max(np.abs(spec.to_si(counts) - x)) <= 0.5 * lsb * (1 + 1e-9)


def test_to_counts_rounds_to_nearest():
    spec = ism330dhcx_gyro(500)
    s = spec.sensitivity
    np.testing.assert_array_equal(
        spec.to_counts([0.4 * s, 0.6 * s, -0.4 * s, -0.6 * s, 7.3 * s, -7.7 * s]), [0, 1, 0, -1, 7, -8]
    )


@pytest.mark.parametrize("spec, lsb, fs", SPECS, ids=IDS)
def test_to_counts_saturates_at_full_scale_and_int16(spec, lsb, fs):
    steps = math.floor(fs / lsb + 1e-9)  # whole LSBs within full scale
    top, bottom = min(steps, 32767), max(-steps, -32768)
    np.testing.assert_array_equal(spec.to_counts([10 * fs, 1e9, -10 * fs, -1e9]), [top, top, bottom, bottom])
    assert spec.max_count == top


def test_to_counts_limits_of_an_int16_sensor():
    spec = mpu6050_accel(2)  # 2 g = 32768 LSB: the register, not the range, limits it
    np.testing.assert_array_equal(spec.to_counts([3 * g, -3 * g]), [32767, -32768])


def test_to_counts_limits_of_a_full_scale_sensor():
    spec = ism330dhcx_gyro(500)  # 500 dps / 17.5 mdps = 28571.4 LSB
    np.testing.assert_array_equal(spec.to_counts([20.0, -20.0]), [28571, -28571])
    assert spec.max_count == 28571


def test_to_si_and_counts_to_si():
    np.testing.assert_allclose(counts_to_si([2, -3], 0.5), [1.0, -1.5])
    assert mpu6050_accel(2).to_si(16384) == pytest.approx(g)
    assert mpu6050_gyro(250).to_si(131) == pytest.approx(deg)


@pytest.mark.parametrize(
    "spec, unit", [(ism330dhcx_accel(), "m/s^2"), (ism330dhcx_gyro(), "rad/s"), (iis2mdc_mag(), "uT")]
)
def test_metadata_carries_what_converts_counts_back(spec, unit):
    meta = spec.metadata()
    assert meta == {"chip": spec.chip, "full_scale": spec.full_scale, "sensitivity": spec.sensitivity, "unit": unit}


def is_rotation(M):
    M = np.asarray(M, float)
    return M.shape == (3, 3) and np.allclose(M @ M.T, np.eye(3)) and np.isclose(np.linalg.det(M), 1.0)


def test_nucleo_mag_mount_is_acc_mount_rotated_180_about_y():
    acc, mag = (np.asarray(NUCLEO_IKS02A1.mount[k]) for k in ("acc", "mag"))
    np.testing.assert_array_equal(mag, acc @ np.diag([-1.0, 1.0, -1.0]))
    assert is_rotation(acc) and is_rotation(mag)


@pytest.mark.parametrize("b", list(BOARDS.values()), ids=list(BOARDS))
def test_board_mounts_are_z_up_rotations(b):
    for key, M in b.mount.items():
        assert is_rotation(M), key
    # flat board: sensor reads +1 g on z, i.e. body z (down) = − sensor z
    for key in ("acc", "gyr"):
        np.testing.assert_array_equal(b.mount[key], np.diag([1.0, -1.0, -1.0]))


def test_board_lookup():
    assert board("nucleo-iks02a1") is NUCLEO_IKS02A1
    assert board("mpu6050") is MPU6050_GY521
    assert NUCLEO_IKS02A1.rate_hz in NUCLEO_IKS02A1.accel.odr_hz


def test_unknown_board_names_known_boards():
    with pytest.raises(ValueError, match="nope") as err:
        board("nope")
    for name in BOARDS:
        assert name in str(err.value)


def test_specs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        sensors.iis2mdc_mag().sensitivity = 1.0
