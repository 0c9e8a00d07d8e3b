"""Lab 04's front door: :func:`estimate_attitude` (roll, pitch, yaw from gyro + accelerometer +
magnetometer) with either filter, each in its own module:

    euler_ekf       the lab's Euler-angle EKF: textbook step functions, EulerAttitudeEKF (run = a loop over step)
    euler_ekf_fast  FastEulerAttitudeEKF, the same filter unrolled on floats (what this front door runs)
    mekf            MultiplicativeEKF + MultiplicativeEKFSettings: quaternion error-state EKF with gyro bias
    mag_gate        MagGate, the MEKF's magnetic-disturbance gate
    attitude_run    AttitudeRun (the FilterRun both return), check_inputs, tilt_heading, learn_field

Its methods are the registry's "attitude" filters (:mod:`kfkit.filters.registry`).
"""

from __future__ import annotations

import numpy as np

from .attitude_run import AttitudeRun, check_inputs, learn_field
from .registry import methods

METHODS = methods("attitude")


def estimate_attitude(gyr, acc, mag, rate_hz, method="euler-ekf", **tuning) -> AttitudeRun:
    """Attitude of a board from its gyro (rad/s), accelerometer (m/s², specific force) and
    magnetometer (µT; None, or NaN rows = no new sample), all (N, 3) in one right-handed sensor
    frame, sampled at ``rate_hz``.

    Returns an :class:`AttitudeRun` with ``quat`` (N, 4; w-x-y-z, sensor → NED) and ``euler``.
    The world frame is NED whose north is that of the reference field: by default (``field_n``
    not given) the field is learned from the first magnetometer samples (:func:`learn_field`),
    so north is magnetic north. Without a magnetometer, yaw starts at 0 and follows the gyro.

    method "euler-ekf"  :class:`FastEulerAttitudeEKF` (tuning: an EulerAttitudeEKFSettings field, field_n, x0, P0)
           "mekf"       :class:`MultiplicativeEKF` (tuning: a MultiplicativeEKFSettings field, field_n, x0, P0)
    """
    gyr, acc, mag = check_inputs(gyr, acc, mag)
    if not (isinstance(rate_hz, (int, float, np.floating, np.integer)) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number (Hz), got {rate_hz!r}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; use {' or '.join(map(repr, METHODS))}")
    if "field_n" not in tuning and mag is not None:
        tuning["field_n"] = learn_field(acc, mag)
    return METHODS[method](rate_hz=rate_hz, **tuning).run(gyr, acc, mag)
