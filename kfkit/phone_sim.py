"""A phone's sensors, simulated: each on its own clock and rate, with timestamp jitter and lost samples.

:func:`simulate_phone` plays a :class:`kfkit.motions.Motion` through a phone held in one of
:data:`kfkit.sensors.PHONE_MOUNTS`: each sensor samples at its own rate (:data:`PHONE_RATES`) from a random
phase, its values come from :func:`kfkit.sim.simulate_imu` with the phone's noise
(:func:`kfkit.sensors.phone_board`) and the phone's unit (:data:`kfkit.unit_errors.PHONE_UNIT`), rounded to
the phone's fixed-point grid (:data:`kfkit.sensors.PHONE_LSB`). :func:`simple_experiment_files` writes the result
as phyphox exports it (read back by :mod:`kfkit.readers.phyphox_export`); :mod:`kfkit.capture.virtual_phone` serves
it as phyphox's remote interface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .frames import MAG_FIELD_LONDON, G, dcm_slerp, dcm_to_euler, dcm_to_quat, euler_to_dcm
from .io import format_header
from .motions import Motion
from .sensors import DEFAULT_PHONE_MOUNT, PHONE_LSB, PHONE_MAG, phone_board, phone_mount
from .sim import simulate_imu
from .unit_errors import PHONE_UNIT

#: The simulated phone's sensor rates (Hz): what phyphox gives when a simple experiment asks for
#: 100 Hz. Each sensor runs on its own oscillator (a phone's differ by about 1 %).
PHONE_RATES = {"gyr": 100.2, "acc": 99.6, "mag": 50.1}
#: RMS jitter of the phone's timestamps, s (interrupt and batching latency; an assumption).
TIMESTAMP_JITTER = 3e-4


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
    R_nb = dcm_slerp(motion.t, euler_to_dcm(motion.euler), t)
    omega = np.column_stack([np.interp(t, motion.t, motion.omega_b[:, i]) for i in range(3)])
    acc_n = np.column_stack([np.interp(t, motion.t, motion.acc_n[:, i]) for i in range(3)])
    return R_nb, omega, acc_n


def _sample_times(rng, t0, t1, rate):
    phase = rng.uniform(0.0, 1.0 / rate)
    return t0 + phase + np.arange(int(np.floor((t1 - t0 - phase) * rate)) + 1) / rate


def simulate_phone(
    motion,
    seed=0,
    rates=None,
    jitter_s=TIMESTAMP_JITTER,
    unit=None,
    field_n=MAG_FIELD_LONDON,
    mount=DEFAULT_PHONE_MOUNT,
    drop=0.0,
) -> PhoneSamples:
    """A phone held in ``mount`` through ``motion`` (a :class:`kfkit.motions.Motion`, best sampled well
    above the sensors' rates, e.g. 400 Hz): each sensor samples at its own rate (:data:`PHONE_RATES`)
    from a random phase, its timestamps carry ``jitter_s`` RMS of jitter, each sample is lost with
    probability ``drop``, and the values come from :func:`kfkit.sim.simulate_imu` with the phone's
    noise (:func:`phone_board`) and the unit's offsets (:data:`kfkit.unit_errors.PHONE_UNIT`). Seeded."""
    rates = {**PHONE_RATES, **(rates or {})}
    unit = dict(PHONE_UNIT if unit is None else unit)
    board = phone_board(mount)
    rng = np.random.default_rng(seed)
    t0, t1 = float(motion.t[0]), float(motion.t[-1])
    t, values, R_true = {}, {}, {}
    for sensor in ("gyr", "acc", "mag"):
        t_true = _sample_times(rng, t0, t1, rates[sensor])
        t_true = t_true[rng.random(len(t_true)) >= drop]
        R_nb, omega, acc_n = resample_motion(motion, t_true)
        euler = dcm_to_euler(R_nb)
        sampled = Motion(t_true, rates[sensor], euler, omega, acc_n)
        rec = simulate_imu(
            sampled, board=board, seed=int(rng.integers(2**31)), field_n=field_n, mag_rate_hz=1e9, **unit
        )
        values[sensor] = rec.counts(sensor) * PHONE_LSB[sensor]
        t[sensor] = t_true + rng.normal(0.0, jitter_s, len(t_true))
        R_true[sensor] = R_nb
    _, M = phone_mount(mount)
    R_ns = R_true["gyr"] @ M  # x_n = R_nb x_b = R_nb M_bs x_s
    gravity = np.einsum("nji,j->ni", R_true["acc"] @ M, [0.0, 0.0, -G])  # R_sn (−g_n), what a "gravity" sensor reports
    quat = dcm_to_quat(R_ns)
    sim = {
        "seed": seed,
        "rates_hz": rates,
        "timestamp_jitter_s": jitter_s,
        "drop": drop,
        "field_n": list(field_n),
        "mount": phone_mount(mount)[0],
        **{k: np.asarray(v, float).tolist() for k, v in unit.items()},
    }
    phases = [{"label": label, "start": float(a), "end": float(b)} for a, b, label in motion.phases]
    return PhoneSamples(t, values, quat, gravity, phases, motion.description, sim)


#: the kit's addition to a simulated export: the phone's true attitude per gyroscope row, ``# kfkit-truth v1 {json}``
TRUTH_FILE, TRUTH_KIND = "kfkit_truth.csv", "truth"


# --- an export as phyphox writes it (the bundled phone recording, tests) ------------------------------------------


def format_number(value: float, decimal: str = ".") -> str:
    """A number as phyphox's CSV export writes it: ten significant digits, ``9.806650000E0``."""
    if math.isnan(value):
        return "NaN"
    mantissa, exponent = f"{value:.9E}".split("E")
    return f"{mantissa.replace('.', decimal)}E{int(exponent)}"


def csv_text(columns, separator=",", decimal=".") -> str:
    """One export set as phyphox-android writes it: quoted labels, then one row per sample, every line
    ending in a newline. ``columns`` is [(label, values (N,)), …] of equal lengths."""
    header = separator.join(f'"{label}"' for label, _ in columns) + "\n"
    arrays = [np.asarray(v, dtype=float) for _, v in columns]
    rows = (separator.join(format_number(v, decimal) for v in row) + "\n" for row in zip(*(a.tolist() for a in arrays)))
    return header + "".join(rows)


#: Android simple experiment: (set name, column labels) per sensor
SIMPLE_EXPERIMENT_SETS = {
    "acc": ("Accelerometer", ("Acceleration x (m/s^2)", "Acceleration y (m/s^2)", "Acceleration z (m/s^2)")),
    "gyr": ("Gyroscope", ("Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)")),
    "mag": ("Magnetometer", ("Magnetic field x (µT)", "Magnetic field y (µT)", "Magnetic field z (µT)")),
}


def write_export(files: dict, folder) -> Path:
    """Write {relative path: text} (e.g. :func:`simple_experiment_files`) as the folder a phyphox zip unpacks to."""
    folder = Path(folder)
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text, encoding="utf-8", newline="\n")
    return folder


