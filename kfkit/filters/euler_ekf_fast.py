"""Lab 04's Euler EKF unrolled on floats: :class:`FastEulerAttitudeEKF`, ≈ 10× faster than the
reference :class:`~kfkit.filters.euler_ekf.EulerAttitudeEKF` (a loop over NumPy steps) and equal to it
to rounding (tests/test_attitude.py). :func:`kfkit.filters.estimate_attitude` runs this one.
"""

from __future__ import annotations

import math

import numpy as np

from ..frames import G, wrap_angle_f
from .attitude_run import AttitudeRun
from .euler_ekf import EulerAttitudeEKF, attitude_jacobian, jacobian_rows


class FastEulerAttitudeEKF(EulerAttitudeEKF):
    """:class:`EulerAttitudeEKF` (same settings, same ``step``) whose :meth:`run` is the unrolled loop."""

    def run(self, gyr, acc, mag=None, *, resume=False) -> AttitudeRun:
        """The reference ``run``'s result, computed on plain floats: gyr (N, 3) rad/s, acc (N, 3) m/s²,
        mag (N, 3) µT or None (NaN rows = no new sample); from the start, or the current state with ``resume=True``."""
        return _unrolled_loop(self, *self._start(gyr, acc, mag, resume))


def _unrolled_loop(ekf: FastEulerAttitudeEKF, gyr, acc, mag) -> AttitudeRun:
    """The Euler EKF over N samples in plain-float arithmetic.

    Same equations as :func:`euler_ekf_predict` / :func:`euler_ekf_update`; the update is done as
    sequential scalar updates (one measurement row at a time, H fixed at x⁻), which with a
    diagonal R gives exactly the batch update's x and P, and Σ e_i²/s_i = yᵀ S⁻¹ y for the NIS.
    Innovations y = z − h(x⁻) and the priors are stored; S = H P⁻ Hᵀ + R is formed afterwards in
    one vectorised pass. H is :func:`jacobian_rows`, the one copy :func:`attitude_jacobian` uses.
    """
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    dt = ekf.dt
    N = len(gyr)
    st_ = ekf.settings
    gq = st_.gyro_noise**2 * dt * dt
    ra0 = st_.accel_noise**2
    rm = st_.mag_noise**2
    gate = st_.accel_gate if st_.accel_gate is not None else math.inf
    ra_gated = ra0 * st_.accel_inflation
    mN, mE, mD = (float(v) for v in ekf.field_n)
    g = G
    W = gyr.tolist()
    A = acc.tolist()
    M = mag.tolist() if mag is not None else None
    phi, theta, psi = (float(v) for v in ekf.state.x)
    P = ekf.state.P
    p00, p01, p02, p11, p12, p22 = (
        float(P[0, 0]),
        float(P[0, 1]),
        float(P[0, 2]),
        float(P[1, 1]),
        float(P[1, 2]),
        float(P[2, 2]),
    )

    xs = [None] * N
    Ps = [None] * N
    priors = [None] * N
    ys = [None] * N
    nis = [0.0] * N
    gated_out = [False] * N
    mag_out = [False] * N
    for k in range(N):
        p, q, r = W[k]
        # ---- predict: x⁻ = x + f dt, P⁻ = F P Fᵀ + G Σ Gᵀ dt² -----------------------------
        sf, cf, st, ct = sin(phi), cos(phi), sin(theta), cos(theta)
        if -1e-9 < ct < 1e-9:
            ct = 1e-9 if ct >= 0 else -1e-9
        tt, ic = st / ct, 1.0 / ct
        u, v = q * sf + r * cf, q * cf - r * sf
        # F = I + dt·A with A = [[v tθ, u/cθ², 0], [−u, 0, 0], [v/cθ, u sθ/cθ², 0]]
        f00 = 1.0 + dt * v * tt
        f01 = dt * u * ic * ic
        f10 = -dt * u
        f20 = dt * v * ic
        f21 = dt * u * st * ic * ic
        phi += (p + u * tt) * dt
        theta += v * dt
        psi = wrap_angle_f(psi + u * ic * dt)
        # M = F P (rows), then P⁻ = M Fᵀ (symmetric, upper triangle)
        a0, a1, a2 = f00 * p00 + f01 * p01, f00 * p01 + f01 * p11, f00 * p02 + f01 * p12
        b0, b1, b2 = f10 * p00 + p01, f10 * p01 + p11, f10 * p02 + p12
        c0, c1, c2 = f20 * p00 + f21 * p01 + p02, f20 * p01 + f21 * p11 + p12, f20 * p02 + f21 * p12 + p22
        # Q = σ² dt² G Gᵀ, G = [[1, sφ tθ, cφ tθ], [0, cφ, −sφ], [0, sφ/cθ, cφ/cθ]]
        g01, g02, g21, g22 = sf * tt, cf * tt, sf * ic, cf * ic
        p00 = a0 * f00 + a1 * f01 + gq * (1.0 + g01 * g01 + g02 * g02)
        p01 = a0 * f10 + a1 + gq * (g01 * cf - g02 * sf)
        p02 = a0 * f20 + a1 * f21 + a2 + gq * (g01 * g21 + g02 * g22)
        p11 = b0 * f10 + b1 + gq
        p12 = b0 * f20 + b1 * f21 + b2 + gq * (cf * g21 - sf * g22)
        p22 = c0 * f20 + c1 * f21 + c2 + gq * (g21 * g21 + g22 * g22)
        priors[k] = (phi, theta, psi, p00, p01, p02, p11, p12, p22)

        # ---- update: sequential scalar rows with H at x⁻ ---------------------------------
        fx, fy, fz = A[k]
        sf, cf, st, ct = sin(phi), cos(phi), sin(theta), cos(theta)
        ra = ra0
        if abs(sqrt(fx * fx + fy * fy + fz * fz) - g) > gate:
            ra = ra_gated
            gated_out[k] = True
        sp, cp = sin(psi), cos(psi)
        H = jacobian_rows(sf, cf, st, ct, sp, cp, mN, mE, mD)
        rows = [  # (innovation z − h(x⁻), H row, variance)
            (fx - g * st, *H[0], ra),
            (fy + g * sf * ct, *H[1], ra),
            (fz + g * cf * ct, *H[2], ra),
        ]
        if M is not None:
            mx, my, mz = M[k]
            if mx == mx and my == my and mz == mz:  # not NaN
                ah = cp * mN + sp * mE  # the horizontal field along the heading
                rows.append((mx - ct * ah + st * mD, *H[3], rm))
                rows.append((my + H[5][0], *H[4], rm))  # h_y = −H[5][0]
                rows.append((mz - H[4][0], *H[5], rm))  # h_z = H[4][0]
                mag_out[k] = True
        d0 = d1 = d2 = 0.0
        s_nis = 0.0
        for y, h0, h1, h2, rv in rows:
            ph0 = p00 * h0 + p01 * h1 + p02 * h2
            ph1 = p01 * h0 + p11 * h1 + p12 * h2
            ph2 = p02 * h0 + p12 * h1 + p22 * h2
            s = h0 * ph0 + h1 * ph1 + h2 * ph2 + rv
            e = y - (h0 * d0 + h1 * d1 + h2 * d2)
            k0, k1, k2 = ph0 / s, ph1 / s, ph2 / s
            d0 += k0 * e
            d1 += k1 * e
            d2 += k2 * e
            p00 -= k0 * ph0
            p01 -= k0 * ph1
            p02 -= k0 * ph2
            p11 -= k1 * ph1
            p12 -= k1 * ph2
            p22 -= k2 * ph2
            s_nis += e * e / s
        phi += d0
        theta += d1
        psi = wrap_angle_f(psi + d2)
        ys[k] = [r_[0] for r_ in rows]
        nis[k] = s_nis
        xs[k] = (phi, theta, psi)
        Ps[k] = (p00, p01, p02, p11, p12, p22)

    ekf.state.x = np.array([phi, theta, psi])
    ekf.state.P = _sym3(np.array([Ps[-1]]))[0] if N else ekf.state.P
    euler = np.array(xs, dtype=float).reshape(N, 3)
    mag_used = np.array(mag_out, dtype=bool)
    gated = np.array(gated_out, dtype=bool)
    y = np.full((N, 6), np.nan)
    for k in range(N):
        y[k, : len(ys[k])] = ys[k]
    prior = np.array(priors, dtype=float).reshape(N, 9)
    x_prior, P_prior = prior[:, :3], _sym3(prior[:, 3:])
    r_acc = np.where(gated, ra_gated, ra0)
    S = _euler_innovation_cov(x_prior, P_prior, r_acc, rm, ekf.field_n, mag_used)
    return AttitudeRun(
        euler,
        _sym3(np.array(Ps, dtype=float).reshape(N, 6)),
        y,
        S,
        x_prior,
        P_prior,
        nis=np.array(nis),
        accel_gated=gated,
        mag_used=mag_used,
        mag_gated=np.zeros(N, dtype=bool),
        method=ekf.method,
    )


def _sym3(p):
    """(N, 6) upper triangles [p00, p01, p02, p11, p12, p22] → (N, 3, 3) symmetric matrices."""
    i, j = np.triu_indices(3)
    out = np.empty((len(p), 3, 3))
    out[:, i, j] = p
    out[:, j, i] = p
    return out


def _euler_innovation_cov(x_prior, P_prior, r_acc, r_mag, field_n, mag_used):
    """S_k = H(x⁻_k) P⁻_k H(x⁻_k)ᵀ + R_k, vectorised; NaN in the magnetometer block where unused."""
    N = len(x_prior)
    if N == 0:
        return np.empty((0, 6, 6))
    H = attitude_jacobian(x_prior, field_n)
    S = np.einsum("nij,njk,nlk->nil", H, P_prior, H)
    S[:, [0, 1, 2], [0, 1, 2]] += r_acc[:, None]
    S[:, [3, 4, 5], [3, 4, 5]] += r_mag
    S[~mag_used, 3:, :] = np.nan
    S[~mag_used, :, 3:] = np.nan
    return S
