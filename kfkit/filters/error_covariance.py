"""The MEKF's 6×6 error covariance P of [δθ (attitude, rad), δb (gyro bias, rad/s)], kept as a tuple of its 36
floats, row by row (``P[6*i + j]``), and worked on with the arithmetic written out: on a 6×6 matrix one numpy call
costs about as much as a whole scalar update written in floats, and the filter would make a dozen of them a sample.

    propagate            P ← F P Fᵀ + Q,  F = [[I, −M], [0, I]],  Q = diag(q_θ I, q_b I)
    times_attitude_row   P Hᵀ for H = [h₀, h₁, h₂, 0, 0, 0]
    scalar_update        one scalar measurement given a = P Hᵀ: S, δx += K·innovation, P ← P − K aᵀ
    Consider             the blocks (tilt, bias) an update leaves alone (a Schmidt "consider" update)
    diagonal_S           (N, m) innovation variances → (N, m, m) diagonal S, NaN where no update was made

P stays symmetric: each function computes the upper triangle (21 values) and mirrors it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Consider(NamedTuple):
    """Which blocks of the error state a "consider" (Schmidt) update leaves alone: the tilt (δθ_N, δθ_E, components 0
    and 1) and the gyro bias (δb, components 3–5). Their gain is zero, their covariance stays, and their correlations
    with the rest are updated."""

    tilt: bool = False
    bias: bool = False


#: an ordinary update, one that leaves the bias alone, one that leaves the tilt alone, and one that leaves both
NOTHING_KEPT, BIAS, TILT, TILT_AND_BIAS = Consider(), Consider(bias=True), Consider(tilt=True), Consider(True, True)


def propagate(P, R, dt, q_angle, q_bias):
    """F P Fᵀ + Q for F = [[I, −M], [0, I]], M = R dt, and Q = diag(q_angle I, q_bias I): P a 36-tuple, R a 3×3
    matrix as a 9-tuple row by row. In blocks, with P = [[A, C], [Cᵀ, B]]: C ← C − M B,
    A ← A − M Cᵀ − C_new Mᵀ + q_angle I, B ← B + q_bias I."""
    (p00, p01, p02, p03, p04, p05,
     _, p11, p12, p13, p14, p15,
     _, _, p22, p23, p24, p25,
     _, _, _, p33, p34, p35,
     _, _, _, _, p44, p45,
     _, _, _, _, _, p55) = P  # fmt: skip
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R
    m00, m01, m02 = r00 * dt, r01 * dt, r02 * dt
    m10, m11, m12 = r10 * dt, r11 * dt, r12 * dt
    m20, m21, m22 = r20 * dt, r21 * dt, r22 * dt
    # C ← C − M B
    c03 = p03 - (m00 * p33 + m01 * p34 + m02 * p35)
    c04 = p04 - (m00 * p34 + m01 * p44 + m02 * p45)
    c05 = p05 - (m00 * p35 + m01 * p45 + m02 * p55)
    c13 = p13 - (m10 * p33 + m11 * p34 + m12 * p35)
    c14 = p14 - (m10 * p34 + m11 * p44 + m12 * p45)
    c15 = p15 - (m10 * p35 + m11 * p45 + m12 * p55)
    c23 = p23 - (m20 * p33 + m21 * p34 + m22 * p35)
    c24 = p24 - (m20 * p34 + m21 * p44 + m22 * p45)
    c25 = p25 - (m20 * p35 + m21 * p45 + m22 * p55)
    # A ← A − M Cᵀ (the old C) − C Mᵀ (the new C) + q_angle I
    a00 = p00 - (m00 * p03 + m01 * p04 + m02 * p05) - (c03 * m00 + c04 * m01 + c05 * m02) + q_angle
    a01 = p01 - (m00 * p13 + m01 * p14 + m02 * p15) - (c03 * m10 + c04 * m11 + c05 * m12)
    a02 = p02 - (m00 * p23 + m01 * p24 + m02 * p25) - (c03 * m20 + c04 * m21 + c05 * m22)
    a11 = p11 - (m10 * p13 + m11 * p14 + m12 * p15) - (c13 * m10 + c14 * m11 + c15 * m12) + q_angle
    a12 = p12 - (m10 * p23 + m11 * p24 + m12 * p25) - (c13 * m20 + c14 * m21 + c15 * m22)
    a22 = p22 - (m20 * p23 + m21 * p24 + m22 * p25) - (c23 * m20 + c24 * m21 + c25 * m22) + q_angle
    # B ← B + q_bias I
    b33, b44, b55 = p33 + q_bias, p44 + q_bias, p55 + q_bias
    return (a00, a01, a02, c03, c04, c05,
            a01, a11, a12, c13, c14, c15,
            a02, a12, a22, c23, c24, c25,
            c03, c13, c23, b33, p34, p35,
            c04, c14, c24, p34, b44, p45,
            c05, c15, c25, p35, p45, b55)  # fmt: skip


def times_attitude_row(P, h0, h1, h2):
    """P Hᵀ (a 6-tuple) for a measurement row H = [h0, h1, h2, 0, 0, 0] that sees the attitude error only."""
    (p00, p01, p02, p03, p04, p05,
     _, p11, p12, p13, p14, p15,
     _, _, p22, p23, p24, p25) = P[:18]  # fmt: skip
    return (
        h0 * p00 + h1 * p01 + h2 * p02,
        h0 * p01 + h1 * p11 + h2 * p12,
        h0 * p02 + h1 * p12 + h2 * p22,
        h0 * p03 + h1 * p13 + h2 * p23,
        h0 * p04 + h1 * p14 + h2 * p24,
        h0 * p05 + h1 * p15 + h2 * p25,
    )


def scalar_update(P, dx, a, hph, innov, r, kept_off=NOTHING_KEPT):
    """One scalar measurement, given a = P Hᵀ (6 floats) and H P Hᵀ: S = H P Hᵀ + r, K = a/S, δx += K·innov (dx a
    list, in place), P ← P − K aᵀ. The blocks ``kept_off`` marks (a :class:`Consider`) are left alone: K is zero
    there and their own covariance stays (a Schmidt update: P ← P − (a aᵀ − a_c a_cᵀ)/S, a_c = a on those blocks,
    keeps their correlations with the rest right). ``innov`` must already be corrected for the δx of the updates
    before it in the same sample. Returns (the new P, S)."""
    S = hph + r
    s = 1.0 / S
    a0, a1, a2, a3, a4, a5 = a
    k0, k1, k2, k3, k4, k5 = a0 * s, a1 * s, a2 * s, a3 * s, a4 * s, a5 * s
    (p00, p01, p02, p03, p04, p05,
     _, p11, p12, p13, p14, p15,
     _, _, p22, p23, p24, p25,
     _, _, _, p33, p34, p35,
     _, _, _, _, p44, p45,
     _, _, _, _, _, p55) = P  # fmt: skip
    # P ← P − K aᵀ, the upper triangle row by row
    n00, n01, n02 = p00 - k0 * a0, p01 - k0 * a1, p02 - k0 * a2
    n03, n04, n05 = p03 - k0 * a3, p04 - k0 * a4, p05 - k0 * a5
    n11, n12, n13 = p11 - k1 * a1, p12 - k1 * a2, p13 - k1 * a3
    n14, n15 = p14 - k1 * a4, p15 - k1 * a5
    n22, n23, n24, n25 = p22 - k2 * a2, p23 - k2 * a3, p24 - k2 * a4, p25 - k2 * a5
    n33, n34, n35 = p33 - k3 * a3, p34 - k3 * a4, p35 - k3 * a5
    n44, n45, n55 = p44 - k4 * a4, p45 - k4 * a5, p55 - k5 * a5
    if kept_off.tilt:
        n00, n01, n11 = p00, p01, p11
        k0 = k1 = 0.0
    if kept_off.bias:
        n33, n34, n35, n44, n45, n55 = p33, p34, p35, p44, p45, p55
        k3 = k4 = k5 = 0.0
        if kept_off.tilt:  # and their correlations: both blocks left alone
            n03, n04, n05, n13, n14, n15 = p03, p04, p05, p13, p14, p15
    dx[0] += k0 * innov
    dx[1] += k1 * innov
    dx[2] += k2 * innov
    dx[3] += k3 * innov
    dx[4] += k4 * innov
    dx[5] += k5 * innov
    return (n00, n01, n02, n03, n04, n05,
            n01, n11, n12, n13, n14, n15,
            n02, n12, n22, n23, n24, n25,
            n03, n13, n23, n33, n34, n35,
            n04, n14, n24, n34, n44, n45,
            n05, n15, n25, n35, n45, n55), S  # fmt: skip


def diagonal_S(variances):
    """(N, m) innovation variances (NaN: no update) → (N, m, m) diagonal S, NaN in the rows and columns of the
    updates not made."""
    S = variances[:, :, None] * np.eye(variances.shape[1])
    unused = np.isnan(variances)
    S[unused[:, :, None] | unused[:, None, :]] = np.nan
    return S
