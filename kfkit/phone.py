"""A phone as the sensor board: its frame, mounting, sensors, clocks, and a simulator of them.

**The phone's frame.** Android and iOS report the accelerometer, gyroscope and magnetometer in one
frame fixed to the phone: x to the right of the screen, y up the screen (towards the top edge),
z out of the screen (Android ``SensorEvent``: "the X axis is horizontal and points to the right,
the Y axis is vertical and points up and the Z axis points towards the outside of the front face
of the screen"). The OS already aligned the chips to it, so all three sensors share one mounting
(unlike the Nucleo's IIS2MDC, lab 03). Units as phyphox exports them: m/s², rad/s, µT.

- Accelerometer: the specific force (the reaction to gravity), +9.81 m/s² on z lying face up.
  Android's ``TYPE_ACCELEROMETER`` reports it so; CoreMotion on iOS reports acceleration in g with
  the opposite sign, and phyphox multiplies it by ``kG = -9.81`` (phyphox-ios,
  ``Experiments/Data-Input/ExperimentSensorInput.swift``), so phyphox exports follow the Android
  convention on both platforms. (iOS scales by 9.81 rather than 9.80665: 0.035 % of g.)
- Gyroscope: right-handed rates about the same axes on both platforms (Android ``TYPE_GYROSCOPE``,
  CoreMotion ``rotationRate``), rad/s; both OSes remove most of the gyro's bias themselves.
- Magnetometer: the calibrated field (hard iron removed by the OS), µT.

**Mounting.** ``x_b = M_bs x_s`` maps the phone frame to the kit's body frame FRD (x forward,
y right, z down). :data:`MOUNTS` names the usual ways to hold a phone; any other is a 3×3 rotation
whose rows are the body axes written in phone axes (checked by :func:`kfkit.frames.mount_matrix`).

**Counts.** The kit's recordings hold integer counts and a sensitivity per sensor (SI per count).
A phone gives SI floats, stored as fixed-point counts with the resolutions :data:`LSB`: rounding
changes a value by at most LSB/2 (5e-5 m/s², 5e-6 rad/s, 5e-4 µT), far below the phone sensors'
own resolution and noise, and a phone recording then saves, loads and streams exactly like a board's.

**Clocks.** Each sensor reports on its own clock and rate; :class:`OneClock` puts them on the
gyroscope's time base (the accelerometer interpolated linearly at the gyro's times, a new
magnetometer sample placed in the first gyro row at or after its time, the rows in between NaN: the
recording format's "no new sample").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .frames import G, MAG_FIELD_LONDON, dcm_to_euler, dcm_to_quat, euler_to_dcm, mount_matrix
from .sensors import DEG, MG, Board, SensorSpec

BOARD_NAME = "phone-phyphox"
SENSORS = ("acc", "gyr", "mag")

#: Fixed-point resolution of a phone recording's counts, SI per count (see the module docstring).
LSB = {"acc": 1e-4, "gyr": 1e-5, "mag": 1e-3}  # m/s², rad/s, µT
UNITS = {"acc": "m/s^2", "gyr": "rad/s", "mag": "uT"}

#: Mounting matrices M_bs (body FRD ← phone frame): rows are the body axes in phone axes.
MOUNTS = {
    # lying flat, screen up, top edge pointing forward: x_b = y_s, y_b = x_s, z_b = −z_s
    "flat": ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
    # lying flat, screen up, right edge pointing forward (landscape): x_b = x_s, y_b = −y_s, z_b = −z_s
    "flat_landscape": ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    # held upright in portrait, screen facing you, the back camera looking forward:
    # x_b = −z_s, y_b = x_s, z_b = −y_s
    "upright": ((0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
}
DEFAULT_MOUNT = "flat"


def phone_mount(mount=DEFAULT_MOUNT) -> tuple[str, np.ndarray]:
    """(name, M_bs) for a name in :data:`MOUNTS` or a 3×3 rotation (named "custom")."""
    if isinstance(mount, str):
        try:
            return mount, np.array(MOUNTS[mount])
        except KeyError:
            raise ValueError(f"unknown phone mounting {mount!r}; known: {', '.join(MOUNTS)}, "
                             f"or a 3×3 rotation matrix M_bs whose rows are the body axes in phone axes") from None
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
PHONE_ACCEL = PhoneSensorSpec("BMI160-class phone accelerometer", "accel", 8 * G, LSB["acc"], 180e-6 * G, None,
                              40 * MG, (25.0, 50.0, 100.0, 200.0, 400.0))
PHONE_GYRO = PhoneSensorSpec("BMI160-class phone gyroscope", "gyro", 2000 * DEG, LSB["gyr"], 0.007 * DEG, None,
                             3.0 * DEG, (25.0, 50.0, 100.0, 200.0, 400.0))
PHONE_MAG = PhoneSensorSpec("AK09918-class phone magnetometer", "mag", 4912.0, LSB["mag"], None, 0.3,
                            1.0, (10.0, 20.0, 50.0, 100.0))


def phone_board(mount=DEFAULT_MOUNT) -> Board:
    """The phone as a :class:`kfkit.sensors.Board` (all three sensors share the phone frame)."""
    _, M = phone_mount(mount)
    return Board(BOARD_NAME, PHONE_ACCEL, PHONE_GYRO, PHONE_MAG, {k: M.tolist() for k in SENSORS}, 100.0, 50.0)


def sensor_metadata(sensor: str, chip: str | None = None, full_scale: float | None = None) -> dict:
    """A recording's ``meta["sensors"][sensor]`` for phone counts (sensitivity = :data:`LSB`)."""
    meta = {"chip": chip or f"phone {dict(acc='accelerometer', gyr='gyroscope', mag='magnetometer')[sensor]}",
            "sensitivity": LSB[sensor], "unit": UNITS[sensor]}
    if full_scale is not None:
        meta["full_scale"] = float(full_scale)
    return meta


