"""Every checkpoint of every lab judged with kfkit's own functions as the right answers (one parametrised
test over all labs), and each lab's judges naming the classic mistakes in answers written another way.

The solutions' own exercise functions as answers, NaN/inf answers and the catalogue of mutated model answers
are in test_checkpoints_every.py; lab 05's answers are the notebook's (its pipeline: test_tilt.py)."""

import dataclasses
import math
import re

import numpy as np
import pytest
from scipy import constants
from scipy.optimize import brentq, least_squares
from scipy.spatial.transform import Rotation

from kfkit import allan, datasets, discrete, filters, frames, mag_calibration, rest_calibration
from kfkit import calibration as C
from kfkit import vehicle as V
from kfkit.checkpoints import REGISTRY, check, compare, get, run_checkpoint
from kfkit.filters import estimate_sideslip, sideslip_step
from kfkit.filters.euler_ekf_fast import FastEulerAttitudeEKF

g = 9.80665
B_LONDON = np.linalg.norm(frames.MAG_FIELD_LONDON)


# --- kfkit's answers, lab by lab ---------------------------------------------------------------------------------


def loop_xor(body):
    x = 0
    for c in body:
        x ^= c
    return x


def unwrap(t_us):
    return np.concatenate([[0.0], np.cumsum(np.diff(np.asarray(t_us, dtype=np.int64)) % 2**32) / 1e6])


def reference_run_kf(gyro_rate, roll_acc, dt, q, r, x0, P0):
    run = filters.roll_kf(gyro_rate, roll_acc, dt, q, r, x0, P0)
    return run.x, run.P, run.y, run.S


def h_scipy(x, field_n):
    """h(x) from scipy's rotation: [R_bn·(0, 0, −g); R_bn·m_n], R_nb = from_euler('ZYX', [ψ, θ, φ])."""
    R_bn = Rotation.from_euler("ZYX", [x[2], x[1], x[0]]).as_matrix().T
    return np.concatenate([R_bn @ [0.0, 0.0, -g], R_bn @ np.asarray(field_n, float)])


def central_differences(h, x, eps=1e-6):
    x = np.asarray(x, float)
    return np.column_stack([(np.asarray(h(x + e)) - np.asarray(h(x - e))) / (2 * eps) for e in np.eye(len(x)) * eps])


def reference_run_ekf(gyr, acc, mag, rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate=None):
    """kfkit's Euler EKF, each step fed the mean rate over it: the trapezoid of the samples at its two ends."""
    gyr = np.asarray(gyr, dtype=float)
    mean_rate = np.vstack([gyr[:1], (gyr[:-1] + gyr[1:]) / 2])
    run = FastEulerAttitudeEKF(
        rate_hz=rate_hz,
        gyro_noise=gyro_noise,
        accel_noise=accel_noise,
        mag_noise=mag_noise,
        field_n=field_n,
        accel_gate=accel_gate,
    ).run(mean_rate, acc, mag)
    return run.euler, run.P, run.nis


def nis_per_row_by_loop(y, S, rows, samples):
    """The mean of y_rᵀ S_rr⁻¹ y_r / len(rows) over the chosen samples whose rows hold a number, one solve each."""
    values = [
        y[k, rows] @ np.linalg.solve(S[k][np.ix_(rows, rows)], y[k, rows]) / len(rows)
        for k in np.flatnonzero(samples)
        if not np.isnan(y[k, rows]).any()
    ]
    return float(np.mean(values))


def coast_by_library_q(sigma0, sigma, gyro_noise, rate_hz):
    """Seconds until a still, level board's yaw variance, growing by the library's Q_ψψ each step, reaches σ²."""
    q_yaw = filters.euler_process_noise(np.zeros(3), gyro_noise, 1.0 / rate_hz)[2, 2]
    return (sigma**2 - sigma0**2) / q_yaw / rate_hz


def van_loan_angle_bias(N, K, dt):
    """Q of [angle, bias] by the general Van Loan matrix exponential (lab 06's discretize), not lab 02's closed form."""
    return discrete.discretize([[0.0, -1.0], [0.0, 0.0]], np.zeros(2), dt, np.diag([N**2, K**2]))[2]


