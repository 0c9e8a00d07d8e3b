"""Sequential scalar measurement updates of an error-state filter, with "consider" (Schmidt) components: what the
MEKF's updates share. One scalar measurement at a time needs no matrix inverse; a consider update leaves chosen
components of the state alone while keeping the covariance right.

    Consider, consider   the masks of the components an update leaves alone
    scalar_update        one scalar measurement: S, δx += K·innovation, P ← P − K aᵀ (masked)
    diagonal_S           (N, m) innovation variances → (N, m, m) diagonal S, NaN where no update was made
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Consider(NamedTuple):
    """Which error-state components a "consider" (Schmidt) update leaves alone: keep_x (n,) is 0 on them and 1
    elsewhere (the gain's mask), keep_P (n×n) is 0 where both the row and the column are left alone (the
    covariance update's mask: their covariance stays, their correlations with the rest are updated)."""

    keep_x: np.ndarray
    keep_P: np.ndarray


def consider(*components, n=6):
    """The :class:`Consider` masks that leave ``components`` (indices of an n-element error state) alone."""
    left = np.zeros(n)
    left[list(components)] = 1.0
    return Consider(1.0 - left, 1.0 - np.outer(left, left))


def scalar_update(P, dx, a, hph, innov, r, kept_off=None):
    """One scalar measurement, given a = P Hᵀ (n,) and H P Hᵀ: S = H P Hᵀ + r, δx += K·innov (in place) with
    K = a/S, P ← P − a aᵀ/S. The components marked in ``kept_off`` (a :class:`Consider`) are left alone: K is zero
    there and P ← P − (a aᵀ − a_c a_cᵀ)/S with a_c = a on those components (a Schmidt update: their covariance
    stays, their correlations with the rest are kept right). ``innov`` must already be corrected for the δx of the
    updates before it in the same sample. Returns (the new P, S)."""
    S = float(hph) + r
    k = a * (1.0 / S)
    k_aT = k[:, None] * a  # K aᵀ = a aᵀ / S
    if kept_off is None:
        dx += k * innov
        return P - k_aT, S
    dx += k * (kept_off.keep_x * innov)
    return P - k_aT * kept_off.keep_P, S


def diagonal_S(variances):
    """(N, m) innovation variances (NaN: no update) → (N, m, m) diagonal S, NaN in the rows and columns of the
    updates not made."""
    S = variances[:, :, None] * np.eye(variances.shape[1])
    unused = np.isnan(variances)
    S[unused[:, :, None] | unused[:, None, :]] = np.nan
    return S
