"""The filter contract (:class:`Step`, :class:`FilterRun`) and the linear Kalman filter.

Textbook names throughout (x, P, F, B, H, Q, R; y innovation, S its covariance, K gain):

    predict   x⁻ = F x + B u              P⁻ = F P Fᵀ + Q
    update    y = z − H x⁻   S = H P⁻ Hᵀ + R   K = P⁻ Hᵀ S⁻¹
              x = x⁻ + K y   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ     (Joseph form)

``step(z_k, u_k)`` does ``predict(u_k)`` then ``update(z_k)`` and ``run`` does a step for every
sample k, so x0, P0 describe the state one step before the first sample. A measurement that is NaN is skipped (no update:
the filter coasts on its prediction), which is how gating and missing samples are handled.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np


class Step(NamedTuple):
    """What one ``step`` of any kfkit filter returns (unpacks as ``x, P, y, S = f.step(...)``).

    x  state after the update, (n,)         P  its covariance, (n, n)
    y  innovation z − h(x⁻), (m,)           S  its covariance, (m, m); y and S are NaN where no update was made

    Scalar filters (lab 01) return floats in the same places.
    """

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray


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


def configure(settings_cls, settings, changes, owner):
    """The settings a filter runs with: ``settings`` (default ``settings_cls()``) with the keyword
    ``changes`` applied, as VQF's ``params`` + keyword overrides. Unknown names are an error."""
    base = settings_cls() if settings is None else settings
    if not isinstance(base, settings_cls):
        raise TypeError(f"{owner}: settings must be a {settings_cls.__name__}, got {type(base).__name__}")
    names = [f.name for f in fields(settings_cls)]
    unknown = sorted(set(changes) - set(names))
    if unknown:
        raise TypeError(f"{owner}: unknown setting {', '.join(unknown)}; {settings_cls.__name__} has {', '.join(names)}")
    return replace(base, **changes) if changes else base


def require_positive(owner, zero_ok=(), none_ok=(), **values):
    """Raise ValueError naming the first value that is not a finite number > 0 (≥ 0 for names in
    ``zero_ok``; None allowed for names in ``none_ok``)."""
    for name, value in values.items():
        if value is None and name in none_ok:
            continue
        ok = isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(value) and \
            (value >= 0 if name in zero_ok else value > 0)
        if not ok:
            what = "a number ≥ 0" if name in zero_ok else "a positive number"
            raise ValueError(f"{owner}: {name} must be {what}{' or None' if name in none_ok else ''}, got {value!r}")


class KalmanFilter:
    """Linear Kalman filter with Joseph-form covariance update.

    x_k = F x_{k−1} + B u_k + w,  w ~ N(0, Q);    z_k = H x_k + v,  v ~ N(0, R).
    After :meth:`update`, ``y``, ``S`` and ``K`` hold that step's innovation, its
    covariance and the gain. ``step`` = predict + update → :class:`Step`; ``run`` = a step per
    sample → :class:`FilterRun`.
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

    def step(self, z, u=None) -> Step:
        """One :meth:`predict` (with input u, if any) and one :meth:`update` with z → Step(x, P, y, S).

        Every method assigns new arrays (nothing is changed in place), so the Step holds this
        step's values, not views that the next step would overwrite.
        """
        self.predict(u)
        self.update(z)
        return Step(self.x, self.P, self.y, self.S)

    def run(self, zs, us=None) -> FilterRun:
        """:meth:`step` over measurements ``zs`` (N, m) and optional inputs ``us`` (N, …), from the current state."""
        zs = np.asarray(zs, dtype=float).reshape(len(zs), -1)
        n, m, N = self.x.size, zs.shape[1], len(zs)
        out = FilterRun(np.empty((N, n)), np.empty((N, n, n)), np.empty((N, m)), np.empty((N, m, m)))
        for k in range(N):
            out.x[k], out.P[k], out.y[k], out.S[k] = self.step(zs[k], None if us is None else us[k])
        return out
