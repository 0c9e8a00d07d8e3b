"""BROAD attitude errors (kfkit.metrics.attitude_errors) against scipy Rotation constructions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit.frames import enu_to_ned_quat
from kfkit.metrics import attitude_errors, attitude_rmse


def wxyz(rot):
    return rot.as_quat()[..., [3, 0, 1, 2]]


def random_truth(rng, n):
    return Rotation.from_quat(rng.normal(size=(n, 4)))


def test_heading_and_inclination_parts_of_a_constructed_error():
    # q_est = swing(β about a horizontal axis) ⊗ twist(α about the vertical) ⊗ q_true, all in the
    # navigation frame: heading error |α|, inclination error |β|, total = angle of the product.
    rng = np.random.default_rng(0)
    n = 200
    truth = random_truth(rng, n)
    alpha = rng.uniform(-np.pi * 0.9, np.pi * 0.9, n)
    beta = rng.uniform(-np.pi * 0.9, np.pi * 0.9, n)
    axis_angle = rng.uniform(0, 2 * np.pi, n)
    horizontal = np.column_stack([np.cos(axis_angle), np.sin(axis_angle), np.zeros(n)])
    error = Rotation.from_rotvec(horizontal * beta[:, None]) * Rotation.from_rotvec(np.outer(alpha, [0, 0, 1]))
    est = error * truth
    total, heading, incl = attitude_errors(wxyz(est), wxyz(truth))
    np.testing.assert_allclose(heading, np.abs(alpha), atol=1e-9)
    np.testing.assert_allclose(incl, np.abs(beta), atol=1e-9)
    np.testing.assert_allclose(total, error.magnitude(), atol=1e-9)
    np.testing.assert_allclose(total, (est * truth.inv()).magnitude(), atol=1e-9)


def test_errors_do_not_depend_on_quaternion_sign_or_frame_ned_vs_enu():
    rng = np.random.default_rng(1)
    truth, est = random_truth(rng, 50), random_truth(rng, 50)
    ref = attitude_errors(wxyz(est), wxyz(truth))
    flipped = attitude_errors(-wxyz(est), wxyz(truth))
    for a, b in zip(ref, flipped):
        np.testing.assert_allclose(a, b, atol=1e-12)
    # The same two attitudes expressed in NED (from ENU): a vertical-preserving frame change.
    in_ned = attitude_errors(enu_to_ned_quat(wxyz(est)), enu_to_ned_quat(wxyz(truth)))
    for a, b in zip(ref, in_ned):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_pure_heading_and_pure_tilt_errors():
    truth = Rotation.from_euler("ZYX", [0.3, 0.2, -0.1])
    yawed = Rotation.from_euler("z", 0.25) * truth  # about the navigation vertical
    total, heading, incl = attitude_errors(wxyz(yawed)[None], wxyz(truth)[None])
    assert (
        heading[0] == pytest.approx(0.25)
        and incl[0] == pytest.approx(0.0, abs=1e-9)
        and total[0] == pytest.approx(0.25)
    )
    tilted = Rotation.from_euler("x", -0.1) * truth
    total, heading, incl = attitude_errors(wxyz(tilted)[None], wxyz(truth)[None])
    assert heading[0] == pytest.approx(0.0, abs=1e-9) and incl[0] == pytest.approx(0.1)


def test_nan_truth_rows_and_masked_rmse():
    rng = np.random.default_rng(2)
    truth = wxyz(random_truth(rng, 10))
    est = wxyz(Rotation.from_euler("z", 0.1) * Rotation.from_quat(truth[:, [1, 2, 3, 0]]))
    truth[3] = np.nan
    total, heading, incl = attitude_errors(est, truth)
    assert np.isnan(total[3]) and np.isnan(heading[3]) and np.isnan(incl[3])
    mask = np.ones(10, bool)
    mask[:2] = False
    r = attitude_rmse(est, truth, mask)
    assert (
        r["heading"] == pytest.approx(0.1)
        and r["total"] == pytest.approx(0.1)
        and r["inclination"] == pytest.approx(0.0, abs=1e-7)
    )


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match=r"q_est must be quaternions w-x-y-z of shape \(N, 4\)"):
        attitude_errors(np.zeros((3, 3)), np.ones((3, 4)))
    with pytest.raises(ValueError, match="q_est has 2 rows but q_true has 3"):
        attitude_errors(np.ones((2, 4)), np.ones((3, 4)))