def kfkit_run_sideslip(params, r_std=(0.003, 0.05), model=V.linear_model, **s):  # run_sideslip's signature
    return estimate_sideslip(**s, params=params, gyro_noise=r_std[0], accel_noise=r_std[1], model=model).beta


def q_by_search(tau, dt, r):
    """The q whose steady-state roll filter has Δt/K∞ = tau, found by bisection on log q (not by the closed form)."""
    log_q = brentq(lambda lq: np.log(dt / filters.roll_kf_steady_state(10.0**lq, r)[1] / tau), -30.0, 5.0, xtol=1e-15)
    return 10.0**log_q


def hard_iron_budget_by_search(field_ned, max_error_deg):
    """The largest |h| whose worst level heading error, over h's direction on a fine grid, is max_error_deg: a search,
    not lab 03's B_h·sin ε."""
    north, east = field_ned[0], field_ned[1]
    turn = np.linspace(0.0, 2 * np.pi, 200_001)

    def worst_deg(length):
        err = np.arctan2(east + length * np.sin(turn), north + length * np.cos(turn)) - np.arctan2(east, north)
        return np.degrees(np.max(np.abs(frames.wrap_angle(err))))

    return brentq(lambda length: worst_deg(length) - max_error_deg, 0.0, 0.999 * np.hypot(north, east), xtol=1e-12)


# lab 04b's answers from scipy's Rotation (scalar-last there): independent of kfkit.frames and kfkit.labs.lab04b
def scipy_rotation(q):
    return Rotation.from_quat(np.asarray(q, float)[[1, 2, 3, 0]])


def scalar_first(r):
    return r.as_quat()[[3, 0, 1, 2]]


def scipy_quat_exp(omega_prev, omega, dt):
    return scalar_first(Rotation.from_rotvec((np.asarray(omega_prev) + omega) / 2 * dt))


def scipy_mekf_predict(q, b, P, omega_prev, omega, dt, gyro_noise, bias_rw):
    step = Rotation.from_rotvec((np.asarray(omega_prev) + omega - 2 * b) / 2 * dt)
    F = np.block([[step.as_matrix().T, -np.eye(3) * dt], [np.zeros((3, 3)), np.eye(3)]])
    return (
        scalar_first(scipy_rotation(q) * step),
        b,
        F @ P @ F.T + np.diag([(gyro_noise * dt) ** 2] * 3 + [bias_rw**2 * dt] * 3),
    )


def scipy_h(q, v_n):
    return scipy_rotation(q).inv().apply(v_n)


def scipy_error_jacobian(q, v_n, eps=1e-6):
    """Central differences of R(q ⊗ exp(δθ/2))ᵀ v_n in δθ, and zero bias columns (3×6)."""
    turned = lambda d: scalar_first(scipy_rotation(q) * Rotation.from_rotvec(d))
    return np.hstack(
        [
            np.column_stack(
                [(scipy_h(turned(e), v_n) - scipy_h(turned(-e), v_n)) / (2 * eps) for e in np.eye(3) * eps]
            ),
            np.zeros((3, 3)),
        ]
    )


def scipy_mekf_reset(q, b, P, dx):
    J = np.eye(6)
    J[:3, :3] -= np.cross(np.eye(3), 0.5 * np.asarray(dx[:3]))  # I − [δθ/2 ×]: row i of [w×] is e_i × w
    return scalar_first(scipy_rotation(q) * Rotation.from_rotvec(dx[:3])), b + dx[3:], J @ P @ J.T


def scipy_mekf_update(q, b, P, z, R, field_n):
    rows = slice(0, 3) if np.isnan(z[3:]).any() else slice(0, 6)
    H = np.vstack([scipy_error_jacobian(q, [0.0, 0.0, -g]), scipy_error_jacobian(q, field_n)])[rows]
    y = (z - np.r_[scipy_h(q, [0.0, 0.0, -g]), scipy_h(q, field_n)])[rows]
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R[rows, rows])
    return scipy_mekf_reset(q, b, (np.eye(6) - K @ H) @ P, K @ y)


