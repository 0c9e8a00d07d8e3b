"""The linear Kalman filter, after the kit's filter contract (:mod:`kfkit.filters.contract`).

Textbook names throughout (x, P, F, B, H, Q, R; y innovation, S its covariance, K gain):

    predict   x⁻ = F x + B u              P⁻ = F P Fᵀ + Q
    update    y = z − H x⁻   S = H P⁻ Hᵀ + R   K = P⁻ Hᵀ S⁻¹
              x = x⁻ + K y   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ     (Joseph form)

``step(z_k, u_k)`` does ``predict(u_k)`` then ``update(z_k)`` and ``run`` does a step for every
sample k, so x0, P0 describe the state one step before the first sample. A measurement that is NaN is skipped
(no update: the filter coasts on its prediction), which is how gating and missing samples are handled.
"""

from __future__ import annotations

import numpy as np

from .contract import FilterRun, State, Step, shaped


class KalmanFilter:
    """Linear Kalman filter with Joseph-form covariance update (a :class:`~kfkit.filters.contract.Filter`).

    x_k = F x_{k−1} + B u_k + w,  w ~ N(0, Q);    z_k = H x_k + v,  v ~ N(0, R).
    x0, P0 are the start, one step before the first sample. After :meth:`update`, ``y``, ``S`` and ``K`` hold that
    step's innovation, its covariance and the gain; ``x`` and ``P`` read the :class:`State`. ``step`` = predict +
    update → :class:`Step`; ``run`` = a step per sample → :class:`FilterRun`.
    """

    def __init__(self, F, H, Q, R, x0, P0, B=None):
        self.F = np.atleast_2d(np.asarray(F, dtype=float))
        self.H = np.atleast_2d(np.asarray(H, dtype=float))
        self.Q = np.atleast_2d(np.asarray(Q, dtype=float))
        self.R = np.atleast_2d(np.asarray(R, dtype=float))
        self.B = None if B is None else np.asarray(B, dtype=float).reshape(self.F.shape[0], -1)
        n, m = self.F.shape[0], self.H.shape[0]
        self._x0, self._P0 = (
            np.asarray(x0, dtype=float).reshape(-1).copy(),
            np.atleast_2d(np.asarray(P0, dtype=float)).copy(),
        )
        shapes = {
            "F": (self.F, (n, n)),
            "H": (self.H, (m, n)),
            "Q": (self.Q, (n, n)),
            "R": (self.R, (m, m)),
            "P0": (self._P0, (n, n)),
            "x0": (self._x0, (n,)),
        }
        for name, (arr, shape) in shapes.items():
            if arr.shape != shape:
                raise ValueError(
                    f"KalmanFilter: {name} has shape {arr.shape}, expected {shape} for {n} states and {m} measurements"
                )
        self._I = np.eye(n)
        self.reset()

    @property
    def x(self) -> np.ndarray:
        return self.state.x

    @property
    def P(self) -> np.ndarray:
        return self.state.P

    def reset(self, x0=None, P0=None):
        """State ← the start (x0, P0); a given x0 or P0 replaces the start's; y, S NaN and K 0 again."""
        n, m = self.F.shape[0], self.H.shape[0]
        if x0 is not None:
            self._x0 = shaped("KalmanFilter", "x0", x0, (n,))
        if P0 is not None:
            self._P0 = shaped("KalmanFilter", "P0", P0, (n, n))
        self.state = State(self._x0.copy(), self._P0.copy())
        self.y = np.full(m, np.nan)
        self.S = np.full((m, m), np.nan)
        self.K = np.zeros((n, m))

    def predict(self, u=None):
        """x⁻ = F x + B u,  P⁻ = F P Fᵀ + Q."""
        s = self.state
        x = self.F @ s.x
        if u is not None:
            if self.B is None:
                raise ValueError("KalmanFilter.predict got a control input u but the filter has no B matrix")
            x = x + self.B @ np.atleast_1d(u)
        s.x, s.P = x, self.F @ s.P @ self.F.T + self.Q
        return s.x

    def update(self, z):
        """Correct with measurement z; a NaN measurement is skipped (y, S set to NaN)."""
        s = self.state
        z = np.atleast_1d(np.asarray(z, dtype=float))
        if np.isnan(z).any():
            self.y = np.full(self.H.shape[0], np.nan)
            self.S = np.full((self.H.shape[0],) * 2, np.nan)
            return s.x
        self.y = z - self.H @ s.x
        PHt = s.P @ self.H.T
        self.S = self.H @ PHt + self.R
        self.K = np.linalg.solve(self.S.T, PHt.T).T  # K = P Hᵀ S⁻¹ without forming S⁻¹
        IKH = self._I - self.K @ self.H
        s.x, s.P = s.x + self.K @ self.y, IKH @ s.P @ IKH.T + self.K @ self.R @ self.K.T
        return s.x

    def step(self, z, u=None) -> Step:
        """One :meth:`predict` (with input u, if any) and one :meth:`update` with z → Step.

        Every method assigns new arrays (nothing is changed in place), so the Step holds this
        step's values, not views that the next step would overwrite.
        """
        x_prior = self.predict(u)
        P_prior = self.state.P
        self.update(z)
        return Step(self.state.x, self.state.P, self.y, self.S, x_prior, P_prior)

    def run(self, zs, us=None, *, resume=False) -> FilterRun:
        """:meth:`step` over measurements ``zs`` (N, m) and optional inputs ``us`` (N, …): from the start, or from
        the current state with ``resume=True``."""
        if not resume:
            self.reset()
        zs = np.asarray(zs, dtype=float).reshape(len(zs), -1)
        n, m, N = self.F.shape[0], zs.shape[1], len(zs)
        out = FilterRun(
            np.empty((N, n)),
            np.empty((N, n, n)),
            np.empty((N, m)),
            np.empty((N, m, m)),
            np.empty((N, n)),
            np.empty((N, n, n)),
        )
        for k in range(N):
            s = self.step(zs[k], None if us is None else us[k])
            out.x[k], out.P[k], out.y[k], out.S[k], out.x_prior[k], out.P_prior[k] = (
                s.x,
                s.P,
                s.y,
                s.S,
                s.x_prior,
                s.P_prior,
            )
        return out
