"""Lab 04's checkpoints: right answers pass (including a Jacobian derived another way), the
common mistakes fail with a line that names them, and nothing crashes."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfkit import filters
from kfkit.checkpoints import REGISTRY, get, run_checkpoint
from kfkit.filters.attitude import EulerAttitudeEKF

g = 9.80665


def h_scipy(x, field_n):
    """h(x) from scipy's rotation: [R_bn·(0, 0, −g); R_bn·m_n], R_nb = from_euler('ZYX', [ψ, θ, φ])."""
    R_bn = Rotation.from_euler("ZYX", [x[2], x[1], x[0]]).as_matrix().T
    return np.concatenate([R_bn @ [0.0, 0.0, -g], R_bn @ np.asarray(field_n, float)])


def central_differences(h, x, eps=1e-6):
    x = np.asarray(x, float)
    return np.column_stack([(np.asarray(h(x + e)) - np.asarray(h(x - e))) / (2 * eps) for e in np.eye(len(x)) * eps])


def reference_run_ekf(gyr, acc, mag, rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate=None):
    run = EulerAttitudeEKF(rate_hz, gyro_noise=gyro_noise, accel_noise=accel_noise, mag_noise=mag_noise,
                           field_n=field_n, accel_gate=accel_gate).run(gyr, acc, mag)
    return run.euler, run.P, run.nis


RIGHT = {
    "04.euler_rates": filters.euler_rates,
    "04.predict": filters.euler_ekf_predict,
    "04.measurement": filters.attitude_measurement,
    "04.jacobian": filters.attitude_jacobian,
    "04.numerical_jacobian": lambda h, x: central_differences(h, x),
    "04.update": filters.euler_ekf_update,
    "04.ekf_rmse": reference_run_ekf,
}


def test_every_registered_lab04_checkpoint_has_a_right_answer_here():
    get("04.predict")
    assert {n for n in REGISTRY if n.startswith("04.")} == set(RIGHT)


@pytest.mark.parametrize("name", sorted(RIGHT))
def test_reference_answers_pass(name):
    for seed in ([0] if name == "04.ekf_rmse" else [0, 1]):
        result = run_checkpoint(get(name), RIGHT[name], seed)
        assert result.ok, result.message
        assert result.points == result.max_points > 0


def test_any_correct_jacobian_passes():
    """H by central differences of an h built on scipy's rotations, not on kfkit's."""
    result = run_checkpoint(get("04.jacobian"), lambda x, field_n: central_differences(lambda v: h_scipy(v, field_n), x))
    assert result.ok, result.message


def test_the_copied_cos_phi_mistake_is_named():
    def copied(euler, omega_b):
        phi, theta = euler[0], euler[1]
        p, q, r = omega_b
        u = q * np.sin(phi) + r * np.cos(phi)
        return np.array([p + u * np.tan(theta), q * np.cos(phi) - r * np.sin(phi), u / np.cos(phi)])

    result = run_checkpoint(get("04.euler_rates"), copied, seed=0)
    assert result.status == "failed" and "divided by cos φ" in result.message and "Hint:" in result.message


def test_predict_without_yaw_wrapping_is_named():
    def unwrapped(x, P, omega_b, dt, Q):
        F = np.eye(3) + dt * filters.attitude.euler_kinematics_jacobian(x, omega_b)
        return np.asarray(x) + filters.euler_rates(x, omega_b) * dt, F @ P @ F.T + Q

    result = run_checkpoint(get("04.predict"), unwrapped, seed=0)
    assert result.status == "failed" and "not wrapped" in result.message


def test_predict_that_forgets_F_fails_with_expected_and_got():
    def no_F(x, P, omega_b, dt, Q):
        x_new = np.asarray(x) + filters.euler_rates(x, omega_b) * dt
        x_new[2] = filters.attitude.wrap_angle(x_new[2])
        return x_new, P + Q

    result = run_checkpoint(get("04.predict"), no_F, seed=1)
    assert result.status == "failed" and "value 2 of 2: expected" in result.message and "first difference at index" in result.message


def test_a_wrong_jacobian_column_is_named():
    def wrong_yaw_column(x, field_n):
        H = filters.attitude_jacobian(x, field_n)
        H[3:, 2] *= -1.0
        return H

    result = run_checkpoint(get("04.jacobian"), wrong_yaw_column, seed=0)
    assert result.status == "failed"
    assert "∂h/∂ψ (magnetometer rows)" in result.message and "∂h/∂φ" not in result.message


def test_jacobian_of_the_wrong_shape_is_explained():
    result = run_checkpoint(get("04.jacobian"), lambda x, field_n: filters.attitude_jacobian(x, field_n).T, seed=0)
    assert "expected shape (6, 3), got shape (3, 6)" in result.message


def test_a_coarse_forward_difference_fails():
    def forward(h, x, eps=1e-2):
        x = np.asarray(x, float)
        return np.column_stack([(np.asarray(h(x + e)) - np.asarray(h(x))) / eps for e in np.eye(len(x)) * eps])

    result = run_checkpoint(get("04.numerical_jacobian"), forward, seed=0)
    assert result.status == "failed"


def test_update_that_ignores_missing_magnetometer_samples_fails():
    def always_six(x, P, z, R, field_n):
        H = filters.attitude_jacobian(x, field_n)
        y = z - filters.attitude_measurement(x, field_n)
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        return x + K @ y, (np.eye(3) - K @ H) @ P, y, S

    result = run_checkpoint(get("04.update"), always_six, seed=0)
    assert result.status in ("failed", "error") and result.points == 0
    assert "magnetometer-less" in result.message or "NaN" in result.message


def test_gyro_only_filter_fails_the_rmse_limits():
    # Dead reckoning with the calibrated gyro stays within 1°, 1°, 2° on the bundled recording itself
    # (0.10°, 0.12°, 0.47°), and ignores the accelerations of the gated run: the run with an extra gyro bias is
    # what catches a filter without updates.
    def gyro_only(gyr, acc, mag, rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate=None):
        x = np.empty((len(gyr), 3))
        x_k = filters.attitude.tilt_heading(acc[0], mag[0], field_n)
        for k, w in enumerate(gyr):
            x_k = x_k + filters.euler_rates(x_k, w) / rate_hz
            x[k] = x_k
        return x, None, None

    result = run_checkpoint(get("04.ekf_rmse"), gyro_only)
    assert result.status == "failed" and result.message.startswith("❌ 04.ekf_rmse: 2/3")
    assert "extra gyro bias" in result.message and "roll RMSE" in result.message and "(limit 3°)" in result.message
    assert "are the accelerometer and magnetometer updates applied?" in result.message


def test_a_filter_that_drops_the_magnetometer_fails_on_yaw():
    def no_mag(gyr, acc, mag, rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate=None):
        return reference_run_ekf(gyr, acc, np.full_like(mag, np.nan), rate_hz, gyro_noise, accel_noise, mag_noise,
                                 field_n, accel_gate)

    result = run_checkpoint(get("04.ekf_rmse"), no_mag)
    assert result.status == "failed" and "yaw RMSE" in result.message


def test_rmse_checkpoint_explains_a_wrong_shape():
    result = run_checkpoint(get("04.ekf_rmse"), lambda **kw: (np.zeros((10, 3)), None, None))
    assert "expected 6240 rows of [roll, pitch, yaw]" in result.message


def test_not_attempted():
    def stub(*args, **kwargs):
        raise NotImplementedError()

    for name in RIGHT:
        result = run_checkpoint(get(name), stub, seed=0)
        assert result.status == "not attempted" and "not attempted yet" in result.message
