"""Sensor specifications and the counts ↔ SI conversion.

Each figure cites its datasheet. Units inside the kit are SI: m/s², rad/s, µT.
Noise densities N (unit/√Hz) are treated as the density of continuous white noise sampled
at ``rate_hz``, giving a per-sample standard deviation

    σ = N · √rate_hz

the convention in which the Allan deviation reads N back at τ = 1 s. (Reading N as a one-sided
density band-limited at Nyquist would give N·√(rate_hz/2), √2 smaller.)

Boards bundle sensors with their mounting matrices M_bs (body ← sensor); see :data:`BOARDS`, and
:func:`phone_board` for a phone (its frame, mountings and fixed-point counts are described there).
The sensor vocabulary is :data:`SENSORS` ("acc", "gyr", "mag") with their :data:`SI_UNITS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frames import MOUNT_Z_UP, G, mount_matrix

DEG = np.pi / 180.0
MG = 1e-3 * G  # one milli-g in m/s²
GAUSS = 100.0  # µT per gauss

#: The kit's sensor vocabulary: a recording's sensors, and the SI unit each is in once converted.
SENSORS = ("acc", "gyr", "mag")
SI_UNITS = {"acc": "m/s^2", "gyr": "rad/s", "mag": "uT"}
INT16_MIN, INT16_MAX = -32768, 32767


@dataclass(frozen=True)
class SensorSpec:
    """One sensor axis set at one full-scale setting.

    full_scale     measuring range ± in SI units (m/s², rad/s or µT)
    sensitivity    SI units per LSB (one count)
    noise_density  white-noise density, SI/√Hz (None where the datasheet gives an RMS figure)
    noise_rms      per-sample RMS noise, SI (used when ``noise_density`` is None)
    bias_typical   typical zero-level offset, SI (the datasheet's "typ." figure)
    odr_hz         output data rates the chip offers, Hz
    """

    chip: str
    kind: str  # "accel", "gyro" or "mag"
    full_scale: float
    sensitivity: float
    noise_density: float | None
    noise_rms: float | None
    bias_typical: float
    odr_hz: tuple[float, ...]

    def noise_std(self, rate_hz: float) -> float:
        """Per-sample white-noise standard deviation (SI) at ``rate_hz``: σ = N·√rate_hz."""
        if self.noise_density is not None:
            return self.noise_density * np.sqrt(rate_hz)
        return float(self.noise_rms)

    @property
    def max_count(self) -> int:
        """Largest count the output reaches (saturation), limited by the int16 register."""
        return int(min(INT16_MAX, np.floor(self.full_scale / self.sensitivity)))

    @property
    def min_count(self) -> int:
        """Most negative count the output reaches: −full scale, or the int16 limit."""
        return int(max(INT16_MIN, -np.floor(self.full_scale / self.sensitivity)))

    def to_si(self, counts):
        """Counts → SI: x = counts · sensitivity."""
        return counts_to_si(counts, self.sensitivity)

    def to_counts(self, x):
        """SI → counts: round to the nearest LSB and saturate at full scale."""
        counts = np.rint(np.asarray(x, dtype=float) / self.sensitivity)
        return np.clip(counts, self.min_count, self.max_count).astype(np.int64)

    def metadata(self) -> dict:
        """What a recording stores so that its counts can be converted back."""
        unit = {"accel": "m/s^2", "gyro": "rad/s", "mag": "uT"}[self.kind]
        return {"chip": self.chip, "full_scale": self.full_scale, "sensitivity": self.sensitivity, "unit": unit}


def counts_to_si(counts, sensitivity):
    """x = counts · sensitivity, with ``sensitivity`` in SI units per LSB."""
    return np.asarray(counts, dtype=float) * sensitivity


# --- ST ISM330DHCX (DS13012 Rev 7, Table 3 "Mechanical characteristics") -----------------
# Linear acceleration sensitivity: 0.061 / 0.122 / 0.244 / 0.488 mg/LSB at ±2/4/8/16 g.
_ISM_ACC_SENS_MG = {2: 0.061, 4: 0.122, 8: 0.244, 16: 0.488}
# Angular rate sensitivity: 4.375 / 8.75 / 17.50 / 35 / 70 / 140 mdps/LSB at ±125 … ±4000 dps.
_ISM_GYR_SENS_MDPS = {125: 4.375, 250: 8.75, 500: 17.50, 1000: 35.0, 2000: 70.0, 4000: 140.0}
# Output data rates (high-performance mode), Hz.
_ISM_ODR = (12.5, 26.0, 52.0, 104.0, 208.0, 416.0, 833.0, 1666.0, 3332.0, 6667.0)


def ism330dhcx_accel(fs_g: int = 4) -> SensorSpec:
    """ISM330DHCX accelerometer at ±fs_g g."""
    return SensorSpec(
        chip="ISM330DHCX",
        kind="accel",
        full_scale=fs_g * G,
        sensitivity=_ISM_ACC_SENS_MG[fs_g] * MG,
        noise_density=60e-6 * G,  # An, high-performance mode: 60 µg/√Hz (DS13012 Table 3)
        noise_rms=None,
        bias_typical=10 * MG,  # LA_TyOff zero-g level offset: ±10 mg typ. (DS13012 Table 3)
        odr_hz=_ISM_ODR,
    )


def ism330dhcx_gyro(fs_dps: int = 500) -> SensorSpec:
    """ISM330DHCX gyroscope at ±fs_dps °/s."""
    return SensorSpec(
        chip="ISM330DHCX",
        kind="gyro",
        full_scale=fs_dps * DEG,
        sensitivity=_ISM_GYR_SENS_MDPS[fs_dps] * 1e-3 * DEG,
        noise_density=5e-3 * DEG,  # Rn rate noise density: 5 mdps/√Hz (DS13012 Table 3)
        noise_rms=None,
        bias_typical=1.0 * DEG,  # G_TyOff zero-rate level: ±1 dps typ. (DS13012 Table 3)
        odr_hz=_ISM_ODR,
    )


def iis2mdc_mag() -> SensorSpec:
    """IIS2MDC magnetometer (single range ±50 gauss)."""
    return SensorSpec(
        chip="IIS2MDC",
        kind="mag",
        full_scale=50 * GAUSS,  # ±50 gauss (DS12134 Rev 5, Table 2)
        sensitivity=1.5e-3 * GAUSS,  # 1.5 mgauss/LSB (DS12134 Table 2)
        noise_density=None,
        noise_rms=3e-3 * GAUSS,  # RMS noise, high-resolution mode: 3 mgauss (DS12134 Table 2)
        bias_typical=60e-3 * GAUSS,  # zero-gauss offset accuracy ±60 mgauss (DS12134 Table 2)
        odr_hz=(10.0, 20.0, 50.0, 100.0),  # ODR selection (DS12134 CFG_REG_A)
    )


# --- InvenSense MPU-6050 (PS-MPU-6000A-00 Rev 3.4, sections 6.1 and 6.2) ------------------
_MPU_ACC_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
_MPU_GYR_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}


def mpu6050_accel(fs_g: int = 2) -> SensorSpec:
    """MPU-6050 accelerometer at ±fs_g g."""
    return SensorSpec(
        chip="MPU6050",
        kind="accel",
        full_scale=fs_g * G,
        sensitivity=G / _MPU_ACC_LSB_PER_G[fs_g],  # 16384 LSB/g at ±2 g (§6.2)
        noise_density=400e-6 * G,  # power spectral density 400 µg/√Hz (§6.2)
        noise_rms=None,
        bias_typical=50 * MG,  # zero-g initial calibration tolerance ±50 mg X, Y (±80 mg Z) (§6.2)
        odr_hz=(1000.0,),  # accelerometer output rate 1 kHz (§6.2)
    )


def mpu6050_gyro(fs_dps: int = 250) -> SensorSpec:
    """MPU-6050 gyroscope at ±fs_dps °/s."""
    return SensorSpec(
        chip="MPU6050",
        kind="gyro",
        full_scale=fs_dps * DEG,
        sensitivity=DEG / _MPU_GYR_LSB_PER_DPS[fs_dps],  # 131 LSB/(°/s) at ±250 °/s (§6.1)
        noise_density=0.005 * DEG,  # rate noise spectral density 0.005 °/s/√Hz (§6.1)
        noise_rms=None,
        bias_typical=20.0 * DEG,  # initial ZRO tolerance ±20 °/s (§6.1)
        odr_hz=(1000.0, 8000.0),  # gyro output rate 8 kHz, 1 kHz with the DLPF on (§6.1)
    )


@dataclass(frozen=True)
class Board:
    """A board: its sensors, their mounting matrices M_bs (body ← sensor) and default rate."""

    name: str
    accel: SensorSpec
    gyro: SensorSpec
    mag: SensorSpec | None
    mount: dict  # {"acc": 3×3, "gyr": 3×3, "mag": 3×3} as nested lists
    rate_hz: float
    mag_rate_hz: float | None = None


# X-NUCLEO-IKS02A1: the ISM330DHCX reads +1 g on z when the board lies flat (z up), so
# M_bs flips y and z. The IIS2MDC is mounted rotated 180° about y relative to the
# ISM330DHCX (its x and z are negated), so its M_bs = MOUNT_Z_UP · diag(−1, 1, −1).
NUCLEO_IKS02A1 = Board(
    name="nucleo-iks02a1",
    accel=ism330dhcx_accel(4),
    gyro=ism330dhcx_gyro(500),
    mag=iis2mdc_mag(),
    mount={
        "acc": MOUNT_Z_UP.tolist(),
        "gyr": MOUNT_Z_UP.tolist(),
        "mag": (MOUNT_Z_UP @ np.diag([-1.0, 1.0, -1.0])).tolist(),
    },
    rate_hz=104.0,
    mag_rate_hz=50.0,
)

# GY-521 breakout: the MPU-6050 reads +1 g on z when flat, so M_bs flips y and z.
MPU6050_GY521 = Board(
    name="mpu6050",
    accel=mpu6050_accel(2),
    gyro=mpu6050_gyro(250),
    mag=None,
    mount={"acc": MOUNT_Z_UP.tolist(), "gyr": MOUNT_Z_UP.tolist()},
    rate_hz=100.0,
)

BOARDS = {b.name: b for b in (NUCLEO_IKS02A1, MPU6050_GY521)}


# --- the phone as a board ----------------------------------------------------------------------------
# **Its frame.** Android and iOS report the accelerometer, gyroscope and magnetometer in one frame fixed
# to the phone: x to the right of the screen, y up the screen (towards the top edge), z out of the
# screen (Android ``SensorEvent``). The OS already aligned the chips to it, so all three sensors share
# one mounting (unlike the Nucleo's IIS2MDC, lab 03). Units as phyphox exports them: m/s², rad/s, µT.
# The accelerometer is the specific force (+9.81 m/s² on z lying face up) on both platforms: Android's
# ``TYPE_ACCELEROMETER`` reports it so; CoreMotion reports acceleration in g with the opposite sign and
# phyphox multiplies it by ``kG = -9.81`` (phyphox-ios ``ExperimentSensorInput.swift``; 9.81, not
# 9.80665: 0.035 % of g). Gyroscope: right-handed rates, rad/s, most of the bias removed by the OS.
# Magnetometer: the calibrated field (hard iron removed by the OS), µT.
#
# **Mounting.** ``x_b = M_bs x_s`` maps the phone frame to the body frame FRD. :data:`PHONE_MOUNTS` names
# the usual ways to hold a phone; any other is a 3×3 rotation whose rows are the body axes written in
# phone axes (checked by :func:`kfkit.frames.mount_matrix`).
#
# **Counts.** The kit's recordings hold integer counts and a sensitivity per sensor. A phone gives SI
# floats, stored as fixed-point counts with the resolutions :data:`PHONE_LSB`: rounding changes a value by
# at most LSB/2 (5e-5 m/s², 5e-6 rad/s, 5e-4 µT), far below the phone sensors' own resolution and noise,
# and a phone recording then saves, loads and streams exactly like a board's: its counts are the serial
# protocol's int32 (|counts| ≤ :data:`PHONE_MAX_COUNTS`), so a phone holds at most ±214,748 m/s² (21,900 g),
# ±21,474 rad/s and ±2,147,483 µT, orders of magnitude beyond any phone sensor's range.

PHONE_BOARD = "phone-phyphox"

#: Fixed-point resolution of a phone recording's counts, SI per count (see above).
PHONE_LSB = {"acc": 1e-4, "gyr": 1e-5, "mag": 1e-3}  # m/s², rad/s, µT
PHONE_MAX_COUNTS = 2**31 - 1  # the largest |count| of a phone recording: protocol v1's int32 fields

#: Mounting matrices M_bs (body FRD ← phone frame): rows are the body axes in phone axes.
PHONE_MOUNTS = {
    # lying flat, screen up, top edge pointing forward: x_b = y_s, y_b = x_s, z_b = −z_s
    "flat": ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
    # lying flat, screen up, right edge pointing forward (landscape): x_b = x_s, y_b = −y_s, z_b = −z_s
    "flat_landscape": ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    # held upright in portrait, screen facing you, the back camera looking forward:
    # x_b = −z_s, y_b = x_s, z_b = −y_s
    "upright": ((0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
}
DEFAULT_PHONE_MOUNT = "flat"


def phone_mount(mount=DEFAULT_PHONE_MOUNT) -> tuple[str, np.ndarray]:
    """(name, M_bs) for a name in :data:`PHONE_MOUNTS` or a 3×3 rotation (named "custom")."""
    if isinstance(mount, str):
        try:
            return mount, np.array(PHONE_MOUNTS[mount])
        except KeyError:
            raise ValueError(
                f"unknown phone mounting {mount!r}; known: {', '.join(PHONE_MOUNTS)}, "
                f"or a 3×3 rotation matrix M_bs whose rows are the body axes in phone axes"
            ) from None
    return "custom", mount_matrix(mount)


@dataclass(frozen=True)
class PhoneSensorSpec(SensorSpec):
    """A phone sensor in the kit's fixed-point counts: saturates at full scale, not at int16."""

    @property
    def max_count(self) -> int:
        return int(np.floor(self.full_scale / self.sensitivity))

    @property
    def min_count(self) -> int:
        return -self.max_count


# Phone-grade sensors for the simulator. A phone's chips vary by model; these are common ones.
# Bosch BMI160 (BST-BMI160-DS000, Table 1), in many Android phones: accelerometer output noise
# density 180 µg/√Hz, zero-g offset ±40 mg; gyroscope noise density 0.007 °/s/√Hz, zero-rate offset
# ±3 °/s; ranges used by Android: ±8 g, ±2000 °/s. AKM AK09918 (016014242-E-00, 2016/11): 0.15 µT
# per LSB, ±4912 µT, continuous modes 10–100 Hz; its noise is not in the datasheet's tables, so
# σ = 0.3 µT (2 LSB) per sample is assumed here.
PHONE_ACCEL = PhoneSensorSpec(
    "BMI160-class phone accelerometer",
    "accel",
    8 * G,
    PHONE_LSB["acc"],
    180e-6 * G,
    None,
    40 * MG,
    (25.0, 50.0, 100.0, 200.0, 400.0),
)
PHONE_GYRO = PhoneSensorSpec(
    "BMI160-class phone gyroscope",
    "gyro",
    2000 * DEG,
    PHONE_LSB["gyr"],
    0.007 * DEG,
    None,
    3.0 * DEG,
    (25.0, 50.0, 100.0, 200.0, 400.0),
)
PHONE_MAG = PhoneSensorSpec(
    "AK09918-class phone magnetometer", "mag", 4912.0, PHONE_LSB["mag"], None, 0.3, 1.0, (10.0, 20.0, 50.0, 100.0)
)


def phone_board(mount=DEFAULT_PHONE_MOUNT) -> Board:
    """The phone as a :class:`Board` (all three sensors share the phone frame)."""
    _, M = phone_mount(mount)
    return Board(PHONE_BOARD, PHONE_ACCEL, PHONE_GYRO, PHONE_MAG, {k: M.tolist() for k in SENSORS}, 100.0, 50.0)


def phone_sensor_metadata(sensor: str, chip: str | None = None, full_scale: float | None = None) -> dict:
    """A recording's ``meta["sensors"][sensor]`` for phone counts (sensitivity = :data:`PHONE_LSB`)."""
    meta = {
        "chip": chip or f"phone {dict(acc='accelerometer', gyr='gyroscope', mag='magnetometer')[sensor]}",
        "sensitivity": PHONE_LSB[sensor],
        "unit": SI_UNITS[sensor],
    }
    if full_scale is not None:
        meta["full_scale"] = float(full_scale)
    return meta


def phone_counts(sensor: str, values) -> np.ndarray:
    """SI values (N, 3) → fixed-point counts: int64, or float with NaN rows kept (magnetometer)."""
    counts = np.rint(np.asarray(values, dtype=float) / PHONE_LSB[sensor])
    return counts if np.isnan(counts).any() else counts.astype(np.int64)


def board(name: str) -> Board:
    """The :class:`Board` called ``name``: one of :data:`BOARDS`, or ``"phone-phyphox"``, a phone
    (:func:`phone_board`: its sensor model; its mounting is each recording's own)."""
    if name == PHONE_BOARD:
        return phone_board()
    try:
        return BOARDS[name]
    except KeyError:
        raise ValueError(f"unknown board {name!r}; known boards: {', '.join(sorted(BOARDS))}, {PHONE_BOARD}") from None
