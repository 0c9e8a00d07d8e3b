"""The Allan deviation of a rate signal and the noise terms read off it (lab 02; IEEE Std 952-1997, Annex C).

:func:`allan_deviation` (overlapping, from the integrated angle θ) at the cluster times :func:`allan_taus`; the
white-noise density N where the curve crosses τ = 1 s (:func:`angle_random_walk`), the bias instability B from its
flat minimum (:func:`bias_instability`), and N, B and the rate random walk K fitted together
(:func:`allan_noise_fit`):

    σ²(τ) = N²/τ + (2 ln 2/π)·B² + K²·τ/3

In the signal's units: for a gyro in rad/s, N in rad/√s (= rad/s/√Hz), B in rad/s, K in rad/s/√s.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from .rest_calibration import CalibrationError, _samples

#: Allan deviation of flicker (1/f) noise at its flat minimum is √(2 ln 2 / π)·B ≈ 0.664·B
#: (IEEE Std 952-1997, Annex C), so the bias instability B is read as σ_min / 0.664.
BIAS_INSTABILITY_FACTOR = float(np.sqrt(2 * np.log(2) / np.pi))


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
