"""Error and consistency metrics: RMSE, wrapped angle errors, NEES, NIS, chi-square bounds,
BROAD attitude errors (total, heading, inclination).

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

from .frames import quat_conjugate, quat_multiply, wrap_angle


def rmse(estimate, truth, axis=0):
    """Root-mean-square error √mean((estimate − truth)²), ignoring NaN rows."""
    err = np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)
    return np.sqrt(np.nanmean(err**2, axis=axis))


def angle_error(estimate, truth):
    """estimate − truth wrapped to (−π, π] (rad): 179° vs −179° is 2°, not 358°."""
    return wrap_angle(np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float))


def angle_rmse_deg(estimate, truth, axis=0):
    """RMSE of the wrapped angle error, in degrees: √mean(wrap(estimate − truth)²) of angles in rad, NaN rows
    ignored (where the motion capture lost the markers). What the labs print as "roll RMSE 0.33°"."""
    return np.degrees(rmse(angle_error(estimate, truth), 0.0, axis=axis))


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


def _quat_array(q, name):
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"{name} must be quaternions w-x-y-z of shape (N, 4), got {q.shape}")
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def attitude_errors(q_est, q_true):
    """BROAD orientation errors (Laidig et al., Data 6(7), 2021) between quaternions (N, 4), w-x-y-z,
    body → navigation frame (both in the same navigation frame, NED or ENU: the result is the same).

    The error quaternion expressed in the navigation frame, q_e = q_est ⊗ q_true⁻¹, gives
        total        2·acos|w_e|              the whole rotation between the two attitudes
        heading      2·atan|z_e / w_e|        its part about the vertical axis
        inclination  2·acos√(w_e² + z_e²)     its part about horizontal axes (tilt error)
    each (N,) in rad; NaN rows (e.g. gaps in optical truth) stay NaN.
    """
    qe, qt = _quat_array(q_est, "q_est"), _quat_array(q_true, "q_true")
    if len(qe) != len(qt):
        raise ValueError(f"q_est has {len(qe)} rows but q_true has {len(qt)}")
    w, _, _, z = quat_multiply(qe, quat_conjugate(qt)).T  # q_true⁻¹ = q_true* (unit quaternion)
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        heading = 2.0 * np.arctan(np.abs(z / w))
    heading = np.where(w == 0, np.pi, heading)
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    nan = np.isnan(w)
    heading[nan] = np.nan
    return total, heading, inclination


def attitude_rmse(q_est, q_true, mask=None):
    """RMSE (rad) of :func:`attitude_errors` over ``mask`` (e.g. BROAD's movement phases),
    ignoring rows whose truth is NaN: dict with 'total', 'heading', 'inclination'."""
    errors = attitude_errors(q_est, q_true)
    keep = slice(None) if mask is None else np.asarray(mask, dtype=bool)
    return {name: float(rmse(e[keep], 0.0)) for name, e in zip(("total", "heading", "inclination"), errors)}