def to_counts(sensor: str, values) -> np.ndarray:
    """SI values (N, 3) → fixed-point counts: int64, or float with NaN rows kept (magnetometer)."""
    counts = np.rint(np.asarray(values, dtype=float) / LSB[sensor])
    return counts if np.isnan(counts).any() else counts.astype(np.int64)


def sequence(t, nominal_dt) -> np.ndarray:
    """Sample counters for times t (s): +1 per sample, +k where the interval is k nominal periods
    (k = round(Δt / nominal_dt) ≥ 1), so a gap in the phone's timestamps shows as dropped samples."""
    steps = np.maximum(np.rint(np.diff(np.asarray(t, dtype=float)) / nominal_dt), 1).astype(np.int64)
    return np.concatenate([[0], np.cumsum(steps)])


# --- one time base --------------------------------------------------------------------------------

class OneClock:
    """Merge a phone's sensors, each on its own clock, onto the time base of one of them.

    ``base`` (default the gyroscope) gives the rows; ``interpolated`` sensors (the accelerometer)
    are interpolated linearly at the base times, so a row is kept only inside their time span;
    ``held`` sensors (the magnetometer) put each new sample in the first base row at or after its
    time (a delay of at most one base period) and leave the other rows NaN. If two held samples
    fall in one row the newer wins (counted in ``stats["mag_merged"]``).

    Samples arrive in pieces (:meth:`push`, times increasing per sensor) and rows leave in order
    (:meth:`pop`), so a file and a live stream give the same rows. Live, a row is released once the
    interpolated sensors have passed it and the held sensor has had ``hold_s`` to deliver a sample
    for it (unless it has sent nothing for ``stall_s``); a held sample that still comes later goes
    into the next row (``stats["mag_late"]``).
    """

    def __init__(self, base="gyr", interpolated=("acc",), held=("mag",), hold_s=0.05, stall_s=1.0):
        self.base, self.interpolated, self.held = base, tuple(interpolated), tuple(held)
        self.hold_s, self.stall_s = hold_s, stall_s
        self._t = {s: np.zeros(0) for s in (base, *self.interpolated, *self.held)}
        self._v = {s: np.zeros((0, 3)) for s in self._t}
        self._seen = {s: False for s in self._t}
        self._last = {s: -np.inf for s in self._t}
        self._index = 0  # base samples consumed so far (their index in the base sensor's stream)
        self._t_out = -np.inf  # time of the last row released
        self.stats = {"before_start": 0, "after_end": 0, "mag_merged": 0, "mag_late": 0, "mag_outside": 0}

    def push(self, sensor, t, values):
        """Append samples of ``sensor``: times t (N,) s, increasing, and values (N, 3)."""
        t = np.asarray(t, dtype=float)
        if not len(t):
            return
        self._t[sensor] = np.concatenate([self._t[sensor], t])
        self._v[sensor] = np.concatenate([self._v[sensor], np.asarray(values, dtype=float).reshape(-1, 3)])
        self._seen[sensor] = True
        self._last[sensor] = max(self._last[sensor], float(t[-1]))

    def pop(self, final=False):
        """Rows ready now: (t (n,), {sensor: (n, 3)}, base indices (n,)). ``final``: everything left."""
        tb = self._t[self.base]
        bound = np.inf if final else self._last[self.base]
        for s in self.interpolated:
            if not final:
                bound = min(bound, self._last[s])
        for s in self.held:
            if not final and self._seen[s] and self._last[self.base] - self._last[s] < self.stall_s:
                bound = min(bound, self._last[s] + self.hold_s)
        # rows before every interpolated sensor has started can never be interpolated
        first = max((self._t[s][0] for s in self.interpolated if len(self._t[s])), default=-np.inf)
        if any(not len(self._t[s]) for s in self.interpolated):
            if final:
                self.stats["before_start"] += len(tb)
                self._consume(len(tb))
            return self._empty()
        early = int(np.searchsorted(tb, first, side="left"))
        if early:
            self.stats["before_start"] += early
            self._consume(early)
            tb = self._t[self.base]
        last_interp = min((self._t[s][-1] for s in self.interpolated), default=np.inf)
        n = int(np.searchsorted(tb, min(bound, last_interp), side="right"))
        if final:
            self.stats["after_end"] += len(tb) - n
        t_rows = tb[:n]
        out = {self.base: self._v[self.base][:n]}
        for s in self.interpolated:
            ts, vs = self._t[s], self._v[s]
            out[s] = np.column_stack([np.interp(t_rows, ts, vs[:, i]) for i in range(3)])
        for s in self.held:
            out[s] = self._place_held(s, t_rows, final)
        index = self._index + np.arange(n)
        self._consume(len(tb) if final else n)
        if n:
            self._t_out = float(t_rows[-1])
        for s in self.interpolated:  # keep the last sample at or before the released rows
            keep = max(int(np.searchsorted(self._t[s], self._t_out, side="right")) - 1, 0)
            self._t[s], self._v[s] = self._t[s][keep:], self._v[s][keep:]
        return t_rows, out, index

    def _place_held(self, s, t_rows, final):
        n = len(t_rows)
        rows = np.full((n, 3), np.nan)
        ts, vs = self._t[s], self._v[s]
        if not n:
            return rows
        ready = ts <= t_rows[-1]
        period = np.median(np.diff(t_rows)) if n > 1 else 0.0
        late = ready & (ts <= self._t_out)
        self.stats["mag_late"] += int(late.sum())
        k = np.searchsorted(t_rows, ts[ready], side="left")
        if self._t_out == -np.inf:  # the first rows: a sample up to one period before row 0 belongs to it
            outside = ts[ready] < t_rows[0] - period
            self.stats["mag_outside"] += int(outside.sum())
            k = np.where(outside, -1, k)
        valid = k >= 0
        k, v = k[valid], vs[ready][valid]
        newest_first = slice(None, None, -1)
        row, where = np.unique(k[newest_first], return_index=True)  # the newest sample of each row
        self.stats["mag_merged"] += len(k) - len(row)
        rows[row] = v[newest_first][where]
        rest = ~ready
        if final:
            self.stats["mag_outside"] += int(rest.sum())
            rest[:] = False
        self._t[s], self._v[s] = ts[rest], vs[rest]
        return rows

    def _consume(self, n):
        self._t[self.base], self._v[self.base] = self._t[self.base][n:], self._v[self.base][n:]
        self._index += n

    def _empty(self):
        return np.zeros(0), {s: np.zeros((0, 3)) for s in self._t}, np.zeros(0, dtype=np.int64)


