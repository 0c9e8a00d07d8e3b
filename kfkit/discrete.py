"""Continuous-time models made discrete over a sample interval: exact, not Euler's first order.

    ẋ = A x + B u + w,   E[w(t) w(τ)ᵀ] = Qc δ(t − τ)     (u held constant over each interval: zero-order hold)
    x_{k+1} = Ad x_k + Bd u_k + w_k,   E[w_k w_kᵀ] = Qd

:func:`discretize` gives Ad, Bd and Qd for any linear model (lab 06's bicycle model); :func:`angle_bias_process_noise`
is the same integral written out for the [angle, gyro bias] model of labs 01, 04 and 05, fed with the gyro noise
lab 02 measures on its Allan curve (white-noise density N, rate random walk K).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm


def discretize(A, B, dt, Qc):
    """Exact discretisation over a sample interval ``dt`` (s): (Ad, Bd, Qd).

    Zero-order hold on the input: expm([[A, B], [0, 0]]·dt) = [[Ad, Bd], [0, I]].
    Van Loan (1978) for the process noise of ẋ = A x + w, E[w wᵀ] = Qc δ(t−τ):
    expm([[−A, Qc], [0, Aᵀ]]·dt) = [[·, G12], [0, G22]],  Ad = G22ᵀ,  Qd = Ad·G12
    = ∫₀^dt e^{Aτ} Qc e^{Aᵀτ} dτ.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    B = np.asarray(B, dtype=float).reshape(n, -1)
    Qc = np.atleast_2d(np.asarray(Qc, dtype=float))
    p = B.shape[1]
    M = np.zeros((n + p, n + p))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    Ad, Bd = E[:n, :n], E[:n, n:]
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n], V[:n, n:], V[n:, n:] = -A, Qc, A.T
    F = expm(V * dt)
    Qd = Ad @ F[:n, n:]
    return Ad, Bd, 0.5 * (Qd + Qd.T)


def angle_bias_process_noise(white_density, bias_walk, dt):
    """Qd (2×2) of the [angle θ, gyro bias b] model over ``dt`` (s), from the gyro's measured noise:

        θ̇ = ω_m − b − n_g,  ḃ = n_b,   n_g white with density N = ``white_density`` (rad/s/√Hz = rad/√s),
                                        n_b white with density K = ``bias_walk`` (rad/s/√s: the rate random walk)

    A = [[0, −1], [0, 0]], Qc = diag(N², K²), and Van Loan's integral in closed form (e^{Aτ} = [[1, −τ], [0, 1]]):

        Qd = [[N² dt + K² dt³/3,  −K² dt²/2],
              [−K² dt²/2,          K² dt   ]]

    N² dt is the angle's own random walk in one step (rad²); K² dt the bias's (rad²/s²); the off-diagonal says a
    bias that grew during the step has already turned the angle the other way. Both N and K come from lab 02's
    Allan curve (:func:`kfkit.allan.allan_noise_fit`).
    """
    N2, K2 = float(white_density) ** 2, float(bias_walk) ** 2
    # Qd's two rows, as the docstring writes them
    return np.array([[N2 * dt + K2 * dt**3 / 3.0, -K2 * dt**2 / 2.0],
                     [-K2 * dt**2 / 2.0, K2 * dt]])  # fmt: skip