def tyre_force_from_slips(params, x, delta, vx):
    """The single-track model's axle forces (N) from the slip angles α_f = δ − β − a r/V_x, α_r = −β + b r/V_x,
    each on its axle's magic formula (kfkit.vehicle.axle_tyres)."""
    front, rear = V.axle_tyres(params)
    beta, r = x
    return float(front.force(delta - beta - params.a * r / vx)), float(rear.force(-beta + params.b * r / vx))


def tyre_jacobian_by_differences(params, x, delta, vx, eps=1e-7):
    """J = ∂[β̇, ṙ]/∂[β, r] and H = ∂[r, a_y]/∂[β, r] of the nonlinear model β̇ = (F_f + F_r)/(m V_x) − r,
    ṙ = (a F_f − b F_r)/I_z, a_y = (F_f + F_r)/m, by central differences (not the local slopes)."""

    def model(state):
        ff, fr = tyre_force_from_slips(params, state, delta, vx)
        return np.array(
            [(ff + fr) / (params.m * vx) - state[1], (params.a * ff - params.b * fr) / params.Iz]
        ), np.array([state[1], (ff + fr) / params.m])

    x = np.asarray(x, dtype=float)
    cols = [[(model(x + e)[i] - model(x - e)[i]) / (2 * eps) for e in np.eye(2) * eps] for i in (0, 1)]
    return np.column_stack(cols[0]), np.column_stack(cols[1])


def banked_straight_by_balance(params, bank):
    """(a_y, β) on a straight across a bank (rad, high side left), solved as a force and moment balance of the linear
    single-track model rather than read off its closed form: F_f + F_r = m g sin(bank), a F_f − b F_r = 0, with
    F_f = C_f (δ − β) and F_r = −C_r β on a straight (r = 0), for the unknowns (δ, β); the accelerometer, tilted with
    the car, reads g sin(bank)."""
    forces = np.array(
        [[params.Cf, -params.Cf - params.Cr], [params.a * params.Cf, -params.a * params.Cf + params.b * params.Cr]]
    )
    _, beta = np.linalg.solve(forces, [params.m * constants.g * np.sin(bank), 0.0])
    return constants.g * np.sin(bank), beta


