"""A phone's sensors, simulated: each on its own clock and rate, with timestamp jitter and lost samples.

:func:`simulate_phone` plays a :class:`kfkit.sim.Motion` through a phone held in one of
:data:`kfkit.sensors.PHONE_MOUNTS`: each sensor samples at its own rate (:data:`PHONE_RATES`) from a random
phase, its values come from :func:`kfkit.sim.simulate_imu` with the phone's noise
(:func:`kfkit.sensors.phone_board`) and the phone's unit (:data:`kfkit.unit_errors.PHONE_UNIT`), rounded to
the phone's fixed-point grid (:data:`kfkit.sensors.PHONE_LSB`). :mod:`kfkit.readers.phyphox_export` writes
the result as a phyphox export; :mod:`kfkit.capture.virtual_phone` serves it as phyphox's remote interface.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frames import G, MAG_FIELD_LONDON, dcm_slerp, dcm_to_euler, dcm_to_quat, euler_to_dcm
from .sensors import DEFAULT_PHONE_MOUNT, PHONE_LSB, phone_board, phone_mount
from .sim import Motion, simulate_imu
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


def simulate_phone(motion, seed=0, rates=None, jitter_s=TIMESTAMP_JITTER, unit=None, field_n=MAG_FIELD_LONDON,
                   mount=DEFAULT_PHONE_MOUNT, drop=0.0) -> PhoneSamples:
    """A phone held in ``mount`` through ``motion`` (a :class:`kfkit.sim.Motion`, best sampled well
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
        rec = simulate_imu(sampled, board=board, seed=int(rng.integers(2**31)), field_n=field_n,
                           mag_rate_hz=1e9, **unit)
        values[sensor] = rec.counts(sensor) * PHONE_LSB[sensor]
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
