"""Oracles for the noise of the virtual board and the virtual phone (used by tests/test_capture_*.py).

The white-noise density N of a datasheet, quantisation to the LSB and a bias random walk of density K
give the Allan variance σ²(τ) = (N² + q²/12/rate)/τ + K²τ/3. allantools checks the estimator of
kfkit.calibration and gives Greenhall's equivalent degrees of freedom for each point's chi-square
interval.
"""

import numpy as np
import pytest


def allan_curves(x, rate_hz):
    """(taus, σ(τ) (M, 3)) of kfkit.allan.allan_deviation, checked against allantools' overlapping ADEV."""
    allantools = pytest.importorskip("allantools")
    from kfkit.allan import allan_deviation

    taus, adev = allan_deviation(x, rate_hz)
    for axis in range(x.shape[1]):
        theirs = allantools.oadev(x[:, axis], rate=rate_hz, data_type="freq", taus=taus)
        np.testing.assert_allclose(theirs[1], adev[:, axis], rtol=1e-7)  # cumulative sums of 10⁴ values near g
    return taus, adev


def model_adev(taus, density, walk, lsb, rate_hz):
    """σ(τ) of white noise of density N (SI/√Hz), quantisation to the LSB q (white, q²/12 per sample) and a
    bias random walk of density K (SI/√s): σ² = (N² + q²/(12·rate))/τ + K²τ/3."""
    return np.sqrt((density**2 + lsb**2 / 12 / rate_hz) / taus + walk**2 * taus / 3)


def outside_chi2_interval(taus, adev, model, n, rate_hz, ci=0.999):
    """The τ (≤ a tenth of the record of n samples) where the Allan variance pooled over the axes lies outside its
    chi-square interval around the model; edf: Greenhall's, the smaller of white and random-walk noise, × axes."""
    allantools = pytest.importorskip("allantools")
    pooled = np.sqrt(np.mean(adev**2, axis=1))
    bad = []
    for tau, got, want in zip(taus, pooled, model):
        m = int(round(tau * rate_hz))
        if m > n / 10:
            continue
        edf = adev.shape[1] * min(
            allantools.edf_greenhall(alpha=a, d=2, m=m, N=n + 1, overlapping=True) for a in (0, -2)
        )
        lo, hi = allantools.confidence_interval(want, edf, ci=ci)
        if not lo <= got <= hi:
            bad.append((round(float(tau), 2), float(got / want)))
    return bad


def loglog_slope(taus, adev, lo, hi):
    """Slope of log σ(τ) (pooled over the axes) against log τ for lo ≤ τ ≤ hi (s)."""
    keep = (taus >= lo) & (taus <= hi)
    assert keep.sum() >= 4, (lo, hi)
    return np.polyfit(np.log(taus[keep]), np.log(np.sqrt(np.mean(adev[keep] ** 2, axis=1))), 1)[0]
