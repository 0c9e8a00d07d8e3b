"""The linear Kalman filter and the batch runner every lab's filter reports through.

Textbook names throughout (x, P, F, B, H, Q, R; y innovation, S its covariance, K gain):

    predict   x⁻ = F x + B u              P⁻ = F P Fᵀ + Q
    update    y = z − H x⁻   S = H P⁻ Hᵀ + R   K = P⁻ Hᵀ S⁻¹
              x = x⁻ + K y   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ     (Joseph form)

A batch run does ``predict(u_k)`` then ``update(z_k)`` for every sample k, so x0, P0 describe
the state one step before the first sample. A measurement that is NaN is skipped (no update:
the filter coasts on its prediction), which is how gating and missing samples are handled.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FilterRun:
    """A filter's history over a recording, one row per sample.

    x  estimates after the update, (N, n) — or (N,) for a scalar filter
    P  their covariances, (N, n, n) — or (N,)
    y  innovations z − H x⁻, (N, m) — or (N,); NaN where no update was made
    S  innovation covariances, (N, m, m) — or (N,); NaN where no update was made
    """

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray


class KalmanFilter:
    """Linear Kalman filter with Joseph-form covariance update.

    x_k = F x_{k−1} + B u_k + w,  w ~ N(0, Q);    z_k = H x_k + v,  v ~ N(0, R).
    After :meth:`update`, ``y``, ``S`` and ``K`` hold that step's innovation, its
    covariance and the gain.
    """

    def __init__(self, F, H, Q, R, x0, P0, B=None):
        self.F = np.atleast_2d(np.asarray(F, dtype=float))
        self.H = np.atleast_2d(np.asarray(H, dtype=float))
        self.Q = np.atleast_2d(np.asarray(Q, dtype=float))
        self.R = np.atleast_2d(np.asarray(R, dtype=float))
        self.B = None if B is None else np.asarray(B, dtype=float).reshape(self.F.shape[0], -1)
        self.x = np.asarray(x0, dtype=float).reshape(-1).copy()
        self.P = np.atleast_2d(np.asarray(P0, dtype=float)).copy()
        n, m = self.F.shape[0], self.H.shape[0]
        shapes = {"F": (self.F, (n, n)), "H": (self.H, (m, n)), "Q": (self.Q, (n, n)), "R": (self.R, (m, m)),
                  "P0": (self.P, (n, n)), "x0": (self.x, (n,))}
        for name, (arr, shape) in shapes.items():
            if arr.shape != shape:
                raise ValueError(f"KalmanFilter: {name} has shape {arr.shape}, expected {shape} for {n} states and {m} measurements")
        self._I = np.eye(n)
        self.y = np.full(m, np.nan)
        self.S = np.full((m, m), np.nan)
        self.K = np.zeros((n, m))

    def predict(self, u=None):
        """x⁻ = F x + B u,  P⁻ = F P Fᵀ + Q."""
        self.x = self.F @ self.x
        if u is not None:
            if self.B is None:
                raise ValueError("KalmanFilter.predict got a control input u but the filter has no B matrix")
            self.x = self.x + self.B @ np.atleast_1d(u)
        self.P = self.F @ self.P @ self.F.T + self.Q
        return self.x

    def update(self, z):
        """Correct with measurement z; a NaN measurement is skipped (y, S set to NaN)."""
        z = np.atleast_1d(np.asarray(z, dtype=float))
        if np.isnan(z).any():
            self.y = np.full(self.H.shape[0], np.nan)
            self.S = np.full((self.H.shape[0],) * 2, np.nan)
            return self.x
        self.y = z - self.H @ self.x
        PHt = self.P @ self.H.T
        self.S = self.H @ PHt + self.R
        self.K = np.linalg.solve(self.S.T, PHt.T).T  # K = P Hᵀ S⁻¹ without forming S⁻¹
        self.x = self.x + self.K @ self.y
        IKH = self._I - self.K @ self.H
        self.P = IKH @ self.P @ IKH.T + self.K @ self.R @ self.K.T
        return self.x


def run_kf(kf: KalmanFilter, zs, us=None) -> FilterRun:
    """Run ``kf`` over measurements ``zs`` (N, m) and optional inputs ``us`` (N, …)."""
    zs = np.asarray(zs, dtype=float).reshape(len(zs), -1)
    n, m, N = kf.x.size, zs.shape[1], len(zs)
    out = FilterRun(np.empty((N, n)), np.empty((N, n, n)), np.empty((N, m)), np.empty((N, m, m)))
    for k in range(N):
        kf.predict(None if us is None else us[k])
        kf.update(zs[k])
        out.x[k], out.P[k], out.y[k], out.S[k] = kf.x, kf.P, kf.y, kf.S
    return out