# --- simulation -------------------------------------------------------------------------------------

#: The simulated phone's sensor rates (Hz): what phyphox gives when a simple experiment asks for
#: 100 Hz. Each sensor runs on its own oscillator (a phone's differ by about 1 %).
PHONE_RATES = {"gyr": 100.2, "acc": 99.6, "mag": 50.1}
#: RMS jitter of the phone's timestamps, s (interrupt and batching latency; an assumption).
TIMESTAMP_JITTER = 3e-4
#: A phone after the OS's own calibration (phone frame, SI; assumptions, not measurements): the
#: gyro bias its drift compensation leaves (a few hundredths of °/s), a few mg of accelerometer
#: offset, and about 1 µT of hard iron its continuous magnetometer calibration has not removed (each
#: µT of it turns the heading by up to 3° in London's 19.5 µT horizontal field: lab 03).
PHONE_UNIT = {"gyro_bias": tuple(np.radians([0.03, -0.02, 0.04])), "accel_bias": (0.04, -0.03, 0.05),
              "mag_hard_iron": (0.6, -0.4, 0.8), "gyro_bias_rw": 2e-5, "accel_bias_rw": 2e-5}


@dataclass
class PhoneSamples:
    """What a phone's sensors delivered: per sensor its timestamps (s) and phone-frame SI values (N, 3),
    and the truth at the gyro's samples: quaternions phone → NED (w-x-y-z)."""

    t: dict
    values: dict
    truth_quat: np.ndarray
    gravity: np.ndarray = None  # the specific force of gravity alone at the accelerometer's samples (N, 3)
    phases: list = field(default_factory=list)
    description: str = ""
    sim: dict = field(default_factory=dict)


