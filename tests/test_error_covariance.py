"""kfkit.filters.error_covariance (the MEKF's 6×6 covariance as 36 floats, its arithmetic written out) against
independent oracles: numpy's F P Fᵀ + Q and P Hᵀ, filterpy's KalmanFilter.update for an ordinary scalar update, the
Joseph form with the masked gain for a consider (Schmidt) update (it holds for any gain)."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.spatial.transform import Rotation

from kfkit.filters.error_covariance import (
    BIAS,
    TILT,
    TILT_AND_BIAS,
    diagonal_S,
    propagate,
    scalar_update,
    times_attitude_row,
)


def random_case(seed, n=6):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    H = rng.normal(size=(1, n))
    x, z, r = rng.normal(size=n), rng.normal(), rng.uniform(0.1, 2.0)
    return P, H, x, z, r


def packed(P):
    return tuple(P.ravel().tolist())


def matrix(P):
    return np.array(P).reshape(6, 6)


@pytest.mark.parametrize("seed", range(5))
def test_propagate_is_F_P_Ft_plus_Q(seed):
    P = random_case(seed)[0]
    R, dt, q_angle, q_bias = Rotation.random(random_state=seed).as_matrix(), 0.0125, 3e-7, 2e-10
    F = np.block([[np.eye(3), -R * dt], [np.zeros((3, 3)), np.eye(3)]])
    want = F @ P @ F.T + np.diag([q_angle] * 3 + [q_bias] * 3)
    got = matrix(propagate(packed(P), tuple(R.ravel()), dt, q_angle, q_bias))
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(got, got.T)


@pytest.mark.parametrize("seed", range(3))
def test_times_attitude_row_is_P_Ht(seed):
    P = random_case(seed)[0]
    h = np.r_[np.random.default_rng(seed).normal(size=3), 0.0, 0.0, 0.0]
    np.testing.assert_allclose(times_attitude_row(packed(P), *h[:3]), P @ h, rtol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_an_ordinary_scalar_update_is_filterpys(seed):
    P, H, x, z, r = random_case(seed)
    kf = KalmanFilter(dim_x=6, dim_z=1)
    kf.x, kf.P, kf.H, kf.R = x[:, None].copy(), P.copy(), H, np.array([[r]])
    kf.update(np.array([[z]]))
    dx = [0.0] * 6
    a = P @ H[0]
    P_new, S = scalar_update(packed(P), dx, tuple(a), float(H[0] @ a), float(z - H[0] @ x), r)
    np.testing.assert_allclose(x + dx, kf.x[:, 0], atol=1e-12)
    np.testing.assert_allclose(matrix(P_new), kf.P, atol=1e-10)
    np.testing.assert_array_equal(matrix(P_new), matrix(P_new).T)
    np.testing.assert_allclose(S, kf.S[0, 0], rtol=1e-12)


@pytest.mark.parametrize("kept, left", [(TILT, [0, 1]), (BIAS, [3, 4, 5]), (TILT_AND_BIAS, [0, 1, 3, 4, 5])])
@pytest.mark.parametrize("seed", range(3))
def test_a_consider_update_leaves_its_components_and_is_the_joseph_form_of_its_gain(seed, kept, left):
    P, H, x, z, r = random_case(seed)
    dx = [0.0] * 6
    a = P @ H[0]
    P_new, S = scalar_update(packed(P), dx, tuple(a), float(H[0] @ a), float(z - H[0] @ x), r, kept)
    dx, P_new = np.array(dx), matrix(P_new)
    updated = [i for i in range(6) if i not in left]
    assert np.all(dx[left] == 0.0) and np.all(dx[updated] != 0.0)
    gain_mask = np.ones(6)
    gain_mask[left] = 0.0
    K = (gain_mask * a / S)[:, None]  # the gain actually applied
    I_KH = np.eye(6) - K @ H
    joseph = I_KH @ P @ I_KH.T + r * K @ K.T
    np.testing.assert_allclose(P_new, joseph, atol=1e-10)
    np.testing.assert_array_equal(P_new[np.ix_(left, left)], P[np.ix_(left, left)])
    np.testing.assert_array_equal(P_new, P_new.T)


def test_diagonal_S_marks_the_updates_not_made():
    S = diagonal_S(np.array([[1.0, np.nan, 3.0]]))[0]
    assert S[0, 0] == 1.0 and S[2, 2] == 3.0 and S[0, 2] == 0.0
    assert np.isnan(S[1]).all() and np.isnan(S[:, 1]).all()
