"""Error and consistency metrics: RMSE, wrapped angle errors, NEES, NIS, chi-square bounds.

For a consistent filter the normalised estimation error squared
    NEES_k = e_kᵀ P_k⁻¹ e_k,   e_k = x̂_k − x_k            (n states)
and the normalised innovation squared
    NIS_k  = y_kᵀ S_k⁻¹ y_k                               (m measurements)
are χ²-distributed with n and m degrees of freedom; their average over N steps, times N,
is χ² with N·n (or N·m) degrees of freedom, which gives the bounds of :func:`chi2_bounds`.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from .frames import wrap_angle


def rmse(estimate, truth, axis=0):
    """Root-mean-square error √mean((estimate − truth)²), ignoring NaN rows."""
    err = np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)
    return np.sqrt(np.nanmean(err ** 2, axis=axis))


def angle_error(estimate, truth):
    """estimate − truth wrapped to (−π, π] (rad): 179° vs −179° is 2°, not 358°."""
    return wrap_angle(np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float))


def _as_vectors(v, M):
    """Reshape scalar-filter histories (N,) / (N,) to (N, 1) / (N, 1, 1)."""
    v = np.asarray(v, dtype=float)
    M = np.asarray(M, dtype=float)
    if v.ndim == 1:
        v, M = v[:, None], M.reshape(len(M), 1, 1)
    return v, M


def nees(err, P):
    """NEES_k = e_kᵀ P_k⁻¹ e_k for errors (N, n) and covariances (N, n, n); (N,) and (N,) for scalars."""
    e, P = _as_vectors(err, P)
    return np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])


def nis(y, S):
    """NIS_k = y_kᵀ S_k⁻¹ y_k; NaN where no update was made."""
    return nees(y, S)


def chi2_bounds(dof, n, alpha=0.05):
    """Two-sided (1 − alpha) bounds for the average of n independent χ²(dof) values.

    Returns (lower, upper) = (χ²⁻¹(α/2; n·dof), χ²⁻¹(1 − α/2; n·dof)) / n.
    With n = 1 these are the bounds for a single NEES or NIS value.
    """
    return chi2.ppf(alpha / 2, n * dof) / n, chi2.ppf(1 - alpha / 2, n * dof) / n


def fraction_inside(values, dof, alpha=0.05):
    """Fraction of single NEES/NIS values inside their per-step (1 − alpha) χ²(dof) bounds."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    lo, hi = chi2_bounds(dof, 1, alpha)
    return float(np.mean((v >= lo) & (v <= hi)))