RIGHT = {
    "00.checksum": loop_xor,
    "00.board_time": unwrap,
    "01.accel_roll": lambda ay, az: np.arctan2(-ay, -az),
    "01.kf_predict": filters.roll_kf_predict,
    "01.kf_update": filters.roll_kf_update,
    "01.run_kf": reference_run_kf,
    "01.kf_beats_sensors": reference_run_kf,
    "01.fuse_gaussians": lambda mu_prior, var_prior, z, r: filters.roll_kf_update(mu_prior, var_prior, z, r)[:2],
    "01.q_for_time_constant": q_by_search,
    "02.gyro_bias": rest_calibration.gyro_bias,
    "02.noise_std": rest_calibration.noise_std,
    "02.accel_bias": rest_calibration.accel_bias,
    "02.six_face": rest_calibration.accel_six_face,
    "02.six_face_recording": rest_calibration.accel_six_face,
    "02.gyro_bias_recording": rest_calibration.gyro_bias,
    "02.noise_recording": rest_calibration.noise_std,
    "02.allan_deviation": lambda x, rate_hz, taus: allan.allan_deviation(x, rate_hz, taus)[1],
    "02.sigma_at_rate": C.noise_at_rate,
    "02.q_from_noise_density": lambda N, K, dt: van_loan_angle_bias(N, K, dt),
    "02.q_from_datasheet": lambda arw, bias_instability, rrw, dt: van_loan_angle_bias(
        arw * constants.degree / np.sqrt(constants.hour),
        rrw * constants.degree / constants.hour / np.sqrt(constants.hour),
        dt,
    ),
    "03.counts_to_ut": lambda counts: counts * 0.15,
    "03.alignment": lambda turns: np.diag([np.sign(np.sum(g * m)) for g, m in (turns[a] for a in "xyz")]),
    "03.mag_calibration": mag_calibration.fit_mag_calibration,
    "03.heading_error": mag_calibration.fit_mag_calibration,
    "03.real_magnet": mag_calibration.fit_mag_calibration,
    "03.flat_heading": frames.mag_heading,
    "03.tilt_heading": frames.tilt_compensated_heading,
    "03.hard_iron_budget": hard_iron_budget_by_search,
    "04.euler_rates": frames.body_rates_to_euler_rates,
    "04.predict": filters.euler_ekf_predict,
    "04.measurement": filters.attitude_measurement,
    "04.jacobian": filters.attitude_jacobian,
    "04.numerical_jacobian": lambda h, x: central_differences(h, x),
    "04.update": filters.euler_ekf_update,
    "04.ekf_rmse": reference_run_ekf,
    "04.real_ekf": reference_run_ekf,
    "04b.quat_exp": scipy_quat_exp,
    "04b.mekf_predict": scipy_mekf_predict,
    "04b.accel_jacobian": lambda q: scipy_error_jacobian(q, [0.0, 0.0, -g]),
    "04b.mekf_reset": scipy_mekf_reset,
    "04b.mekf_update": scipy_mekf_update,
    "04.nis_per_row": nis_per_row_by_loop,
    "04.coast_seconds": coast_by_library_q,
    "06.bicycle_model": V.linear_model,
    "06.tyre_force": tyre_force_from_slips,
    "06.banked_road": banked_straight_by_balance,
    "06.tyre_jacobian": tyre_jacobian_by_differences,
    "06.discretize": discrete.discretize,
    "06.kf_step": sideslip_step,
    "06.slalom_rmse": kfkit_run_sideslip,
}
SEEDS = {"00": (1,), "01": (0, 1, 2), "02": (0, 1), "03": (0, 1), "04": (0, 1), "04b": (0, 1), "06": (1,)}
SEEDS_OF = {
    "04.ekf_rmse": (0,),
    "04.real_ekf": (0,),
    "06.slalom_rmse": (None,),
}  # a whole filter over bundled recordings: one run
WITHOUT_KFKIT_ANSWER = "05"  # lab 05's exercises are a pipeline of the notebook's own (test_checkpoints_every.py)


def all_checkpoints():
    get("00.checksum")  # imports every lab's module
    return sorted(REGISTRY)


def test_every_registered_checkpoint_has_a_kfkit_answer_here():
    assert {n for n in all_checkpoints() if n[:2] != WITHOUT_KFKIT_ANSWER} == set(RIGHT)
    assert {n.split(".")[0] for n in RIGHT} == set(SEEDS)


@pytest.mark.parametrize("name, seed", [(n, s) for n in sorted(RIGHT) for s in SEEDS_OF.get(n, SEEDS[n.split(".")[0]])])
def test_kfkits_answers_pass(name, seed):
    result = run_checkpoint(get(name), RIGHT[name], seed)
    assert result.ok, result.message
    assert result.message.startswith(f"✅ {name}: {result.total}/{result.total}")
    assert result.points == result.max_points > 0


@pytest.mark.parametrize("name", all_checkpoints())
def test_not_attempted_is_said_for_every_checkpoint(name):
    def stub(*args, **kwargs):
        raise NotImplementedError()

    result = run_checkpoint(get(name), stub, seed=0)
    assert result.status == "not attempted" and "not attempted yet" in result.message and result.points == 0


# --- lab 00 ------------------------------------------------------------------------------------------------------


def test_lab00_judges_name_a_sum_a_hex_text_and_an_unwrapped_clock():
    assert not run_checkpoint(get("00.checksum"), lambda body: sum(body) % 256, seed=1).ok
    hex_text = run_checkpoint(get("00.checksum"), lambda body: f"{loop_xor(body):02X}", seed=1)
    assert "not its hex text" in hex_text.message
    naive = run_checkpoint(get("00.board_time"), lambda t_us: (np.asarray(t_us) - t_us[0]) / 1e6, seed=1)
    assert not naive.ok and "t_us went" in naive.message


