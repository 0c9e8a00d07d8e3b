"""Sensor calibration: gyro bias, accelerometer six-face, magnetometer hard/soft iron, Allan deviation.

Everything works in the body frame (FRD) and SI units (rad/s, m/s², µT). A :class:`Calibration`
holds the results of labs 02 and 03 and corrects raw body-frame measurements:

    gyro   ω = ω_raw − b_g
    accel  f = (f_raw − b_a) / s_a          (per axis)
    mag    m = S (m_raw − h)                (h hard iron, S symmetric soft-iron correction)

It is saved as a small JSON file. :func:`load_calibration` finds the right one for a board: an
explicit path, else the student's own file saved by labs 02/03 (:func:`user_calibration_path`),
else the bundled default in ``data/`` (made by ``kfkit data regenerate`` from the labs' analyses
of the bundled simulations). :func:`calibration_for` picks the one that belongs to a recording: the
bundled default for the bundled recordings, the student's own for theirs.

**A phone** (board ``"phone-phyphox"``) comes calibrated by its OS, and the kit's default for it is the
identity, with the noise σ of the phone's sensor model (:func:`kfkit.sensors.phone_board`)
(``data/calibration_phone-phyphox.json``):

- gyro bias 0: Android's ``TYPE_GYROSCOPE``, which phyphox reads, "MUST be calibrated and compensated while
  in use" (Android CDD §7.3.4; AOSP "Sensor types": base sensors carry bias and temperature compensation,
  ``TYPE_GYROSCOPE_UNCALIBRATED`` is the one without); phyphox on iOS reads CoreMotion's device-motion
  rotation rate, whose bias Core Motion removes. What is left is a few hundredths of °/s, which lab 02 measures.
- hard iron 0, soft iron I: phyphox reads the calibrated field (``TYPE_MAGNETIC_FIELD``, hard iron removed
  online; ``TYPE_MAGNETIC_FIELD_UNCALIBRATED`` only if an experiment asks; iOS: device motion's calibrated
  field), so an ellipsoid fit (lab 03) finds what the OS left, about 1 µT.
- accelerometer bias 0, scale 1: an assumption. The CDD (§7.3.1) only recommends calibrating the accelerometer
  in use, and iOS gives phyphox the raw accelerometer; a phone's six faces (lab 02) measure its offsets.

Student-saved phone calibrations (labs 02 and 03) replace it as for a board. :func:`label_rests` finds and
names the rests of a recording without labelled windows (a phyphox export), so labs 02 and 03 run on it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

from .frames import MAG_FIELD_LONDON, G
from .paths import bundled_calibration_path, data_dir, user_calibration_path
from .sensors import board as get_board

FACES = ("x_up", "x_down", "y_up", "y_down", "z_up", "z_down")

#: Allan deviation of flicker (1/f) noise at its flat minimum is √(2 ln 2 / π)·B ≈ 0.664·B
#: (IEEE Std 952-1997, Annex C), so the bias instability B is read as σ_min / 0.664.
BIAS_INSTABILITY_FACTOR = float(np.sqrt(2 * np.log(2) / np.pi))

NOISE_WINDOW_S = 10.0  # s: noise σ over windows this short leaves the bias wander out
MIN_MAG_SPREAD = 0.1  # smallest/largest principal variance of a usable magnetometer rotation
#: smallest principal standard deviation of a usable rotation's readings, as a fraction of the field norm B:
#: a tumble covering the sphere spreads B/√3 ≈ 0.58·B along every axis, a hemisphere 0.29·B along its axis, a
#: board turned about one axis ~0 along it, a board left still only its noise (~0.01·B)
MIN_MAG_COVERAGE = 0.1
ACCEL_SCALE_RANGE = (0.5, 2.0)  # what six faces can give: each axis must read beyond ±g/2 (accel_six_face)
MAX_SOFT_IRON_CONDITION = 1e3  # eigenvalue ratio of S beyond which the correction is (nearly) singular


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


# --- Allan deviation ----------------------------------------------------------------------------


def allan_deviation(x, rate_hz, taus=None):
    """Overlapping Allan deviation of a rate signal (IEEE Std 952-1997, Annex C).

    x (N,) or (N, k) samples at ``rate_hz``; taus cluster times (s), by default :func:`allan_taus` (~10 per decade
    from one sample to a fifth of the record). With N samples,
    the angle θ_j = Σ_{i<j} x_i / rate_hz for j = 0 … N (θ_0 = 0: N + 1 angles) and m samples per
    cluster (τ = m / rate_hz), summing every one of the N − 2m + 1 overlapping clusters:

        σ²(τ) = Σ_{k=0}^{N−2m} (θ_{k+2m} − 2θ_{k+m} + θ_k)² / (2 τ² (N − 2m + 1))

    Returns (taus (M,), adev (M,) or (M, k)) in the unit of x; τ are rounded to whole samples.
    """
    a = _samples(x, "x", min_samples=9, width=None)
    n = len(a)
    if not rate_hz > 0:
        raise CalibrationError(f"rate_hz must be positive, got {rate_hz}")
    if taus is None:
        m = np.round(allan_taus(n, rate_hz) * rate_hz).astype(int)
    else:
        m = np.unique(np.round(np.asarray(taus, dtype=float) * rate_hz).astype(int))
        if m.min() < 1 or 2 * m.max() >= n:
            raise CalibrationError(
                f"taus must lie between one sample ({1 / rate_hz:g} s) and under half the record "
                f"({n / 2 / rate_hz:g} s); got {np.min(taus):g} … {np.max(taus):g} s"
            )
    theta = np.vstack([np.zeros((1, a.shape[1])), np.cumsum(a, axis=0)]) / rate_hz
    adev = np.empty((len(m), a.shape[1]))
    for j, mj in enumerate(m):
        d = theta[2 * mj :] - 2 * theta[mj:-mj] + theta[: -2 * mj]
        tau = mj / rate_hz
        adev[j] = np.sqrt(np.sum(d**2, axis=0) / (2 * tau**2 * (len(theta) - 2 * mj)))
    taus_out = m / rate_hz
    return taus_out, (adev[:, 0] if np.ndim(x) == 1 else adev)


def allan_taus(n, rate_hz):
    """The cluster times :func:`allan_deviation` uses by default (s): about 10 per decade, whole samples, from one
    sample to a fifth of a record of ``n`` samples (longer τ have too few clusters to trust)."""
    decades = np.log10(n / 5)
    return np.unique(np.round(np.logspace(0, decades, int(10 * decades) + 1))) / rate_hz


def angle_random_walk(taus, adev):
    """White-noise density N read off the Allan curve at τ = 1 s (log-log interpolation).

    White noise gives σ(τ) = N/√τ (slope −½), so σ(1 s) = N: in rad/s/√Hz = rad/√s for a gyro
    (× 60·180/π for °/√h), m/s²/√Hz for an accelerometer. Check on the plot that the −½ slope
    passes through 1 s. Works per column for (M, k) curves.
    """
    taus, adev = np.asarray(taus, float), np.asarray(adev, float)
    if not taus.min() <= 1.0 <= taus.max():
        raise CalibrationError(
            f"the Allan curve must span τ = 1 s to read the angle random walk; it spans "
            f"{taus.min():g} … {taus.max():g} s"
        )
    logs = np.log(adev).reshape(len(taus), -1)
    out = np.array([np.exp(np.interp(0.0, np.log(taus), col)) for col in logs.T])
    return out if adev.ndim > 1 else float(out[0])


def bias_instability(taus, adev):
    """Bias instability B and where it was read: (B, τ_min) from the flat minimum of the Allan curve.

    B = σ_min / 0.664 (:data:`BIAS_INSTABILITY_FACTOR`, exact for flicker noise). Where the curve has
    no flat floor (white noise meeting a rate random walk, as in kfkit's simulator) this is the
    conventional read-out of the lowest point, not a flicker-noise level. The lowest of several noisy
    points reads a little low (about 10 % on a long floor); if τ_min is the longest τ the curve has not
    turned up yet and B is only an upper bound: record longer. Per column for (M, k).
    """
    taus, adev = np.asarray(taus, float), np.asarray(adev, float)
    k = np.argmin(adev, axis=0)
    return adev.min(axis=0) / BIAS_INSTABILITY_FACTOR, taus[k]


def allan_noise_fit(taus, adev):
    """(N, B, K): white-noise density, bias instability and rate random walk that best explain an Allan curve,

        σ²(τ) = N²/τ + (2 ln 2/π)·B² + K²·τ/3        (IEEE Std 952-1997, Annex C)

    fitted by non-negative least squares on σ², each point weighted by its precision: an Allan variance averages about
    T/τ independent clusters of a record T long, so its relative error grows as √τ, and the weight is 1/(σ²(τ)·√τ).
    Units for a gyro in rad/s: N rad/√s (= rad/s/√Hz), B rad/s, K rad/s/√s (the bias's random walk:
    its σ grows as K·√t). A term the curve does not show comes out 0: K needs the curve to turn up (slope +½) before
    its longest τ, so a short rest gives K = 0 (unmeasured, not zero). Per column for (M, k) curves.
    """
    taus, adev = np.asarray(taus, float), np.asarray(adev, float)
    var = adev.reshape(len(taus), -1) ** 2
    basis = np.column_stack([1.0 / taus, np.full(len(taus), BIAS_INSTABILITY_FACTOR**2), taus / 3.0])
    weight = 1.0 / (var * np.sqrt(taus)[:, None])
    out = np.array([np.sqrt(nnls(basis * w[:, None], v * w)[0]) for v, w in zip(var.T, weight.T)])  # (k, 3)
    return tuple(out[:, i] if adev.ndim > 1 else float(out[0, i]) for i in range(3))


# --- magnetometer ----------------------------------------------------------------------------------


def fit_mag_calibration(mag, field_norm=None, min_samples=50, min_spread=MIN_MAG_SPREAD):
    """Hard iron h (3,) µT and soft-iron correction S (3, 3) symmetric, with m_cal = S (m − h).

    Raw readings of a rotated board lie on an ellipsoid (m − h)ᵀ A (m − h) = 1. A linear least-squares
    fit of the general quadric  xᵀ Q x + pᵀ x + c = 0  (smallest right singular vector, on centred and
    scaled data) gives h = −Q⁻¹p/2 and A; then S = B·A^½ (symmetric square root) so calibrated
    norms equal the local field magnitude B (µT; default |MAG_FIELD_LONDON|). A rotation part of the
    soft iron cannot be seen from norms alone and stays in the mounting.

    Rows that are all NaN (no new magnetometer sample) are dropped. Raises :class:`CalibrationError`
    for too few samples, partly non-finite rows, or when the rotations cover too little of the sphere,
    judged against the field itself: the readings' standard deviation along each principal direction
    must reach :data:`MIN_MAG_COVERAGE` · B (a still board's noise cloud, or a board turned about one
    axis only, spreads ~0 along some direction however round the cloud is), and the smallest principal
    variance must reach ``min_spread`` of the largest (a board only turned flat gives a thin ellipse).
    """
    raw = np.asarray(mag, dtype=float)
    if raw.ndim == 2 and raw.shape[1] == 3:
        raw = raw[np.isfinite(raw).all(axis=1) | ~np.isnan(raw).all(axis=1)]  # rows with no new sample go
    m = _samples(raw, "mag", min_samples=min_samples)
    B = float(np.linalg.norm(MAG_FIELD_LONDON)) if field_norm is None else float(field_norm)
    centre, scale = m.mean(axis=0), m.std(axis=0).max()
    if scale == 0:
        raise CalibrationError("mag: all readings are equal: the board did not move")
    if not (np.isfinite(B) and B > 0):
        raise CalibrationError(f"field_norm must be the local field's magnitude in µT (positive), got {field_norm!r}")
    spread = np.linalg.eigvalsh(np.cov(m.T))
    sigma = np.sqrt(np.maximum(spread, 0.0))  # µT along the principal directions, smallest first
    if sigma[0] < MIN_MAG_COVERAGE * B:
        still = sigma[-1] < MIN_MAG_COVERAGE * B
        raise CalibrationError(
            f"mag: the rotations cover too little of the sphere: the readings spread only {sigma[0]:.2g} µT along "
            f"their narrowest direction (and {sigma[-1]:.2g} µT along "
            f"the widest), under {MIN_MAG_COVERAGE:.0%} of the {B:.3g} µT field: "
            + (
                "the board hardly turned (this is sensor noise around one reading). "
                if still
                else "the board turned about one axis only, so the field was never seen along that axis. "
            )
            + "Record again, turning the board slowly through every orientation — figure eights, on its side and "
            "upside down — for about a minute (and pass field_norm= your local field if it is far from London's)"
        )
    if spread[0] < min_spread * spread[-1]:
        raise CalibrationError(
            f"mag: the rotations cover too little of the sphere (smallest/largest spread "
            f"{spread[0] / spread[-1]:.3f} < {min_spread}): a hard/soft-iron fit needs the field seen from all "
            f"directions. Record again, turning the board slowly through every orientation — figure eights, on its "
            f"side and upside down — for about a minute"
        )
    u = (m - centre) / scale
    x, y, z = u.T
    design = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z, np.ones_like(x)])
    coef = np.linalg.svd(design, full_matrices=False)[2][-1]
    Q = np.array([[coef[0], coef[3], coef[4]], [coef[3], coef[1], coef[5]], [coef[4], coef[5], coef[2]]])
    p, c = coef[6:9], coef[9]
    h_u = -0.5 * np.linalg.solve(Q, p)
    k = h_u @ Q @ h_u - c  # (u − h)ᵀ Q (u − h) = k
    A_u = Q / k
    w, V = np.linalg.eigh(A_u)
    if w.min() <= 0:
        raise CalibrationError(
            "mag: the readings do not lie on an ellipsoid (the fit is not positive definite): "
            "record again with slow rotations through all orientations, away from steel and magnets"
        )
    S = B / scale * (V * np.sqrt(w)) @ V.T
    return centre + scale * h_u, S


def apply_mag_calibration(mag, hard_iron, soft_iron):
    """m_cal = S (m − h) row-wise, (N, 3) µT; NaN rows (no new sample) stay NaN."""
    return (np.asarray(mag, dtype=float) - np.asarray(hard_iron, float)) @ np.asarray(soft_iron, float).T


# --- the saved calibration ----------------------------------------------------------------------------


def _zeros():
    return [0.0, 0.0, 0.0]


@dataclass
class Calibration:
    """One board's calibration, body frame FRD, SI units (µT for the magnetometer).

    gyro_bias (rad/s), gyro_noise (rad/s, σ per sample at ``rate_hz``), gyro_bias_walk (rad/s/√s: the bias's
    random walk K, read on a long rest's Allan curve; 0 = not measured), accel_bias (m/s²),
    accel_scale (1), accel_noise (m/s², σ per sample at ``rate_hz``), mag_hard_iron (µT),
    mag_soft_iron (3×3), mag_noise (µT, σ per magnetometer sample), source (how it was made).
    """

    board: str = "nucleo-iks02a1"
    rate_hz: float = 104.0
    gyro_bias: list = field(default_factory=_zeros)
    gyro_noise: list = field(default_factory=_zeros)
    gyro_bias_walk: list = field(default_factory=_zeros)
    accel_bias: list = field(default_factory=_zeros)
    accel_scale: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    accel_noise: list = field(default_factory=_zeros)
    mag_hard_iron: list = field(default_factory=_zeros)
    mag_soft_iron: list = field(default_factory=lambda: np.eye(3).tolist())
    mag_noise: list = field(default_factory=_zeros)
    source: str = ""

    SHAPES = {
        "gyro_bias": (3,),
        "gyro_noise": (3,),
        "gyro_bias_walk": (3,),
        "accel_bias": (3,),
        "accel_scale": (3,),
        "accel_noise": (3,),
        "mag_hard_iron": (3,),
        "mag_soft_iron": (3, 3),
        "mag_noise": (3,),
    }

    def __post_init__(self):
        """Checks every field: shapes, finite, noise ≥ 0, accel_scale within :data:`ACCEL_SCALE_RANGE`,
        S symmetric positive definite with eigenvalue ratio ≤ :data:`MAX_SOFT_IRON_CONDITION`, rate_hz > 0."""
        if not isinstance(self.board, str) or not self.board:
            raise CalibrationError(f"Calibration.board must be a board name, got {self.board!r}")
        if not isinstance(self.source, str):
            raise CalibrationError(f"Calibration.source must be text, got {self.source!r}")
        if (
            isinstance(self.rate_hz, bool)
            or not isinstance(self.rate_hz, (int, float, np.number))
            or not (np.isfinite(self.rate_hz) and self.rate_hz > 0)
        ):
            raise CalibrationError(f"Calibration.rate_hz must be a positive finite number (Hz), got {self.rate_hz!r}")
        for name, shape in self.SHAPES.items():
            try:
                value = np.asarray(getattr(self, name), dtype=float)
            except (ValueError, TypeError):
                raise CalibrationError(
                    f"Calibration.{name}: expected numbers of shape {shape}, got {getattr(self, name)!r}"
                ) from None
            if value.shape != shape:
                raise CalibrationError(f"Calibration.{name}: expected shape {shape}, got {value.shape}")
            if not np.isfinite(value).all():
                raise CalibrationError(f"Calibration.{name}: holds NaN or inf: {value.tolist()}")
            setattr(
                self,
                name,
                [float(f"{v:.9g}") for v in value.ravel()]
                if value.ndim == 1
                else [[float(f"{v:.9g}") for v in row] for row in value],
            )
        lo, hi = ACCEL_SCALE_RANGE
        if not all(lo <= s <= hi for s in self.accel_scale):
            raise CalibrationError(
                f"Calibration.accel_scale must lie within {lo:g} … {hi:g} (1 = exact; it divides the "
                f"reading), got {self.accel_scale}"
            )
        for name in ("gyro_noise", "gyro_bias_walk", "accel_noise", "mag_noise"):
            if min(getattr(self, name)) < 0:
                raise CalibrationError(
                    f"Calibration.{name} is a noise level: it cannot be negative, got {getattr(self, name)}"
                )
        S = np.asarray(self.mag_soft_iron)
        w = np.linalg.eigvalsh((S + S.T) / 2)
        if (
            not np.allclose(S, S.T, rtol=1e-6, atol=1e-9 * np.abs(S).max())
            or w[0] <= 0
            or w[-1] > MAX_SOFT_IRON_CONDITION * w[0]
        ):
            raise CalibrationError(
                f"Calibration.mag_soft_iron must be symmetric positive definite and not (nearly) singular "
                f"(eigenvalues {', '.join(f'{x:.3g}' for x in w)}), got {self.mag_soft_iron}: "
                f"fit it again with fit_mag_calibration"
            )
        self.rate_hz = float(self.rate_hz)

    @property
    def gyro_density(self) -> np.ndarray:
        """The gyro's white-noise density N = σ/√rate (rad/s/√Hz = rad/√s), per axis: what a Q is made from."""
        return np.asarray(self.gyro_noise) / np.sqrt(self.rate_hz)

    def to_json(self) -> str:
        """The JSON text ``save`` writes (one field per line, 9 significant digits)."""
        return json.dumps(asdict(self), indent=1, ensure_ascii=False) + "\n"

    @classmethod
    def from_json(cls, text: str, where="calibration") -> Calibration:
        """A calibration file's text. Stricter than the constructor: every field but ``source`` must be
        there (no default stands in for a measurement) and the board must be one the kit knows. A noise σ
        of 0 means "not measured" (a board without magnetometer, a lab that saved before measuring it); a file from
        before ``gyro_bias_walk`` existed reads it as 0."""
        try:
            d = json.loads(text.removeprefix("\ufeff"))
        except json.JSONDecodeError as e:
            raise CalibrationError(f"{where}: not valid JSON ({e.msg}, line {e.lineno})") from None
        if not isinstance(d, dict):
            raise CalibrationError(f"{where}: expected a JSON object of calibration fields")
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise CalibrationError(f"{where}: unknown fields {', '.join(unknown)}")
        missing = [f for f in cls.__dataclass_fields__ if f not in d and f not in ("source", "gyro_bias_walk")]
        if missing:
            raise CalibrationError(
                f"{where}: missing fields {', '.join(missing)}: a calibration file needs every "
                f"measurement; save one again from labs 02/03 (Calibration.save)"
            )
        try:
            cal = cls(**d)
            get_board(cal.board)
            return cal
        except (CalibrationError, ValueError) as e:
            raise CalibrationError(f"{where}: {e}") from None

    def save(self, path=None) -> Path:
        """Write the JSON file; by default where :func:`load_calibration` looks for the student's own.

        A different calibration already there is kept as ``<name>.previous.json`` (one step back),
        so re-running a lab never silently loses the last one.
        """
        path = Path(path) if path is not None else user_calibration_path(self.board)
        path.parent.mkdir(parents=True, exist_ok=True)
        text = self.to_json()
        if path.exists() and path.read_text(encoding="utf-8") != text:
            path.replace(path.with_name(f"{path.stem}.previous.json"))
        path.write_text(text, encoding="utf-8", newline="\n")
        return path

    @classmethod
    def load(cls, path) -> Calibration:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no calibration file at {path}")
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as e:
            raise CalibrationError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
        return cls.from_json(text, where=str(path))

    def apply(self, rec_or_arrays):
        """Corrected body-frame (gyr, acc, mag) from a Recording or a tuple (gyr, acc[, mag]) of (N, 3).

        ω = ω_raw − b_g,  f = (f_raw − b_a) / s_a,  m = S (m_raw − h); mag is None when absent.
        """
        if hasattr(rec_or_arrays, "body"):
            rec = rec_or_arrays
            board = rec.meta.get("board")
            if board is not None and board != self.board:
                raise CalibrationError(
                    f"this calibration is for board {self.board!r}, the recording is from {board!r}: "
                    f"use load_calibration(board={board!r})"
                )
            arrays = (rec.body("gyr"), rec.body("acc"), rec.body("mag") if "mag" in rec.meta.get("mount", {}) else None)
        else:
            arrays = tuple(rec_or_arrays) + (None,) * (3 - len(tuple(rec_or_arrays)))
            if len(arrays) != 3:
                raise CalibrationError(f"apply: expected (gyr, acc) or (gyr, acc, mag), got {len(arrays)} arrays")
        gyr, acc, mag = (None if a is None else np.asarray(a, dtype=float) for a in arrays)
        for name, a in (("gyr", gyr), ("acc", acc), ("mag", mag)):
            if a is not None and (a.ndim not in (1, 2) or a.shape[-1] != 3):
                raise CalibrationError(f"apply: {name} must have shape (3,) or (N, 3), got {a.shape}")
        gyr = None if gyr is None else gyr - np.asarray(self.gyro_bias)
        acc = None if acc is None else (acc - np.asarray(self.accel_bias)) / np.asarray(self.accel_scale)
        mag = None if mag is None else apply_mag_calibration(mag, self.mag_hard_iron, self.mag_soft_iron)
        return gyr, acc, mag


def load_calibration(board="nucleo-iks02a1", path=None) -> Calibration:
    """The calibration labs 04/05 use: ``path`` if given, else the student's own (saved by labs 02/03,
    :func:`user_calibration_path`), else the bundled default for ``board`` in ``data/`` (a phone,
    ``"phone-phyphox"``: the identity its OS calibration leaves, see the module docstring)."""
    if path is not None:
        return Calibration.load(path)
    get_board(board)  # an unknown board name: ValueError naming the known ones
    for candidate in (user_calibration_path(board), bundled_calibration_path(board)):
        if candidate.exists():
            return Calibration.load(candidate)
    raise FileNotFoundError(
        f"no calibration for {board!r}: neither {user_calibration_path(board)} nor the bundled "
        f"{bundled_calibration_path(board)} exists. Rebuild the bundled one with: python -m kfkit data regenerate"
    )


def calibration_for(rec) -> Calibration:
    """The calibration that belongs to recording ``rec``.

    The kit's bundled recordings (files in ``data/``) are simulations of one unit per board, so they get
    that unit's bundled default, whatever the student has saved; any other recording (the student's own)
    gets :func:`load_calibration` for its board: their saved file, else the bundled default.
    """
    board = rec.meta.get("board")
    if rec.path is not None and Path(rec.path).resolve().parent == data_dir().resolve():
        return Calibration.load(bundled_calibration_path(board))
    return load_calibration(board)


def noise_at_rate(sigma, rate_from, rate_to):
    """White noise σ per sample measured at ``rate_from`` (Hz) scaled to ``rate_to``: σ·√(rate_to/rate_from).

    The sensor's property is the density N = σ/√rate; the per-sample σ grows with the output rate.
    """
    return np.asarray(sigma, dtype=float) * np.sqrt(rate_to / rate_from)


def calibrate(stationary, six_faces=None, mag_rotations=None, rate_hz=None, field_norm=None, source="") -> Calibration:
    """The labs' analysis in one call (kfkit's reference, used to build the bundled defaults).

    stationary     a Recording of the board at rest (its 'stationary' phase if labelled), level
    six_faces      a Recording with the six face phases (optional: else bias from the level rest, scale 1)
    mag_rotations  a Recording with the 'mag_rotations' phase (optional)
    rate_hz        the rate the noise σ is given at (default: the board's streaming rate)
    """
    board = get_board(stationary.meta["board"])
    rate = float(rate_hz or board.rate_hz)
    still = _phase_or_all(stationary, "stationary")
    gyr, acc = stationary.body("gyr")[still], stationary.body("acc")[still]
    window = min(len(gyr), int(NOISE_WINDOW_S * stationary.rate_hz))
    cal = {
        "board": board.name,
        "rate_hz": rate,
        "gyro_bias": gyro_bias(gyr),
        "gyro_noise": noise_at_rate(noise_std(gyr, window), stationary.rate_hz, rate),
        "gyro_bias_walk": allan_noise_fit(*allan_deviation(gyr, stationary.rate_hz))[2],
        "accel_noise": noise_at_rate(noise_std(acc, window), stationary.rate_hz, rate),
        "accel_bias": accel_bias(acc, [0.0, 0.0, -G]),
    }
    if six_faces is not None:
        faces = {f: six_faces.body("acc")[six_faces.phase(f)] for f in FACES}
        cal["accel_bias"], cal["accel_scale"] = accel_six_face(faces)
    if "mag" in stationary.meta.get("mount", {}):
        mag = stationary.body("mag")[still]
        cal["mag_noise"] = noise_std(mag[np.isfinite(mag).all(axis=1)])
    if mag_rotations is not None:
        mag = mag_rotations.body("mag")[_phase_or_all(mag_rotations, "mag_rotations")]
        cal["mag_hard_iron"], cal["mag_soft_iron"] = fit_mag_calibration(mag, field_norm)
    return Calibration(**cal, source=source)


def _phase_or_all(rec, label):
    return rec.phase(label) if any(p["label"] == label for p in rec.phases) else np.ones(len(rec), dtype=bool)
