"""kfkit.frames against independent oracles (scipy Rotation, finite differences)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from kfkit.frames import (
    Q_NED_ENU,
    R_NED_ENU,
    G,
    accel_tilt,
    body_rates_to_euler_rates,
    cross_matrix,
    dcm_slerp,
    dcm_to_euler,
    dcm_to_quat,
    enu_to_ned,
    enu_to_ned_quat,
    euler_rates_to_body_rates,
    euler_to_dcm,
    euler_to_quat,
    mount_matrix,
    quat_conjugate,
    quat_multiply,
    quat_multiply_f,
    quat_normalise_f,
    quat_rotate,
    quat_slerp,
    quat_to_dcm,
    quat_to_dcm_f,
    quat_to_euler,
    quat_to_rotvec,
    random_dcm,
    rotvec_to_quat,
    rotvec_to_quat_f,
    wrap_angle,
    wrap_angle_f,
)

HALF_PI = np.pi / 2


def scipy_dcm(roll, pitch, yaw):
    """Oracle: R_nb = Rz(yaw) Ry(pitch) Rx(roll) via scipy's intrinsic ZYX."""
    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_matrix()


def random_euler(rng, n, max_pitch=HALF_PI):
    return (rng.uniform(-np.pi, np.pi, n), rng.uniform(-max_pitch, max_pitch, n), rng.uniform(-np.pi, np.pi, n))


def near_lock_pitch(rng, n):
    """Pitches within 1e-6 rad of ±90°, exactly ±90° included."""
    sign = rng.choice([-1.0, 1.0], n)
    offset = rng.uniform(0.0, 1e-6, n)
    offset[:4] = 0.0
    return sign * (HALF_PI - offset)


def test_G_is_standard_gravity():
    assert G == 9.80665


def scipy_quat(rot):
    """Oracle: scipy's quaternion (x-y-z-w) as w-x-y-z with w ≥ 0."""
    q = rot.as_quat()[..., [3, 0, 1, 2]]
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def random_rotations(n, seed):
    """Random rotations plus the hard cases for a matrix → quaternion conversion: 180° turns about
    each axis and about diagonals (w = 0), the identity, and tiny angles."""
    rng = np.random.default_rng(seed)
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, -1], [0, -1, 1], [1, 1, 1]], float)
    special = np.concatenate(
        [np.pi * axes / np.linalg.norm(axes, axis=1, keepdims=True), 1e-9 * axes, np.zeros((1, 3))]
    )
    return Rotation.concatenate([Rotation.random(n, random_state=rng), Rotation.from_rotvec(special)])


# --- quaternions ----------------------------------------------------------------------------


def test_euler_to_quat_matches_scipy():
    rng = np.random.default_rng(11)
    roll, pitch, yaw = random_euler(rng, 300)
    q = euler_to_quat(np.column_stack([roll, pitch, yaw]))
    np.testing.assert_allclose(
        q, scipy_quat(Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))), atol=1e-12
    )
    assert euler_to_quat([0.1, 0.2, 0.3]).shape == (4,)


def test_quat_to_dcm_matches_scipy():
    rot = random_rotations(300, 12)
    np.testing.assert_allclose(quat_to_dcm(scipy_quat(rot)), rot.as_matrix(), atol=1e-12)


