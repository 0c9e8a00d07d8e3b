"""What a board at rest measures (lab 02): gyro bias, noise σ, accelerometer bias, and each axis's bias and scale from
six faces; and the rests of a recording without labelled windows.

Body frame (FRD), SI units (rad/s, m/s²). At rest, level:

    gyro   b_g = mean(ω)
    accel  b_a = mean(f) − f_expected,    f_expected = [0, 0, −g]
    six faces, per axis (a⁺, a⁻ its mean pointing up and down):  b = (a⁺ + a⁻)/2,  s = (a⁺ − a⁻)/(2g)

:func:`label_rests` finds and names the rests of a recording without labelled windows (a phyphox export), so labs 02
and 03 run on it. :class:`CalibrationError` (data that cannot give a calibration, saying what to do) and the sample
checks every calibration input passes are here too, shared by :mod:`kfkit.allan`, :mod:`kfkit.mag_calibration` and
:mod:`kfkit.calibration`.
"""

from __future__ import annotations

import numpy as np

from .frames import G

FACES = ("x_up", "x_down", "y_up", "y_down", "z_up", "z_down")


class CalibrationError(ValueError):
    """Data that cannot give a calibration; the message says what is wrong and what to do."""


def _samples(x, name, min_samples=2, width=3):
    """``x`` as a float (N, width) array (N ≥ min_samples), all finite; clear errors otherwise."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1 and width == 3 and a.shape == (3,):
        raise CalibrationError(f"{name}: expected N samples of 3 axes, shape (N, 3); got one vector of shape (3,)")
    if a.ndim == 1 and width is None:
        a = a[:, None]
    if a.ndim != 2 or (width is not None and a.shape[1] != width):
        want = f"(N, {width})" if width else "(N,) or (N, k)"
        raise CalibrationError(f"{name}: expected shape {want}, got {a.shape}")
    if len(a) < min_samples:
        raise CalibrationError(f"{name}: {len(a)} samples, at least {min_samples} are needed")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise CalibrationError(
            f"{name}: {bad.sum()} of {len(a)} samples hold NaN or inf (first at row {np.argmax(bad)}); "
            f"drop them first, e.g. x[np.isfinite(x).all(axis=1)]"
        )
    return a


def gyro_bias(gyr):
    """Gyro bias b_g (3,), rad/s: the mean rate of a board at rest, (N, 3) body frame."""
    return _samples(gyr, "gyr").mean(axis=0)


def noise_std(x, window=None):
    """Per-sample noise σ (3,) of a stationary window (N, 3): the standard deviation (ddof = 1).

    Over a long rest the slow bias wander adds to it; with ``window`` (samples) σ is the RMS of the
    standard deviations of consecutive windows of that length, which leaves the wander out.
    """
    a = _samples(x, "x")
    if window is None:
        return a.std(axis=0, ddof=1)
    window = int(window)
    if not 2 <= window <= len(a):
        raise CalibrationError(f"window must be between 2 and the {len(a)} samples, got {window}")
    chunks = a[: len(a) // window * window].reshape(-1, window, a.shape[1])
    return np.sqrt(np.mean(chunks.var(axis=1, ddof=1), axis=0))


def accel_bias(acc, expected):
    """Accelerometer bias b_a = mean(f) − f_expected (3,), m/s².

    ``expected`` is the specific force of the pose (3,), e.g. [0, 0, −g] level and at rest: gravity
    is in the mean, and subtracting the whole mean would remove it too.
    """
    e = np.asarray(expected, dtype=float)
    if e.shape != (3,):
        raise CalibrationError(f"expected: the specific force of the pose must have shape (3,), got {e.shape}")
    return _samples(acc, "acc").mean(axis=0) - e


def accel_six_face(faces, g=G):
    """Per-axis bias b and scale s (3,) from six rests, one per face.

    ``faces`` maps "x_up", "x_down", … (which body axis points up, reading +g) to (N, 3) specific
    force (m/s², body). With a⁺, a⁻ the means of an axis pointing up and down:

        b = (a⁺ + a⁻) / 2,   s = (a⁺ − a⁻) / (2g);   corrected f = (f_raw − b) / s.
    """
    missing = [f for f in FACES if f not in faces]
    if missing:
        raise CalibrationError(f"faces: missing {', '.join(missing)}; need all six of {', '.join(FACES)}")
    bias, scale = np.empty(3), np.empty(3)
    for i, axis in enumerate("xyz"):
        up = _samples(faces[f"{axis}_up"], f"faces['{axis}_up']").mean(axis=0)[i]
        down = _samples(faces[f"{axis}_down"], f"faces['{axis}_down']").mean(axis=0)[i]
        if not (up > 0.5 * g and down < -0.5 * g):
            raise CalibrationError(
                f"faces: axis {axis} reads {up:+.2f} m/s² on '{axis}_up' and {down:+.2f} on "
                f"'{axis}_down'; expected about +{g:.2f} and −{g:.2f}: are the faces labelled "
                f"by the axis pointing up, in the body frame?"
            )
        bias[i], scale[i] = (up + down) / 2, (up - down) / (2 * g)
    return bias, scale


# --- finding the rests of an unlabelled recording -------------------------------------------------

REST_MIN_S = 2.0  # s: a shorter still spell is a pause, not a pose
REST_TRIM_S = 0.5  # s cut from both ends of a rest: the hand letting go, reaching for the stop button
REST_WINDOW_S = 0.5  # s: the moving window the spreads below are taken over
REST_GYRO_STD = np.radians(0.5)  # rad/s: at rest the gyro scatters by its noise (≈ 0.05–0.1 °/s), held by hand by °/s
REST_ACCEL_STD = 0.15  # m/s²: at rest the noise (≈ 0.01–0.02 m/s²); a hand or a slow turn moves it more
REST_G_TOLERANCE = 0.5  # m/s²: at rest |f| is g, up to the accelerometer's bias and scale errors
FACE_MAX_TILT = np.radians(10.0)  # an axis within this of vertical names the face; six faces err by g(1 − cos δ)


def _moving_mean_std(x, window):
    from scipy.ndimage import uniform_filter1d

    mean = uniform_filter1d(x, window, axis=0, mode="nearest")
    var = uniform_filter1d(x * x, window, axis=0, mode="nearest") - mean**2
    return mean, np.sqrt(np.maximum(var, 0.0))


def label_rests(rec, min_s=REST_MIN_S, trim_s=REST_TRIM_S, max_tilt=FACE_MAX_TILT):
    """A copy of ``rec`` whose ``phases`` mark its rests, for recordings without labelled windows
    (a phone's phyphox export); labs 02 and 03 then read them like a guided capture's.

    A sample is still where, over a moving ``REST_WINDOW_S``, every gyro and accelerometer axis
    (body frame) scatters less than ``REST_GYRO_STD`` and ``REST_ACCEL_STD`` and |f| is within
    ``REST_G_TOLERANCE`` of g. A still spell of at least ``min_s`` after cutting ``trim_s`` from both
    ends is a rest, named by the body axis pointing up (its mean specific force reads +g: ``"x_up"``;
    −g: ``"x_down"``, …, :data:`FACES`) when that axis is within ``max_tilt`` of vertical, else
    ``"rest"``; a level rest (``"z_down"``) is also ``"stationary"``. Raises :class:`CalibrationError`
    when there is none.
    """
    gyr, acc = rec.body("gyr"), rec.body("acc")
    t = rec.t
    window = max(3, int(round(REST_WINDOW_S * rec.rate_hz)))
    _, gyr_std = _moving_mean_std(gyr, window)
    acc_mean, acc_std = _moving_mean_std(acc, window)
    still = (
        (gyr_std < REST_GYRO_STD).all(axis=1)
        & (acc_std < REST_ACCEL_STD).all(axis=1)
        & (np.abs(np.linalg.norm(acc_mean, axis=1) - G) < REST_G_TOLERANCE)
    )
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    phases = []
    for first, stop in zip(edges[::2], edges[1::2]):
        start, end = t[first] + trim_s, t[stop - 1] - trim_s
        if end - start < min_s:
            continue
        f = acc[(t >= start) & (t < end)].mean(axis=0)
        i = int(np.argmax(np.abs(f)))
        tilted = np.arccos(min(1.0, abs(f[i]) / np.linalg.norm(f))) > max_tilt
        label = "rest" if tilted else f"{'xyz'[i]}_{'up' if f[i] > 0 else 'down'}"
        phases.append({"label": label, "start": float(start), "end": float(end)})
        if label == "z_down":
            phases.append({"label": "stationary", "start": float(start), "end": float(end)})
    if not phases:
        raise CalibrationError(
            f"{rec.path or 'recording'}: no rest of at least {min_s:g} s found (the gyro and the "
            f"accelerometer never stay still together): lay the board or phone down, let go, and "
            f"keep it still for a few seconds before moving it again"
        )
    meta = {**rec.meta, "phases": phases, "phases_from": "kfkit.calibration.label_rests"}
    return type(rec)(meta, rec.data, rec.path)
