"""Oracles for recordings of the virtual board (used by tests/test_capture_*.py and tests/test_calibration.py).

The virtual board is, by default, the simulated unit the bundled recordings come from. Its truth is taken
here from kfkit.unit_errors (not from kfkit.capture.virtual, the code under test), turned into the body frame
the labs work in, with the standard uncertainties of the labs' estimates of it:

- a linear estimate Σ cᵢ xᵢ of samples xᵢ = truth + wᵢ + W(tᵢ), with white noise wᵢ of σ per sample and a bias
  random walk W of density K that starts at 0 when the board starts: Var = σ² Σ cᵢ² + K² Σₖ Δtₖ Cₖ², with
  Cₖ = Σ_{tᵢ ≥ tₖ} cᵢ (W(t) = ∫ dW: each increment is shared by every later sample);
- the ellipsoid fit (hard iron h, symmetric S): the linearised covariance σ² (JᵀJ)⁻¹ of the residuals
  ‖S(mᵢ − h)‖ − B at the truth.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from kfkit.frames import G, mount_matrix
from kfkit.sensors import board as get_board
from kfkit.unit_errors import BOARD_UNITS

#: the simulated units (kfkit.unit_errors: what the bundled recordings and the virtual boards are made with)
UNITS = BOARD_UNITS


def body_truth(rec) -> dict:
    """The unit of ``rec``'s board in the body frame of ``rec``'s mounting (a signed permutation per sensor):
    gyro_bias (rad/s), accel_bias (m/s²), accel_scale, and for a magnetometer mag_hard_iron (µT) and the soft-iron
    correction mag_S = (M W Mᵀ)⁻¹ an exact fit finds; the walks K as gyro_bias_rw, accel_bias_rw."""
    unit = UNITS[rec.meta["board"]]
    M = {k: mount_matrix(v) for k, v in rec.meta["mount"].items()}
    truth = {
        "gyro_bias": M["gyr"] @ np.asarray(unit["gyro_bias"]),
        "accel_bias": M["acc"] @ np.asarray(unit["accel_bias"]),
        "accel_scale": np.abs(M["acc"]) @ np.asarray(unit["accel_scale"]),
        "gyro_bias_rw": unit["gyro_bias_rw"],
        "accel_bias_rw": unit["accel_bias_rw"],
    }
    if "mag" in M:
        truth["mag_hard_iron"] = M["mag"] @ np.asarray(unit["mag_hard_iron"])
        truth["mag_S"] = np.linalg.inv(M["mag"] @ np.asarray(unit["mag_soft_iron"]) @ M["mag"].T)
    return truth


def sample_sigma(rec, sensor) -> float:
    """Per-sample white noise σ of ``sensor`` ('gyr', 'acc', 'mag') at ``rec``'s rate: the datasheet's (kfkit.sensors)
    with rounding to counts, LSB²/12."""
    spec = getattr(get_board(rec.meta["board"]), {"gyr": "gyro", "acc": "accel", "mag": "mag"}[sensor])
    return float(np.hypot(spec.noise_std(rec.rate_hz), rec.meta["sensors"][sensor]["sensitivity"] / np.sqrt(12)))


def linear_estimate_sd(t, c, sigma, walk):
    """Standard deviation of Σ cᵢ xᵢ over samples at times t (s from the board's start) with white noise σ per
    sample and a bias walk of density ``walk`` (module docstring)."""
    order = np.argsort(t)
    t, c = np.asarray(t, float)[order], np.asarray(c, float)[order]
    C = np.cumsum(c[::-1])[::-1]  # Cₖ = Σ_{i ≥ k} cᵢ
    dt = np.diff(np.concatenate([[0.0], t]))
    return float(np.sqrt(sigma**2 * np.sum(c**2) + walk**2 * np.sum(dt * C**2)))


def walk_times(rec):
    """The times the board's bias walk has stepped to at each row: one step per sample, the first at sample 0."""
    return rec.t + 1.0 / rec.rate_hz


def mean_sd(rec, mask, sensor, walk):
    """Standard deviation of the mean of ``sensor`` over the rows ``mask`` of ``rec`` (per axis: the same)."""
    n = int(mask.sum())
    return linear_estimate_sd(walk_times(rec)[mask], np.full(n, 1.0 / n), sample_sigma(rec, sensor), walk)


def six_face_target(rec, motion, faces=("x", "y", "z")):
    """What the six-face estimator b = (a⁺ + a⁻)/2, s = (a⁺ − a⁻)/(2g) (body, per axis) converges to on ``rec``, the
    virtual board playing ``motion``: with f̄± the mean true specific force (scipy's rotations) on the faces with
    the axis up/down, b + s ⊙ (f̄⁺ + f̄⁻)/2 and s ⊙ (f̄⁺ − f̄⁻)/(2g): the unit's b and s, moved by the tilt of the
    simulated table. Returns (bias, scale, sd_bias, sd_scale)."""
    truth = body_truth(rec)
    euler = motion.euler[: len(rec)]
    R_nb = Rotation.from_euler("ZYX", euler[:, ::-1]).as_matrix()
    f_b = np.einsum("nji,j->ni", R_nb, [0.0, 0.0, -G])  # R_bn [0, 0, −g]
    sigma, t = sample_sigma(rec, "acc"), walk_times(rec)
    bias, scale, sd_b, sd_s = (np.empty(3) for _ in range(4))
    for i, axis in enumerate(faces):
        up, down = rec.phase(f"{axis}_up"), rec.phase(f"{axis}_down")
        fp, fm = f_b[up, i].mean(), f_b[down, i].mean()
        bias[i] = truth["accel_bias"][i] + truth["accel_scale"][i] * (fp + fm) / 2
        scale[i] = truth["accel_scale"][i] * (fp - fm) / (2 * G)
        both = up | down
        c = np.where(up, 1.0 / up.sum(), 0.0) + np.where(down, -1.0 / down.sum(), 0.0)  # a⁺ − a⁻ weights
        sd_s[i] = linear_estimate_sd(t[both], c[both] / (2 * G), sigma, truth["accel_bias_rw"])
        sd_b[i] = linear_estimate_sd(t[both], np.abs(c[both]) / 2, sigma, truth["accel_bias_rw"])
    return bias, scale, sd_b, sd_s


def mag_fit_sd(mag, h, S, sigma):
    """Standard deviations of an ellipsoid fit (h (3,), S (3, 3) symmetric) of ``mag`` (N, 3, µT; rows with a sample)
    with white noise σ per axis, from the linearised residuals rᵢ = ‖S(mᵢ − h)‖ − B at (h, S):
    ∂r/∂h = −S u, ∂r/∂S_ab = u_a d_b + u_b d_a (a ≠ b), u_a d_a (a = b), with d = m − h, u = S d/‖S d‖; each rᵢ has
    variance σ²‖S u‖². Returns (sd of h (3,), sd of S (3, 3))."""
    d = mag - h
    v = d @ S.T
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    pairs = [(a, b) for a in range(3) for b in range(a, 3)]
    J = np.column_stack([-(u @ S)] + [u[:, a] * d[:, b] + (u[:, b] * d[:, a] if a != b else 0.0) for a, b in pairs])
    weight = 1.0 / (sigma**2 * np.sum((u @ S) ** 2, axis=1))
    sd = np.sqrt(np.diag(np.linalg.inv(J.T @ (J * weight[:, None]))))
    sd_S = np.zeros((3, 3))
    for k, (a, b) in enumerate(pairs):
        sd_S[a, b] = sd_S[b, a] = sd[3 + k]
    return sd[:3], sd_S


def assert_mag_fit_within(rec, mag, h, S, k=4.0):
    """Assert a fit (h, S) of ``rec``'s body-frame magnetometer ``mag`` (N, 3, µT; NaN rows = no sample) lies within
    ``k`` of its own linearised standard deviations (:func:`mag_fit_sd`) of the simulated unit's hard and soft iron."""
    truth = body_truth(rec)
    fresh = np.isfinite(mag[:, 0])
    sd_h, sd_S = mag_fit_sd(mag[fresh], truth["mag_hard_iron"], truth["mag_S"], sample_sigma(rec, "mag"))
    assert np.all(np.abs(h - truth["mag_hard_iron"]) < k * sd_h), (h - truth["mag_hard_iron"]) / sd_h
    assert np.all(np.abs(S - truth["mag_S"]) < k * sd_S), (S - truth["mag_S"]) / sd_S
