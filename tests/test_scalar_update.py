"""kfkit.filters.scalar_update against independent oracles: filterpy's KalmanFilter.update for an ordinary scalar
update, the Joseph form with the masked gain for a consider (Schmidt) update (it holds for any gain)."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from kfkit.filters.scalar_update import consider, diagonal_S, scalar_update


def random_case(seed, n=6):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    H = rng.normal(size=(1, n))
    x, z, r = rng.normal(size=n), rng.normal(), rng.uniform(0.1, 2.0)
    return P, H, x, z, r


@pytest.mark.parametrize("seed", range(5))
def test_an_ordinary_scalar_update_is_filterpys(seed):
    P, H, x, z, r = random_case(seed)
    kf = KalmanFilter(dim_x=6, dim_z=1)
    kf.x, kf.P, kf.H, kf.R = x[:, None].copy(), P.copy(), H, np.array([[r]])
    kf.update(np.array([[z]]))
    dx = np.zeros(6)
    a = P @ H[0]
    P_new, S = scalar_update(P, dx, a, H[0] @ a, z - H[0] @ x, r)
    np.testing.assert_allclose(x + dx, kf.x[:, 0], atol=1e-12)
    np.testing.assert_allclose(P_new, kf.P, atol=1e-10)
    np.testing.assert_allclose(S, kf.S[0, 0], rtol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_a_consider_update_leaves_its_components_and_is_the_joseph_form_of_its_gain(seed):
    P, H, x, z, r = random_case(seed)
    kept = consider(0, 1, 4)
    dx = np.zeros(6)
    a = P @ H[0]
    P_new, S = scalar_update(P, dx, a, H[0] @ a, z - H[0] @ x, r, kept)
    assert np.all(dx[[0, 1, 4]] == 0.0) and np.all(dx[[2, 3, 5]] != 0.0)
    K = (kept.keep_x * a / S)[:, None]  # the gain actually applied
    I_KH = np.eye(6) - K @ H
    joseph = I_KH @ P @ I_KH.T + r * K @ K.T
    np.testing.assert_allclose(P_new, joseph, atol=1e-10)
    np.testing.assert_allclose(P_new[np.ix_([0, 1, 4], [0, 1, 4])], P[np.ix_([0, 1, 4], [0, 1, 4])], atol=0)


def test_diagonal_S_marks_the_updates_not_made():
    S = diagonal_S(np.array([[1.0, np.nan, 3.0]]))[0]
    assert S[0, 0] == 1.0 and S[2, 2] == 3.0 and S[0, 2] == 0.0
    assert np.isnan(S[1]).all() and np.isnan(S[:, 1]).all()
