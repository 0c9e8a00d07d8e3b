"""The magnetometer's hard- and soft-iron calibration (lab 03): m_cal = S (m − h), µT, body frame.

Raw readings of a rotated board lie on an ellipsoid (m − h)ᵀ A (m − h) = 1: :func:`fit_mag_calibration` fits it and
returns the hard iron h (3,) and the symmetric soft-iron correction S = B·A^½ (3, 3), so calibrated norms equal the
local field B; it refuses rotations that cover too little of the sphere (:data:`MIN_MAG_COVERAGE`,
:data:`MIN_MAG_SPREAD`). :func:`apply_mag_calibration` corrects readings row by row.
"""

from __future__ import annotations

import numpy as np

from .frames import MAG_FIELD_LONDON
from .rest_calibration import CalibrationError, _samples

MIN_MAG_SPREAD = 0.1  # smallest/largest principal variance of a usable magnetometer rotation
#: smallest principal standard deviation of a usable rotation's readings, as a fraction of the field norm B:
#: a tumble covering the sphere spreads B/√3 ≈ 0.58·B along every axis, a hemisphere 0.29·B along its axis, a
#: board turned about one axis ~0 along it, a board left still only its noise (~0.01·B)
MIN_MAG_COVERAGE = 0.1


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