def resample_motion(motion, t):
    """The truth of ``motion`` at times t (s, inside its span): attitude by slerp, body rate and
    linear acceleration linearly. Returns (R_nb (N, 3, 3), ω_b (N, 3), a_n (N, 3))."""
    rotations = Rotation.from_matrix(euler_to_dcm(*motion.euler.T))
    R_nb = Slerp(motion.t, rotations)(t).as_matrix()
    omega = np.column_stack([np.interp(t, motion.t, motion.omega_b[:, i]) for i in range(3)])
    acc_n = np.column_stack([np.interp(t, motion.t, motion.acc_n[:, i]) for i in range(3)])
    return R_nb, omega, acc_n


def _sample_times(rng, t0, t1, rate):
    phase = rng.uniform(0.0, 1.0 / rate)
    return t0 + phase + np.arange(int(np.floor((t1 - t0 - phase) * rate)) + 1) / rate


def simulate_phone(motion, seed=0, rates=None, jitter_s=TIMESTAMP_JITTER, unit=None, field_n=MAG_FIELD_LONDON,
                   mount=DEFAULT_MOUNT, drop=0.0) -> PhoneSamples:
    """A phone held in ``mount`` through ``motion`` (a :class:`kfkit.sim.Motion`, best sampled well
    above the sensors' rates, e.g. 400 Hz): each sensor samples at its own rate (:data:`PHONE_RATES`)
    from a random phase, its timestamps carry ``jitter_s`` RMS of jitter, each sample is lost with
    probability ``drop``, and the values come from :func:`kfkit.sim.simulate_imu` with the phone's
    noise (:func:`phone_board`) and the unit's offsets (:data:`PHONE_UNIT`). Seeded."""
    from .sim import Motion, simulate_imu

    rates = {**PHONE_RATES, **(rates or {})}
    unit = dict(PHONE_UNIT if unit is None else unit)
    board = phone_board(mount)
    rng = np.random.default_rng(seed)
    t0, t1 = float(motion.t[0]), float(motion.t[-1])
    t, values, R_true = {}, {}, {}
    for k, sensor in enumerate(("gyr", "acc", "mag")):
        t_true = _sample_times(rng, t0, t1, rates[sensor])
        t_true = t_true[rng.random(len(t_true)) >= drop]
        R_nb, omega, acc_n = resample_motion(motion, t_true)
        euler = np.column_stack(dcm_to_euler(R_nb))
        sampled = Motion(t_true, rates[sensor], euler, omega, acc_n)
        rec = simulate_imu(sampled, board=board, seed=int(rng.integers(2**31)), field_n=field_n,
                           mag_rate_hz=1e9, **unit)
        values[sensor] = rec.counts(sensor) * LSB[sensor]
        t[sensor] = t_true + rng.normal(0.0, jitter_s, len(t_true))
        R_true[sensor] = R_nb
    _, M = phone_mount(mount)
    R_ns = R_true["gyr"] @ M  # x_n = R_nb x_b = R_nb M_bs x_s
    gravity = np.einsum("nji,j->ni", R_true["acc"] @ M, [0.0, 0.0, -G])  # R_sn (−g_n), what a "gravity" sensor reports
    quat = dcm_to_quat(R_ns)
    sim = {"seed": seed, "rates_hz": rates, "timestamp_jitter_s": jitter_s, "drop": drop, "field_n": list(field_n),
           "mount": phone_mount(mount)[0], **{k: np.asarray(v, float).tolist() for k, v in unit.items()}}
    phases = [{"label": label, "start": float(a), "end": float(b)} for a, b, label in motion.phases]
    return PhoneSamples(t, values, quat, gravity, phases, motion.description, sim)