def test_dcm_to_quat_matches_scipy_including_half_turns():
    rot = random_rotations(300, 13)
    q = dcm_to_quat(rot.as_matrix())
    want = scipy_quat(rot)
    # at w = 0 (half turns) q and −q both have w ≥ 0: compare up to sign there
    sign = np.where(np.sum(q * want, axis=1) < 0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(q * sign, want, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert np.all(q[:, 0] >= 0)
    assert dcm_to_quat(np.eye(3)).tolist() == [1.0, 0.0, 0.0, 0.0]


def test_dcm_to_quat_rejects_wrong_shape():
    with pytest.raises(ValueError, match=r"\(…, 3, 3\), got \(3, 4\)"):
        dcm_to_quat(np.zeros((3, 4)))


def test_quat_to_euler_matches_scipy_away_from_gimbal_lock():
    rng = np.random.default_rng(14)
    rot = Rotation.from_euler("ZYX", np.column_stack(random_euler(rng, 300, max_pitch=1.5)[::-1]))
    yaw, pitch, roll = rot.as_euler("ZYX").T
    np.testing.assert_allclose(quat_to_euler(scipy_quat(rot)), np.column_stack([roll, pitch, yaw]), atol=1e-9)


def test_quat_multiply_composes_like_scipy():
    a, b = random_rotations(200, 15), random_rotations(200, 16)
    product = quat_multiply(scipy_quat(a), scipy_quat(b))
    want = scipy_quat(a * b)
    sign = np.where(np.sum(product * want, axis=1) < 0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(product * sign, want, atol=1e-12)
    # broadcasting: one quaternion against many
    np.testing.assert_allclose(
        quat_multiply(scipy_quat(a)[0], scipy_quat(b)), quat_multiply(scipy_quat(a)[[0] * len(b)], scipy_quat(b))
    )


def test_quat_conjugate_is_scipys_inverse():
    rot = random_rotations(100, 17)
    np.testing.assert_allclose(quat_to_dcm(quat_conjugate(scipy_quat(rot))), rot.inv().as_matrix(), atol=1e-12)


def test_enu_to_ned_maps_axes():
    east, north, up = np.eye(3)
    np.testing.assert_array_equal(enu_to_ned([east, north, up]), [[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    np.testing.assert_array_equal(enu_to_ned(enu_to_ned([1.0, 2.0, 3.0])), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="3 components"):
        enu_to_ned([1.0, 2.0])


def test_enu_to_ned_quat_rotates_like_the_vector_map():
    """q_NED = Q_NED_ENU ⊗ q_ENU means R_nb = R_NED_ENU · R_eb (scipy composes the same way)."""
    rot = random_rotations(100, 18)
    q_ned = enu_to_ned_quat(scipy_quat(rot))
    np.testing.assert_allclose(quat_to_dcm(q_ned), R_NED_ENU @ rot.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(np.roll(Q_NED_ENU, -1)).as_matrix(), R_NED_ENU, atol=1e-15)
    v_b = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(np.einsum("nij,j->ni", quat_to_dcm(q_ned), v_b), enu_to_ned(rot.apply(v_b)), atol=1e-12)


# --- euler_to_dcm -------------------------------------------------------------------------


def stacked(roll, pitch, yaw):
    return np.stack(np.broadcast_arrays(roll, pitch, yaw), axis=-1)


def test_euler_to_dcm_matches_scipy_vectorised():
    rng = np.random.default_rng(1)
    roll, pitch, yaw = random_euler(rng, 300)
    R = euler_to_dcm(stacked(roll, pitch, yaw))
    assert R.shape == (300, 3, 3)
    np.testing.assert_allclose(R, scipy_dcm(roll, pitch, yaw), atol=1e-12)


def test_euler_to_dcm_matches_scipy_near_gimbal_lock():
    rng = np.random.default_rng(2)
    roll, _, yaw = random_euler(rng, 200)
    pitch = near_lock_pitch(rng, 200)
    np.testing.assert_allclose(euler_to_dcm(stacked(roll, pitch, yaw)), scipy_dcm(roll, pitch, yaw), atol=1e-12)


def test_euler_to_dcm_single_attitude_and_leading_axes():
    R = euler_to_dcm([0.3, -0.2, 1.1])
    assert R.shape == (3, 3)
    np.testing.assert_allclose(R, scipy_dcm(0.3, -0.2, 1.1)[0], atol=1e-12)
    grid = np.random.default_rng(6).uniform(-1, 1, (4, 5, 3))
    assert euler_to_dcm(grid).shape == (4, 5, 3, 3)
    np.testing.assert_allclose(euler_to_dcm(grid)[2, 3], scipy_dcm(*grid[2, 3])[0], atol=1e-12)


def test_euler_to_dcm_maps_body_to_ned():
    # Yaw 90° (heading east): body forward (x_b) points east in NED.
    np.testing.assert_allclose(euler_to_dcm([0.0, 0.0, HALF_PI]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # Pitch +90° (nose up): body forward points up, i.e. −z in NED.
    np.testing.assert_allclose(euler_to_dcm([0.0, HALF_PI, 0.0]) @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    # Roll +90° (right wing down): body right (y_b) points down.
    np.testing.assert_allclose(euler_to_dcm([HALF_PI, 0.0, 0.0]) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def test_euler_to_dcm_refuses_three_separate_angles_or_a_wrong_shape():
    with pytest.raises(TypeError):
        euler_to_dcm(0.2, 0.1, 0.3)  # the old three-argument form: one array shape per pair now
    with pytest.raises(ValueError, match=r"\[roll, pitch, yaw\] on the last axis"):
        euler_to_dcm(np.zeros((3, 4)))


# --- dcm_to_euler -------------------------------------------------------------------------


def test_dcm_to_euler_round_trip_away_from_gimbal_lock():
    rng = np.random.default_rng(3)
    angles = random_euler(rng, 300, max_pitch=np.radians(89.0))
    back = dcm_to_euler(scipy_dcm(*angles))
    assert back.shape == (300, 3)
    np.testing.assert_allclose(wrap_angle(back - stacked(*angles)), 0.0, atol=1e-9)


def test_dcm_to_euler_matches_scipy_as_euler():
    rng = np.random.default_rng(4)
    R = scipy_dcm(*random_euler(rng, 300, max_pitch=np.radians(85.0)))
    yaw, pitch, roll = Rotation.from_matrix(R).as_euler("ZYX").T
    got_roll, got_pitch, got_yaw = dcm_to_euler(R).T
    np.testing.assert_allclose(wrap_angle(got_roll - roll), 0.0, atol=1e-9)
    np.testing.assert_allclose(got_pitch, pitch, atol=1e-9)
    np.testing.assert_allclose(wrap_angle(got_yaw - yaw), 0.0, atol=1e-9)


def test_dcm_to_euler_near_gimbal_lock_reproduces_the_matrix():
    rng = np.random.default_rng(5)
    roll, _, yaw = random_euler(rng, 400)
    R = scipy_dcm(roll, near_lock_pitch(rng, 400), yaw)  # not built by the code under test
    angles = dcm_to_euler(R)
    np.testing.assert_allclose(scipy_dcm(*angles.T), R, atol=1e-6)


@pytest.mark.parametrize("pitch", [HALF_PI, -HALF_PI])
def test_dcm_to_euler_exact_gimbal_lock_single(pitch):
    R = scipy_dcm(0.7, pitch, -2.0)[0]
    angles = dcm_to_euler(R)
    assert angles.shape == (3,)
    assert angles[1] == pytest.approx(pitch, abs=1e-6)
    np.testing.assert_allclose(scipy_dcm(*angles)[0], R, atol=1e-6)


def test_dcm_to_euler_single_attitude():
    out = dcm_to_euler(scipy_dcm(0.1, 0.2, 0.3)[0])
    assert out.shape == (3,)
    np.testing.assert_allclose(out, [0.1, 0.2, 0.3], atol=1e-12)


# --- body rates ↔ Euler rates ---------------------------------------------------------------


def test_body_rates_to_euler_rates_inverts_euler_rates_to_body_rates():
    rng = np.random.default_rng(7)
    euler = stacked(*random_euler(rng, 200, max_pitch=np.radians(80.0)))
    omega = rng.normal(0.0, 2.0, (200, 3))
    rates = body_rates_to_euler_rates(euler, omega)
    np.testing.assert_allclose(euler_rates_to_body_rates(euler, rates), omega, atol=1e-9)


def test_body_rates_to_euler_rates_match_scipy_finite_difference():
    """Turn by ω_b for a short dt with scipy (R(t+dt) = R(t)·exp(ω_b dt)) and difference the Euler angles."""
    rng = np.random.default_rng(8)
    euler = stacked(*random_euler(rng, 50, max_pitch=np.radians(80.0)))
    omega, dt = rng.normal(0.0, 1.0, (50, 3)), 1e-6
    before = Rotation.from_euler("ZYX", euler[:, ::-1])
    after = (before * Rotation.from_rotvec(omega * dt)).as_euler("ZYX")[:, ::-1]
    finite = wrap_angle(after - euler) / dt
    np.testing.assert_allclose(body_rates_to_euler_rates(euler, omega), finite, rtol=1e-4, atol=1e-4)


# --- rotation vectors, quat_rotate, slerp, random ------------------------------------------


def test_rotvec_pair_matches_scipy_and_round_trips():
    rng = np.random.default_rng(9)
    v = rng.normal(0.0, 1.5, (300, 3))
    v = np.concatenate([v, [[0.0, 0.0, 0.0], [1e-9, -2e-9, 0.0], [np.pi, 0.0, 0.0]]])
    q = rotvec_to_quat(v)
    np.testing.assert_allclose(quat_to_dcm(q), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    back = quat_to_rotvec(q)
    np.testing.assert_allclose(Rotation.from_rotvec(back).as_matrix(), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    small = np.linalg.norm(v, axis=-1) < np.pi
    np.testing.assert_allclose(back[small], v[small], atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(-q[:5]), back[:5], atol=1e-12)  # q and −q: one rotation


def test_quat_rotate_is_the_rotation_matrix():
    rng = np.random.default_rng(10)
    rot = Rotation.random(100, random_state=rng)
    v = rng.normal(size=(100, 3))
    np.testing.assert_allclose(quat_rotate(scipy_quat(rot), v), rot.apply(v), atol=1e-12)


def test_quat_slerp_matches_scipy_slerp():
    rng = np.random.default_rng(11)
    a, b = Rotation.random(50, random_state=rng), Rotation.random(50, random_state=rng)
    frac = rng.uniform(0.0, 1.0, 50)
    got = quat_slerp(scipy_quat(a), scipy_quat(b), frac)
    for i in range(50):
        want = Slerp([0.0, 1.0], Rotation.concatenate([a[i], b[i]]))([frac[i]])
        np.testing.assert_allclose(quat_to_dcm(got[i]), want.as_matrix()[0], atol=1e-12)
    np.testing.assert_allclose(quat_to_dcm(quat_slerp(scipy_quat(a), scipy_quat(b), 0.0)), a.as_matrix(), atol=1e-12)


def test_dcm_slerp_interpolates_a_constant_rate_turn():
    t = np.linspace(0.0, 2.0, 9)
    R = Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 0.7])).as_matrix()  # 0.7 rad/s about down
    t_mid = np.array([0.1, 0.37, 1.93])
    np.testing.assert_allclose(
        dcm_slerp(t, R, t_mid), Rotation.from_rotvec(np.outer(t_mid, [0, 0, 0.7])).as_matrix(), atol=1e-12
    )


def test_random_dcm_is_uniform_and_seeded():
    R = random_dcm(4000, 12)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert abs(R[:, :, 0].mean(axis=0)).max() < 0.05  # directions average out (σ of the mean ≈ 0.009)
    np.testing.assert_array_equal(random_dcm(3, 12), random_dcm(3, 12))
    assert random_dcm(rng=np.random.default_rng(1)).shape == (3, 3)


# --- accel_tilt ---------------------------------------------------------------------------


def specific_force_at_rest(roll, pitch, yaw):
    """f_b = R_bn · [0, 0, −g] with R_bn from scipy."""
    return np.einsum("nji,j->ni", scipy_dcm(roll, pitch, yaw), [0.0, 0.0, -G])


def test_accel_tilt_recovers_roll_and_pitch():
    rng = np.random.default_rng(6)
    roll, pitch, yaw = random_euler(rng, 300, max_pitch=np.radians(89.0))
    got_roll, got_pitch = accel_tilt(specific_force_at_rest(roll, pitch, yaw))
    assert got_roll.shape == got_pitch.shape == (300,)
    np.testing.assert_allclose(wrap_angle(got_roll - roll), 0.0, atol=1e-9)
    np.testing.assert_allclose(got_pitch, pitch, atol=1e-9)


def test_accel_tilt_single_vector_returns_floats():
    f = specific_force_at_rest([np.radians(-150.0)], [np.radians(40.0)], [1.0])[0]
    roll, pitch = accel_tilt(f)
    assert isinstance(roll, float) and isinstance(pitch, float)
    assert roll == pytest.approx(np.radians(-150.0), abs=1e-9)
    assert pitch == pytest.approx(np.radians(40.0), abs=1e-9)


def test_accel_tilt_level_board():
    assert accel_tilt([0.0, 0.0, -G]) == pytest.approx((0.0, 0.0), abs=1e-15)


@pytest.mark.parametrize("bad", [np.zeros(2), np.zeros((5, 4)), 1.0])
def test_accel_tilt_rejects_wrong_shape(bad):
    with pytest.raises(ValueError, match="3 components"):
        accel_tilt(bad)


# --- wrap_angle ---------------------------------------------------------------------------


@pytest.mark.parametrize("a", [np.pi, -np.pi])
def test_wrap_angle_pi_maps_to_plus_pi(a):
    assert wrap_angle(a) == np.pi


@pytest.mark.parametrize(
    "a, want",
    [(0.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (3 * HALF_PI, -HALF_PI), (-3 * HALF_PI, HALF_PI), (2 * np.pi, 0.0)],
)
def test_wrap_angle_values(a, want):
    assert wrap_angle(a) == pytest.approx(want, abs=1e-12)


def test_wrap_angle_large_multiples():
    rng = np.random.default_rng(7)
    base = rng.uniform(-3.0, 3.0, 100)
    k = rng.integers(-1000, 1000, 100)
    got = wrap_angle(base + 2 * np.pi * k)
    np.testing.assert_allclose(got, base, atol=1e-9)
    assert np.all((got > -np.pi) & (got <= np.pi))


def test_wrap_angle_return_types():
    assert isinstance(wrap_angle(4.0), float)
    out = wrap_angle([4.0, -4.0])
    assert isinstance(out, np.ndarray) and out.shape == (2,)
    np.testing.assert_allclose(out, [4.0 - 2 * np.pi, 2 * np.pi - 4.0])


# --- euler_rates_to_body_rates ------------------------------------------------------------


def vee_of_skew(W):
    """ω from a (nearly) skew matrix Ω×, using its skew part."""
    S = 0.5 * (W - W.T)
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def body_rate_by_finite_difference(euler, euler_dot, h=1e-6):
    """Oracle: Ω× ≈ R_nbᵀ (R_nb(t+h) − R_nb(t−h)) / 2h, rotation from scipy."""
    R = lambda e: scipy_dcm(*e)[0]  # noqa: E731
    return vee_of_skew(R(euler).T @ (R(euler + h * euler_dot) - R(euler - h * euler_dot)) / (2 * h))


def test_euler_rates_to_body_rates_matches_finite_difference():
    rng = np.random.default_rng(8)
    euler = np.column_stack(random_euler(rng, 200, max_pitch=np.radians(85.0)))
    euler_dot = rng.normal(0.0, 2.0, (200, 3))
    got = euler_rates_to_body_rates(euler, euler_dot)
    assert got.shape == (200, 3)
    want = np.array([body_rate_by_finite_difference(e, ed) for e, ed in zip(euler, euler_dot)])
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_euler_rates_to_body_rates_single_sample():
    e, ed = np.array([0.4, -0.3, 2.0]), np.array([0.5, -1.0, 0.7])
    np.testing.assert_allclose(euler_rates_to_body_rates(e, ed), body_rate_by_finite_difference(e, ed), atol=1e-6)


# --- mount_matrix -------------------------------------------------------------------------


def test_mount_matrix_accepts_rotation_as_nested_list():
    spec = Rotation.from_euler("ZYX", [0.3, 0.2, 0.1]).as_matrix().tolist()
    np.testing.assert_allclose(mount_matrix(spec), spec)
    np.testing.assert_array_equal(mount_matrix([[1, 0, 0], [0, -1, 0], [0, 0, -1]]), np.diag([1.0, -1.0, -1.0]))


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.diag([1.0, 1.0, -1.0]), "rotation"),  # reflection, det −1
        (2 * np.eye(3), "rotation"),  # not orthonormal
        (np.eye(2), "3×3"),  # wrong shape
        ([[1, 0, 0], [0, 1, 0]], "3×3"),
    ],
)
def test_mount_matrix_rejects_non_rotations(bad, match):
    with pytest.raises(ValueError, match=match):
        mount_matrix(bad)


# --- magnetic heading (calibration helper) --------------------------------------------------


def _field_in_body(yaw, pitch, roll, field_n=(19.5, 0.3, 45.0)):
    """m_b = R_bn m_n with R_nb from scipy's Rotation (the oracle)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).inv().apply(field_n)


def test_tilt_compensated_heading_recovers_yaw_on_random_attitudes():
    from kfkit.frames import declination, tilt_compensated_heading, wrap_angle

    rng = np.random.default_rng(0)
    yaw, pitch, roll = rng.uniform(-np.pi, np.pi, 500), rng.uniform(-1.5, 1.5, 500), rng.uniform(-np.pi, np.pi, 500)
    m_b = _field_in_body(yaw, pitch, roll)
    psi = tilt_compensated_heading(m_b, roll, pitch, declination=declination())
    np.testing.assert_allclose(wrap_angle(psi - yaw), 0.0, atol=1e-9)
    assert np.all((psi > -np.pi) & (psi <= np.pi))
    magnetic = tilt_compensated_heading(m_b, roll, pitch)  # without declination: off by D = atan2(0.3, 19.5)
    np.testing.assert_allclose(wrap_angle(yaw - magnetic), np.arctan2(0.3, 19.5), atol=1e-9)


def test_flat_heading_is_right_level_and_wrong_tilted():
    from kfkit.frames import mag_heading, wrap_angle

    yaw = np.linspace(-3.1, 3.1, 13)
    level = _field_in_body(yaw, 0 * yaw, 0 * yaw, field_n=(20.0, 0.0, 45.0))
    np.testing.assert_allclose(wrap_angle(mag_heading(level) - yaw), 0.0, atol=1e-12)
    assert mag_heading(level[3]) == pytest.approx(yaw[3])
    tilted = _field_in_body(yaw, 0 * yaw + 0.3, 0 * yaw, field_n=(20.0, 0.0, 45.0))
    assert np.max(np.abs(wrap_angle(mag_heading(tilted) - yaw))) > np.radians(20)


def test_heading_rejects_wrong_shapes():
    from kfkit.frames import mag_heading, tilt_compensated_heading

    with pytest.raises(ValueError, match="3 components"):
        mag_heading(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="3 components"):
        tilt_compensated_heading(1.0, 0.0, 0.0)


@pytest.mark.parametrize("D_deg, dip_deg", [(-12.0, 70.0), (0.0, 66.0), (15.0, 30.0), (179.0, -40.0)])
def test_true_heading_with_large_declinations(D_deg, dip_deg):
    """A field D east of true north (and south of the equator for negative dip): ψ_true = atan2(−m_y', m_x') + D."""
    from kfkit.frames import declination, mag_heading, tilt_compensated_heading, wrap_angle

    D, dip, B = np.radians(D_deg), np.radians(dip_deg), 48.0
    field_n = B * np.array([np.cos(dip) * np.cos(D), np.cos(dip) * np.sin(D), np.sin(dip)])
    assert declination(field_n) == pytest.approx(D)
    rng = np.random.default_rng(4)
    yaw, pitch, roll = rng.uniform(-np.pi, np.pi, 200), rng.uniform(-1.4, 1.4, 200), rng.uniform(-np.pi, np.pi, 200)
    m_b = _field_in_body(yaw, pitch, roll, field_n=field_n)
    np.testing.assert_allclose(wrap_angle(tilt_compensated_heading(m_b, roll, pitch, D) - yaw), 0.0, atol=1e-9)
    level = _field_in_body(yaw, 0 * yaw, 0 * yaw, field_n=field_n)
    np.testing.assert_allclose(wrap_angle(mag_heading(level, declination=D) - yaw), 0.0, atol=1e-9)


def test_cross_matrix_is_the_cross_product_and_the_small_body_rotation():
    """[v×]u = v × u (NumPy's cross as the oracle), for one vector and a stack; and R(I + [δθ×]) is scipy's
    R·exp(δθ) to first order (the body-frame turn the MEKF's error is)."""
    rng = np.random.default_rng(3)
    v, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    assert np.allclose(np.einsum("nij,nj->ni", cross_matrix(v), u), np.cross(v, u))
    assert np.allclose(cross_matrix(v[0]) @ u[0], np.cross(v[0], u[0]))
    R, d = Rotation.random(random_state=4), 1e-6 * rng.normal(size=3)
    assert np.allclose(
        R.as_matrix() @ (np.eye(3) + cross_matrix(d)), (R * Rotation.from_rotvec(d)).as_matrix(), atol=1e-11
    )
    with pytest.raises(ValueError, match="cross_matrix"):
        cross_matrix([1.0, 2.0])


# --- float-only helpers for hot loops --------------------------------------------------------


def test_quat_multiply_f_chains_rotations_like_scipy():
    rots = random_rotations(60, seed=41)
    p, q = rots[:-1], rots[1:]
    for a, b in zip(p, q):
        got = quat_multiply_f(tuple(scipy_quat(a).tolist()), tuple(scipy_quat(b).tolist()))
        assert isinstance(got, tuple) and all(type(v) is float for v in got)
        want = scipy_quat(a * b)  # q and −q are the same rotation
        np.testing.assert_allclose(np.array(got) * np.sign(np.dot(got, want)), want, atol=1e-12)


def test_quat_to_dcm_f_matches_scipy():
    for rot in random_rotations(60, seed=42):
        np.testing.assert_allclose(
            np.reshape(quat_to_dcm_f(tuple(scipy_quat(rot).tolist())), (3, 3)), rot.as_matrix(), atol=1e-12
        )


def test_rotvec_to_quat_f_is_the_exact_exponential():
    rng = np.random.default_rng(43)
    vectors = np.concatenate(
        [
            rng.normal(0.0, 1.5, (60, 3)),
            [[np.pi, 0.0, 0.0], [0.0, 0.0, 3.0 * np.pi]],
            [[1e-9, -2e-9, 3e-10], [0.0, 0.0, 0.0], [1e-7, 0.0, 0.0]],
        ]
    )
    for v in vectors:
        got = np.array(rotvec_to_quat_f(*v.tolist()))
        want = Rotation.from_rotvec(v).as_quat()[[3, 0, 1, 2]]  # the same turn, not reduced to w ≥ 0
        np.testing.assert_allclose(got * np.sign(got @ want), want, atol=1e-15)
        assert abs(np.linalg.norm(got) - 1.0) < 1e-15


def test_quat_normalise_f():
    q = quat_normalise_f((2.0, 0.0, -1.0, 2.0))
    np.testing.assert_allclose(q, np.array([2.0, 0.0, -1.0, 2.0]) / 3.0, atol=1e-16)


@pytest.mark.parametrize("a", [0.0, 1.0, -1.0, np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 7.5, -7.5, 1e3, -np.pi + 1e-12])
def test_wrap_angle_f_agrees_with_wrap_angle(a):
    got = wrap_angle_f(float(a))
    assert type(got) is float and -np.pi < got <= np.pi
    assert got == pytest.approx(wrap_angle(a), abs=1e-12)