# --- lab 01 ------------------------------------------------------------------------------------------------------


def test_atan2_off_by_pi_is_named():
    result = run_checkpoint(get("01.accel_roll"), lambda ay, az: np.arctan2(ay, az), seed=0)
    assert result.status == "failed" and "180° off" in result.message and "Hint:" in result.message
    assert result.points == 0


def test_predict_that_forgets_q_fails_with_expected_and_got():
    result = run_checkpoint(get("01.kf_predict"), lambda x, P, omega, dt, q: (x + omega * dt, P), seed=0)
    assert result.status == "failed"
    assert (
        "value 2 of 2: expected" in result.message and ", got " in result.message and "kf_predict(x=" in result.message
    )


def test_update_returning_two_values_is_explained():
    result = run_checkpoint(get("01.kf_update"), lambda x, P, z, r: (x, P), seed=0)
    assert "expected 4 values" in result.message


def test_run_kf_that_skips_updates_fails_the_bundled_recording():
    def gyro_only(gyro_rate, roll_acc, dt, q, r, x0, P0):
        x = filters.integrate_rate(gyro_rate, dt, x0)
        return x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)

    result = run_checkpoint(get("01.kf_beats_sensors"), gyro_only)
    assert result.status == "failed" and "is not below" in result.message


def test_not_attempted(capsys):
    def stub(**kwargs):
        raise NotImplementedError()

    result = check("01.kf_update", stub)
    assert result.status == "not attempted" and result.points == 0
    assert "not attempted yet" in capsys.readouterr().out


def test_student_exception_is_reported_not_raised():
    result = run_checkpoint(get("01.kf_predict"), lambda x, P, omega, dt, q: 1 / 0, seed=0)
    assert result.status == "error" and "ZeroDivisionError" in result.message


def test_unknown_checkpoint_lists_known_ones():
    with pytest.raises(KeyError, match="01.kf_predict"):
        get("01.nope")


def test_compare_structure_and_tolerance():
    assert compare((1.0, np.array([1.0, 2.0])), (1.0 + 1e-12, [1.0, 2.0])) is None
    assert compare(np.zeros(3), np.zeros(4)) == "shape mismatch: expected shape (3,), got shape (4,)"
    assert compare(1.0, "one").startswith("expected a number")
    assert compare(1.0, 1.1) is not None


# --- labs 02 and 03 ----------------------------------------------------------------------------------------------


def test_heading_checkpoint_catches_the_half_turn_atan2():
    def off_by_pi(m_b, roll, pitch, declination=0.0):  # atan2(m_y', −m_x'): both arguments negated
        return frames.wrap_angle(frames.tilt_compensated_heading(m_b, roll, pitch, declination) + np.pi)

    result = run_checkpoint(get("03.tilt_heading"), off_by_pi, seed=0)
    assert not result.ok and "exactly 180° off" in result.message


def test_lab02_judges_name_gravity_and_ddof():
    assert "gravity is still in it" in run_checkpoint(get("02.accel_bias"), lambda acc, expected: acc.mean(0)).message
    assert "ddof=0" in run_checkpoint(get("02.noise_std"), lambda x: x.std(axis=0)).message