def simple_experiment_files(samples, separator=",", decimal=".", device=None) -> dict[str, str]:
    """The files of an Android simple experiment's CSV export of ``samples``
    (:class:`kfkit.phone_sim.PhoneSamples`), plus :data:`TRUTH_FILE`: {relative path: text}."""
    files = {}
    for k, (set_name, labels) in SIMPLE_EXPERIMENT_SETS.items():
        v = samples.values[k]
        files[f"{set_name}.csv"] = csv_text(
            [("Time (s)", samples.t[k])] + [(labels[i], v[:, i]) for i in range(3)], separator, decimal
        )
    props = {
        "version": "1.2.0",
        "deviceModel": "kfkit simulated phone",
        "deviceBrand": "kfkit",
        "deviceManufacturer": "kfkit",
        "deviceRelease": "simulation",
        **(device or {}),
    }
    for k, android in (("acc", "accelerometer"), ("gyr", "gyroscope"), ("mag", "magnetic_field")):
        spec = phone_board().accel if k == "acc" else phone_board().gyro if k == "gyr" else PHONE_MAG
        props[f"{android} Name"] = spec.chip
        props[f"{android} Range"] = f"{spec.full_scale:.6g}"
    files["meta/device.csv"] = f'"property"{separator}"value"\n' + "".join(
        f'"{p}"{separator}"{v}"\n' for p, v in props.items()
    )
    files["meta/time.csv"] = (
        separator.join(f'"{c}"' for c in ("event", "experiment time", "system time", "system time text"))
        + "\n"
        + separator.join(
            [
                '"START"',
                format_number(0.0, decimal),
                "0.000".replace(".", decimal),
                '"1970-01-01 00:00:00.000 UTC+00:00"',
            ]
        )
        + "\n"
    )
    truth = {"description": samples.description, "phases": samples.phases, "sim": samples.sim}
    files[TRUTH_FILE] = format_header(truth, ("row", "true_qw", "true_qx", "true_qy", "true_qz"), TRUTH_KIND) + "".join(
        f"{i},{w:.9f},{x:.9f},{y:.9f},{z:.9f}\n" for i, (w, x, y, z) in enumerate(samples.truth_quat.tolist())
    )
    return files