def test_alignment_checkpoint_against_scipy_rotation():
    # 180° about y negates x and z: the sign matrix the checkpoint expects for the IIS2MDC
    D = Rotation.from_euler("y", np.pi).as_matrix()
    np.testing.assert_allclose(D, np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    result = run_checkpoint(
        get("03.alignment"),
        lambda turns: np.diag([np.sign(np.sum(g * m)) for g, m in (turns[a] for a in "xyz")]),
        seed=1,
    )
    assert result.ok, result.message


def test_uncalibrated_magnetometer_fails_the_heading_checkpoint():
    result = run_checkpoint(get("03.heading_error"), lambda mag: (np.zeros(3), np.eye(3)))
    assert not result.ok and "uncalibrated" in result.message


def test_allan_checkpoint_names_a_normalisation_factor():
    result = run_checkpoint(
        get("02.allan_deviation"), lambda x, rate_hz, taus: 2 * allan.allan_deviation(x, rate_hz, taus)[1]
    )
    assert "constant factor 2" in result.message


def _geometric_fit(mag):
    """A different, sound answer: the reference fit refined by minimising ‖S(m − h)‖ − B (scipy least squares)."""
    h0, S0 = mag_calibration.fit_mag_calibration(mag)
    iu = np.triu_indices(3)

    def unpack(p):
        S = np.zeros((3, 3))
        S[iu] = p[3:]
        return p[:3], S + np.triu(S, 1).T

    fit = least_squares(
        lambda p: np.linalg.norm((mag - unpack(p)[0]) @ unpack(p)[1].T, axis=1) - B_LONDON, np.concatenate([h0, S0[iu]])
    )
    return unpack(fit.x)


def test_mag_calibration_checkpoint_judges_against_the_true_ellipsoid():
    cp = get("03.mag_calibration")
    assert run_checkpoint(cp, _geometric_fit, seed=3).ok
    cholesky = lambda mag: (lambda h, S: (h, np.linalg.cholesky(S.T @ S).T))(*mag_calibration.fit_mag_calibration(mag))
    assert "not symmetric" in run_checkpoint(cp, cholesky, seed=3).message
    unscaled = lambda mag: (lambda h, S: (h, S / B_LONDON))(*mag_calibration.fit_mag_calibration(mag))
    assert "scale S by B" in run_checkpoint(cp, unscaled, seed=3).message
    centre_only = lambda mag: (mag.mean(axis=0), np.eye(3))
    assert "off by" in run_checkpoint(cp, centre_only, seed=3).message


@pytest.mark.slow
def test_bundled_recording_checks_reject_estimates_a_few_uncertainties_off():
    from kfkit.labs.lab02 import gyro_bias_truth, noise_truth, six_face_truth

    rec = datasets.load("02_six_faces")
    _, _, u_b, u_s = six_face_truth(rec)
    assert run_checkpoint(get("02.six_face_recording"), rest_calibration.accel_six_face).ok
    off = lambda faces: (lambda b, s: (b + 6 * u_b, s))(*rest_calibration.accel_six_face(faces))
    assert "standard uncertainties away" in run_checkpoint(get("02.six_face_recording"), off).message
    off_scale = lambda faces: (lambda b, s: (b, s + 6 * u_s))(*rest_calibration.accel_six_face(faces))
    assert not run_checkpoint(get("02.six_face_recording"), off_scale).ok
    still = datasets.load("02_stationary")
    _, u_g = gyro_bias_truth(still)
    assert not run_checkpoint(get("02.gyro_bias_recording"), lambda gyr: rest_calibration.gyro_bias(gyr) + 6 * u_g).ok
    sigma, u, n = noise_truth(still, "gyr")
    assert np.all(u / sigma < 0.02) and n == 1500  # 2 min at 12.5 Hz: σ known to 2 %
    assert not run_checkpoint(get("02.noise_recording"), lambda x: 1.1 * rest_calibration.noise_std(x)).ok
    assert not run_checkpoint(get("02.noise_recording"), lambda x: rest_calibration.noise_std(x) ** 0.5).ok


# --- lab 04 ------------------------------------------------------------------------------------------------------


def test_any_correct_jacobian_passes():
    """H by central differences of an h built on scipy's rotations, not on kfkit's."""
    result = run_checkpoint(
        get("04.jacobian"), lambda x, field_n: central_differences(lambda v: h_scipy(v, field_n), x)
    )
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
        F = np.eye(3) + dt * filters.euler_ekf.euler_kinematics_jacobian(x, omega_b)
        return np.asarray(x) + frames.body_rates_to_euler_rates(x, omega_b) * dt, F @ P @ F.T + Q

    result = run_checkpoint(get("04.predict"), unwrapped, seed=0)
    assert result.status == "failed" and "not wrapped" in result.message


def test_predict_that_forgets_F_fails_with_expected_and_got():
    def no_F(x, P, omega_b, dt, Q):
        x_new = np.asarray(x) + frames.body_rates_to_euler_rates(x, omega_b) * dt
        x_new[2] = frames.wrap_angle(x_new[2])
        return x_new, P + Q

    result = run_checkpoint(get("04.predict"), no_F, seed=1)
    assert (
        result.status == "failed"
        and "value 2 of 2: expected" in result.message
        and "first difference at index" in result.message
    )


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


@pytest.mark.parametrize("eps", [1e-5, 1e-6, 1e-7, 1e-8])
def test_a_forward_difference_fails_at_every_step_and_is_named(eps):
    # issue 26 §7: the old linear cases passed any forward difference; on a quadratic h a central one is exact
    def forward(h, x):
        x = np.asarray(x, float)
        return np.column_stack([(np.asarray(h(x + e)) - np.asarray(h(x))) / eps for e in np.eye(len(x)) * eps])

    for seed in range(3):
        result = run_checkpoint(get("04.numerical_jacobian"), forward, seed=seed)
        assert result.status == "failed" and "a one-sided difference" in result.message, result.message


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
        x_k = filters.attitude_run.tilt_heading(acc[0], mag[0], field_n)
        for k, w in enumerate(gyr):
            x_k = x_k + frames.body_rates_to_euler_rates(x_k, w) / rate_hz
            x[k] = x_k
        return x, None, None

    result = run_checkpoint(get("04.ekf_rmse"), gyro_only)
    assert result.status == "failed" and result.message.startswith("❌ 04.ekf_rmse: 2/5")  # bundled and gated pass
    assert "extra gyro bias" in result.message and "roll RMSE" in result.message and "(limit 3°)" in result.message
    assert "are the accelerometer and magnetometer updates applied?" in result.message


def test_a_filter_that_drops_the_magnetometer_fails_on_yaw():
    def no_mag(gyr, acc, mag, rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate=None):
        return reference_run_ekf(
            gyr, acc, np.full_like(mag, np.nan), rate_hz, gyro_noise, accel_noise, mag_noise, field_n, accel_gate
        )

    result = run_checkpoint(get("04.ekf_rmse"), no_mag)
    assert result.status == "failed" and "yaw RMSE" in result.message


def test_rmse_checkpoint_explains_a_wrong_shape():
    result = run_checkpoint(get("04.ekf_rmse"), lambda **kw: (np.zeros((10, 3)), None, None))
    assert "expected 6240 rows of [roll, pitch, yaw]" in result.message


# --- lab 06 ------------------------------------------------------------------------------------------------------


def test_lab06_judges_name_the_classic_mistakes():
    copied = run_checkpoint(get("06.bicycle_model"), V.miscopied_linear_model, seed=1)
    assert not copied.ok and "widely copied model" in copied.message
    euler = run_checkpoint(get("06.discretize"), lambda A, B, dt, Qc: (np.eye(2) + A * dt, B * dt, Qc * dt), seed=1)
    assert not euler.ok and "Euler" in euler.message

    def no_d_term(x, P, delta_prev, z, delta, Ad, Bd, Qd, C, D, R):
        return sideslip_step(x, P, delta_prev, z, 0.0, Ad, Bd, Qd, C, D, R)

    no_d = run_checkpoint(get("06.kf_step"), no_d_term, seed=1)
    assert not no_d.ok and "misses the D-term" in no_d.message
    zero = run_checkpoint(get("06.slalom_rmse"), lambda t, **_: np.zeros_like(t))
    assert not zero.ok and "0/3 bundled slaloms" in zero.message and "expected under 0.5°" in zero.message

    # the copied model stays under 0.5° at 20 km/h (β there is mostly kinematic) but not at 80 km/h
    copied_run = run_checkpoint(
        get("06.slalom_rmse"), lambda **s: kfkit_run_sideslip(**s, model=V.miscopied_linear_model)
    )
    assert not copied_run.ok and "1/3" in copied_run.message and "80 km/h" in copied_run.message
    assert "expected under 0.1°" in copied_run.message

    def b_as_a_row(params, vx):
        A, B, C, D = V.linear_model(params, vx)
        return A, B.ravel(), C, D

    flat = run_checkpoint(get("06.bicycle_model"), b_as_a_row, seed=1)
    assert not flat.ok and "B has shape (2,), expected (2, 1)" in flat.message


# --- the hint matches the kind of failure: the checkpoint's own only for wrong numbers ------------------------------


def not_for_arrays(**kwargs):
    return math.atan2(np.ones(3), np.ones(3))  # math takes one number: a function written for scalars


def shapes_that_do_not_fit(**kwargs):
    return np.ones(3) @ np.ones(2)


def divides_by_zero(**kwargs):
    return 1 / 0


def returns_nan(**kwargs):
    return float("nan")


def returns_nothing(**kwargs):
    pass


KINDS = {  # student function → words of the hint its failure must get
    not_for_arrays: "is called with NumPy arrays",
    shapes_that_do_not_fit: "shapes do not fit together",
    divides_by_zero: "a division by zero",
    returns_nan: "NaN or inf comes from",
    returns_nothing: "returns None when no return statement runs",
}


@pytest.mark.parametrize("name", all_checkpoints())
def test_every_checkpoint_gives_the_hint_of_the_failures_kind_not_its_own(name):
    """`math.atan2` on arrays used to get the atan2-sign hint of 01.accel_roll, and every exception, NaN or missing
    return its checkpoint's hint about the numbers. The grader's path too: its exception is rebuilt from the
    kernel's class name and message (kfkit.grading.core), so kinds are matched by name."""
    from kfkit.grading.core import _student_exception

    cp = get(name)
    drawn = cp.cases(np.random.default_rng(0))
    cp = dataclasses.replace(cp, cases=lambda rng: drawn)  # drawn once: some build a filter's whole run
    for student, words in KINDS.items():
        result = run_checkpoint(cp, student)
        assert not result.ok and words in result.message and cp.hint not in result.message, (student.__name__, result)

        def in_the_kernel(student=student, **kwargs):
            try:
                return student(**kwargs)
            except Exception as e:  # as the grader sees it: a class of that name, that message
                raise _student_exception(type(e).__name__, str(e)) from None

        assert words in run_checkpoint(cp, in_the_kernel).message, student.__name__


def test_wrong_numbers_keep_the_checkpoints_own_hint_and_a_wrong_form_says_the_expected_one():
    cp = get("01.accel_roll")
    assert cp.hint in run_checkpoint(cp, lambda ay, az: np.arctan2(ay, az), seed=0).message
    update = run_checkpoint(get("01.kf_update"), lambda x, P, z, r: (x, P), seed=0).message
    assert "Hint: return a tuple of 4 numbers, as the exercise's docstring says" in update
    run_kf = run_checkpoint(get("01.run_kf"), lambda **kw: np.zeros((3, 2)), seed=0).message
    assert re.search(r"Hint: return a tuple of 4 arrays of shape \(\d+,\)", run_kf), run_kf
    jacobian = run_checkpoint(
        get("04.jacobian"), lambda x, field_n: np.zeros((3, 6)), seed=0
    ).message  # a judge's words
    assert "got shape (3, 6)" in jacobian and "Hint: return an array of shape (6, 3)" in jacobian, jacobian


@pytest.mark.parametrize(
    "raised, words",
    [
        (
            TypeError("f() got an unexpected keyword argument 'omega'"),
            "the check calls kf_predict(x, P, omega, dt, q) by these names",
        ),
        (NameError("name 'kf_gain' is not defined"), "a name kf_predict uses is not defined"),
        (ValueError("math domain error"), "outside its domain"),
        (KeyError("x"), "run kf_predict yourself on the input shown"),
    ],
)
def test_other_exception_kinds(raised, words):
    def student(**kwargs):
        raise raised

    message = run_checkpoint(get("01.kf_predict"), student, seed=0).message
    assert words in message and get("01.kf_predict").hint not in message
