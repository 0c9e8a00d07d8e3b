"""kfkit.vehicle: bicycle models against physics and independent oracles, scenarios, vehicle CSVs."""

import json
import math
import warnings

import numpy as np
import pytest
from scipy.integrate import quad_vec, solve_ivp
from scipy.linalg import expm, solve_discrete_are
from scipy.signal import cont2discrete, lsim

from kfkit import discrete
from kfkit import io as kio
from kfkit import vehicle as V
from kfkit.filters import estimate_sideslip
from kfkit.frames import G
from kfkit.io import RecordingError
from kfkit.readers.vehicle_csv import load_vehicle_csv, sign_check

CAR = V.BicycleParams()


def random_params(rng):
    return V.BicycleParams(
        m=rng.uniform(900, 2500),
        Iz=rng.uniform(1200, 4500),
        a=rng.uniform(0.9, 1.5),
        b=rng.uniform(1.2, 1.8),
        Cf=rng.uniform(6e4, 2e5),
        Cr=rng.uniform(6e4, 2.5e5),
    )


# --- parameters ----------------------------------------------------------------------------


def test_default_car_understeers_with_the_textbook_gradient():
    assert CAR.a * CAR.Cf < CAR.b * CAR.Cr
    # Rajamani (2012) eq. for the understeer gradient with per-axle stiffness: K = m/L (b/Cf − a/Cr)
    assert CAR.understeer_gradient == pytest.approx(1573 / 2.68 * (1.58 / 160e3 - 1.10 / 160e3))


@pytest.mark.parametrize("field, value", [("m", 0.0), ("Cf", -1.0), ("Iz", float("nan"))])
def test_bad_parameters_are_named(field, value):
    with pytest.raises(ValueError, match=f"BicycleParams.{field}"):
        V.BicycleParams(**{field: value})


# --- the linear model ----------------------------------------------------------------------


@pytest.mark.parametrize("vx", [0.0, -3.0, float("nan")])
def test_linear_model_refuses_a_speed_it_would_divide_by(vx):
    with pytest.raises(ValueError, match="Vx > 0"):
        V.linear_model(CAR, vx)


def test_ay_row_is_vx_times_betadot_plus_r():
    """a_y = V_x (β̇ + r): the output row must equal V_x·(first state row + [0, 1]) at any state and input."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        p, vx = random_params(rng), rng.uniform(2, 45)
        A, B, C, D = V.linear_model(p, vx)
        np.testing.assert_allclose(C[1], vx * (A[0] + [0.0, 1.0]), rtol=1e-12)
        np.testing.assert_allclose(D[1], vx * B[0], rtol=1e-12)


def test_units_check_passes_the_model_and_catches_the_copied_errors():
    assert all(V.units_consistent(V.linear_model).values())
    # mass cancels in every entry: a car heavier by 3× in every mass-carrying parameter has the same model
    heavy = V.BicycleParams(m=3 * CAR.m, Iz=3 * CAR.Iz, a=CAR.a, b=CAR.b, Cf=3 * CAR.Cf, Cr=3 * CAR.Cr)
    for same, other in zip(V.linear_model(CAR, 15.0), V.linear_model(heavy, 15.0)):
        np.testing.assert_allclose(other, same, rtol=1e-12)

    def a_y_per_beta_over_vx(params, vx):  # a student's slip: C[1,0] = −(Cf+Cr)/(m Vx), in 1/s instead of m/s²
        A, B, C, D = V.linear_model(params, vx)
        C = C.copy()
        C[1, 0] /= vx
        return A, B, C, D

    assert [k for k, ok in V.units_consistent(a_y_per_beta_over_vx).items() if not ok] == ["C[1,0]"]
    wrong = V.units_consistent(V.miscopied_linear_model)
    assert not wrong["A[0,1]"] and not wrong["A[1,0]"]
    # the third copied error (+V_x·r in a_y) is dimensionally consistent: only physics catches it
    assert wrong["C[1,1]"]
    _, r, ay = V.steady_state(CAR, 20.0, 0.01)
    A, B, C, D = V.miscopied_linear_model(CAR, 20.0)
    x = -np.linalg.solve(A, B[:, 0] * 0.01)
    assert (C @ x + D[:, 0] * 0.01)[1] != pytest.approx(20.0 * x[1], rel=0.05)  # steady state must give a_y = V_x r
    assert ay == pytest.approx(20.0 * r, rel=1e-9)


def test_steady_state_yaw_gain_matches_the_understeer_formula():
    """Textbook steady cornering: r/δ = V_x / (L + K V_x²) with K = m/L·(b/Cf − a/Cr)."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        p, vx, delta = random_params(rng), rng.uniform(3, 40), rng.uniform(-0.05, 0.05)
        L = p.a + p.b
        K = p.m / L * (p.b / p.Cf - p.a / p.Cr)
        beta, r, ay = V.steady_state(p, vx, delta)
        assert r == pytest.approx(vx / (L + K * vx**2) * delta, rel=1e-9)
        # sideslip at steady state: β = (b/L − m a V_x² / (L² Cr)) δ / (1 + K V_x²/L)   (same textbook)
        assert beta == pytest.approx(
            (p.b / L - p.m * p.a * vx**2 / (L**2 * p.Cr)) * delta / (1 + K * vx**2 / L), rel=1e-9
        )


@pytest.mark.parametrize("vx", [20 / 3.6, 15.0, 80 / 3.6])
def test_linear_model_matches_the_nonlinear_model_at_small_slip(vx):
    """Steady state at a_y = 0.5 m/s²: the nonlinear model's a_y within 2 % of the linear one's."""
    delta = 0.5 / V.steady_state(CAR, vx, 1.0)[2]
    t = np.arange(0.0, 8.0, 0.01)
    out = V.simulate_nonlinear(CAR, t, np.full_like(t, delta), vx)
    beta, r, ay = V.steady_state(CAR, vx, delta)
    assert out["ay"][-1] == pytest.approx(0.5, rel=0.02)
    assert out["r"][-1] == pytest.approx(r, rel=0.02)
    assert out["beta"][-1] == pytest.approx(beta, rel=0.05, abs=2e-5)


def test_linear_model_follows_the_nonlinear_transient_at_small_slip():
    """Sinusoidal steering for a_y ≈ 0.5 m/s²: scipy's lsim of (A, B, C, D) tracks the nonlinear truth within 2 %.

    Unlike the steady state (which only sees A⁻¹B), the transient exercises every entry of A and the D-term.
    """
    for vx, freq in [(20 / 3.6, 0.3), (80 / 3.6, 0.6)]:
        t = np.arange(0.0, 6.0, 0.002)
        delta = 0.5 / V.ay_gain(CAR, vx, freq) * np.sin(2 * np.pi * freq * t)
        truth = V.simulate_nonlinear(CAR, t, delta, vx, substeps=1)
        _, z, x = lsim((*V.linear_model(CAR, vx),), delta, t, interp=False)  # ZOH input, like the truth
        peak = np.max(np.abs(truth["ay"]))
        assert peak == pytest.approx(0.5, rel=0.03)
        assert np.max(np.abs(z[:, 1] - truth["ay"])) < 0.02 * peak
        assert np.max(np.abs(z[:, 0] - truth["r"])) < 0.02 * np.max(np.abs(truth["r"]))
        assert np.max(np.abs(x[:, 0] - truth["beta"])) < 0.02 * np.max(np.abs(truth["beta"]))


def steady_beta_std(A, B, C, R, dt=0.01, Qc=np.diag([1e-4, 1e-3])):
    """Steady-state posterior σ_β (rad) of a KF measuring C x with noise R: the DARE's answer, not our filter's."""
    Ad, _, Qd = discrete.discretize(A, B, dt, Qc)
    prior = solve_discrete_are(Ad.T, C.T, Qd, R)
    post = prior - prior @ C.T @ np.linalg.solve(C @ prior @ C.T + R, C @ prior)
    return math.sqrt(post[0, 0])


def test_observability_yaw_rate_only_vs_with_lateral_acceleration():
    A, B, C, D = V.linear_model(CAR, 15.0)

    def obs(A, C):
        return np.vstack([C @ np.linalg.matrix_power(A, i) for i in range(A.shape[0])])

    assert np.linalg.matrix_rank(obs(A, C[:1])) == 2 and np.linalg.matrix_rank(obs(A, C)) == 2
    # yaw rate alone sees β only through the weak yaw moment (b Cr − a Cf) β / Iz: observable in theory,
    # poorly in practice. Steady-state σ_β with the kit's sensor noise (0.003 rad/s, 0.05 m/s²):
    yaw_only = steady_beta_std(A, B, C[:1], np.array([[0.003**2]]))
    both = steady_beta_std(A, B, C, np.diag([0.003**2, 0.05**2]))
    assert both < math.radians(0.05) and yaw_only > 5 * both
    # a neutral-steer car (a Cf = b Cr): β leaves no trace in r at all
    neutral = V.BicycleParams(Cf=CAR.b * CAR.Cr / CAR.a)
    An, _, Cn, _ = V.linear_model(neutral, 15.0)
    assert np.linalg.matrix_rank(obs(An, Cn[:1])) == 1 and np.linalg.matrix_rank(obs(An, Cn)) == 2
    # an a_y bias state is invisible to the gyro, visible with a_y
    Ab = np.pad(A, ((0, 1), (0, 1)))
    Cb = np.hstack([C, [[0.0], [1.0]]])
    assert np.linalg.matrix_rank(obs(Ab, Cb[:1])) == 2 and np.linalg.matrix_rank(obs(Ab, Cb)) == 3


# --- discretisation ------------------------------------------------------------------------


def with_bias_state(A, B):
    """The lab's augmented model [β, r, b_ay]: a random-walk bias (A gets a zero row and column)."""
    return np.pad(A, ((0, 1), (0, 1))), np.vstack([B, [[0.0]]])


def test_zoh_matches_scipy_cont2discrete():
    rng = np.random.default_rng(3)
    for k in range(12):
        A, B, C, D = V.linear_model(random_params(rng), rng.uniform(2, 45))
        if k % 3 == 0:
            A, B = with_bias_state(A, B)
            C, D = np.hstack([C, [[0.0], [1.0]]]), D
        dt = rng.choice([0.001, 0.01, 0.05])
        Ad, Bd, _ = discrete.discretize(A, B, dt, np.eye(len(A)))
        Ad_ref, Bd_ref, *_ = cont2discrete((A, B, C, D), dt, method="zoh")
        np.testing.assert_allclose(Ad, Ad_ref, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(Bd, Bd_ref, rtol=1e-10, atol=1e-14)


@pytest.mark.slow
def test_van_loan_matches_numerical_integration():
    """Qd = ∫₀^dt e^{As} Qc e^{Aᵀs} ds by adaptive quadrature (scipy quad_vec), not by another matrix exponential
    trick."""
    rng = np.random.default_rng(4)
    for vx, dt, bias in [(3.0, 0.01, False), (22.0, 0.02, False), (40.0, 0.1, False), (8.0, 0.01, True)]:
        A, B, *_ = V.linear_model(random_params(rng), vx)
        if bias:
            A, B = with_bias_state(A, B)
        Qc = np.diag(rng.uniform(1e-5, 1e-2, len(A)))
        _, _, Qd = discrete.discretize(A, B, dt, Qc)
        ref, _ = quad_vec(lambda s, A=A, Qc=Qc: expm(A * s) @ Qc @ expm(A * s).T, 0.0, dt, epsabs=1e-16, epsrel=1e-11)
        np.testing.assert_allclose(Qd, ref, rtol=1e-8, atol=1e-18)
        assert np.all(np.linalg.eigvalsh(Qd) > 0)
        np.testing.assert_array_equal(Qd, Qd.T)


# --- the nonlinear model -------------------------------------------------------------------


def test_magic_formula_initial_slope_is_the_cornering_stiffness():
    front, rear = V.axle_tyres(CAR)
    h = 1e-7
    assert (front.force(h) - front.force(-h)) / (2 * h) == pytest.approx(CAR.Cf, rel=1e-6)
    assert (rear.force(h) - rear.force(-h)) / (2 * h) == pytest.approx(CAR.Cr, rel=1e-6)
    # saturates near µ F_z: the front axle carries m g b / L
    assert np.max(front.force(np.linspace(0, 0.5, 500))) == pytest.approx(CAR.m * G * CAR.b / CAR.wheelbase, rel=1e-3)


def test_rk4_truth_matches_solve_ivp():
    t = np.arange(0.0, 3.0, 0.01)
    delta, vx = 0.04, 12.0
    out = V.simulate_nonlinear(CAR, t, np.full_like(t, delta), vx)
    front, rear = V.axle_tyres(CAR)

    def f(_, s):
        vy, r = s
        fyf = front.force(delta - math.atan((vy + CAR.a * r) / vx)) * math.cos(delta)
        fyr = rear.force(-math.atan((vy - CAR.b * r) / vx))
        return [(fyf + fyr) / CAR.m - vx * r, (CAR.a * fyf - CAR.b * fyr) / CAR.Iz]

    ref = solve_ivp(f, (0.0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(out["vy"], ref.y[0], atol=1e-7)
    np.testing.assert_allclose(out["r"], ref.y[1], atol=1e-7)


def test_truth_model_refuses_a_standstill():
    with pytest.raises(ValueError, match="below 0.5 m/s"):
        V.simulate_nonlinear(CAR, [0.0, 0.01], [0.0, 0.0], [0.0, 0.0])


# --- scenarios and sensors -----------------------------------------------------------------


@pytest.mark.parametrize("kmh, spacing, peak", [(20.0, 9.0, 3.0), (80.0, 18.0, 4.0)])
def test_slalom_passes_a_cone_every_half_period_at_the_asked_ay(kmh, spacing, peak):
    d = V.slalom(kmh, cone_spacing=spacing, peak_ay=peak)
    ((t0, t1, label),) = d.phases
    assert label == "slalom" and (t1 - t0) * kmh / 3.6 == pytest.approx(10 * spacing)
    inside = (d.t > t0) & (d.t < t1)
    crossings = d.t[inside][1:][np.diff(np.sign(d.delta[inside])) != 0]
    np.testing.assert_allclose(np.diff(crossings), spacing / (kmh / 3.6), atol=0.011)
    out = V.simulate_nonlinear(CAR, d.t, d.delta, d.vx)
    assert np.max(np.abs(out["ay"][d.t > t0 + 2.0])) == pytest.approx(peak, rel=0.1)


def test_lane_change_moves_the_car_over_by_the_offset():
    d = V.lane_change(60.0, offset=3.5)
    out = V.simulate_nonlinear(CAR, d.t, d.delta, d.vx)
    dt = np.diff(d.t, prepend=d.t[0])
    heading = np.cumsum(out["r"] * dt)
    y = np.cumsum(d.vx * np.sin(heading + out["beta"]) * dt)
    hold = [(s, e) for s, e, lab in d.phases if lab == "hold"][0]
    mid = np.searchsorted(d.t, 0.5 * (hold[0] + hold[1]))
    assert y[mid] == pytest.approx(3.5, rel=0.03)
    assert abs(y[-1]) < 0.5 and np.max(np.abs(out["ay"])) < 4.5


def test_simulated_sensors_have_their_noise_and_recorded_bias():
    d = V.slalom(80.0, cone_spacing=18.0)
    sensors = V.VehicleSensors()
    rec = V.simulate_drive(d, seed=5)
    bias_g, bias_a = rec.meta["sim"]["gyro_bias"], rec.meta["sim"]["accel_bias"]
    eg = rec["yaw_rate"] - rec["true_yaw_rate"]
    assert np.mean(eg) == pytest.approx(bias_g, abs=4 * sensors.gyro_noise / math.sqrt(len(eg)))
    assert np.std(eg) == pytest.approx(sensors.gyro_noise, rel=0.1)
    assert np.std(rec["vx"] - d.vx) == pytest.approx(sensors.wheel_noise / math.sqrt(2), rel=0.15)
    assert np.max(np.abs(rec["delta"] - d.delta)) <= 0.5 * sensors.steer_lsb / sensors.steer_ratio + 1e-15
    truth = V.simulate_nonlinear(CAR, d.t, d.delta, d.vx)
    assert np.mean(rec["ay"] - truth["ay"]) == pytest.approx(bias_a, abs=4 * sensors.accel_noise / math.sqrt(len(eg)))
    again = V.simulate_drive(d, seed=5)
    assert all(np.array_equal(rec[c], again[c]) for c in rec.columns)


# --- vehicle CSVs --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_drive():
    d = V.slalom(80.0, cone_spacing=18.0, cones=2, lead=0.2)
    return V.simulate_drive(d, seed=6)


def test_vehicle_recording_round_trip(tmp_path, short_drive):
    path = kio.save_vehicle(short_drive, tmp_path / "drive.csv")
    assert path.read_text().startswith("# kfkit-vehicle v1 {")
    back = kio.load_vehicle(path)
    assert back.columns == short_drive.columns and back.meta == short_drive.meta
    for c in short_drive.columns:
        np.testing.assert_allclose(back[c], short_drive[c], rtol=1e-8, atol=1e-12)


def test_load_vehicle_rejects_an_imu_recording(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text('# kfkit-recording v1 {"rate_hz": 100}\nt,seq\n0,0\n')
    with pytest.raises(
        RecordingError, match=r"imu\.csv, line 1: expected the header '# kfkit-vehicle v1.*load_vehicle_csv"
    ):
        kio.load_vehicle(path)


STUDENT = """# exported from the logger, 2025-03-01
Time [ms];Steer [deg];YawRate [deg/s];LatAcc [g];Speed [km/h];Beta [deg]
0;1.0;2.0;0.1;36.0;0.5
10;1.5;2.5;0.2;36.0;0.6
20;2.0;3.0;0.3;37.0;0.7
"""
MAPPING = {
    "t": "Time [ms]",
    "delta": "Steer [deg]",
    "yaw_rate": "YawRate [deg/s]",
    "ay": "LatAcc [g]",
    "vx": "Speed [km/h]",
    "true_beta": "Beta [deg]",
}
UNITS = {"t": "ms", "delta": "deg", "yaw_rate": "deg/s", "ay": "g", "vx": "km/h", "true_beta": "deg"}


def student_csv(tmp_path, text=STUDENT):
    path = tmp_path / "mycar.csv"
    path.write_text(text)
    return path


def test_student_csv_is_mapped_and_converted_to_si(tmp_path):
    rec = load_vehicle_csv(student_csv(tmp_path), MAPPING, UNITS, delimiter=";")
    np.testing.assert_allclose(rec.t, [0.0, 0.01, 0.02])
    np.testing.assert_allclose(rec["delta"], np.radians([1.0, 1.5, 2.0]))
    np.testing.assert_allclose(rec["yaw_rate"], np.radians([2.0, 2.5, 3.0]))
    np.testing.assert_allclose(rec["ay"], [0.1 * 9.80665, 0.2 * 9.80665, 0.3 * 9.80665])
    np.testing.assert_allclose(rec["vx"], [10.0, 10.0, 37 / 3.6])
    np.testing.assert_allclose(rec["true_beta"], np.radians([0.5, 0.6, 0.7]))
    assert rec.rate_hz == pytest.approx(100.0)


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda s: s.replace("LatAcc [g]", "Lateral"),
            r"mycar\.csv, line 2: no column 'LatAcc \[g\]' for ay \(columns in the file: .*Lateral",
        ),
        (
            lambda s: s.replace("10;1.5;2.5", "10;1,5;2.5"),
            r"mycar\.csv, line 4: column 'Steer \[deg\]' \(delta\): '1,5' is not a number",
        ),
        (
            lambda s: s.replace("10;1.5;2.5;0.2", "10;1.5;2.5;"),
            r"mycar\.csv, line 4: column 'LatAcc \[g\]' \(ay\): is empty",
        ),
        (
            lambda s: s.replace("20;2.0;3.0", "20;2.0;nan"),
            r"mycar\.csv, line 5: column 'YawRate \[deg/s\]' \(yaw_rate\): 'nan' is not a finite",
        ),
        (
            lambda s: s.replace("20;2.0", "5;2.0"),
            r"mycar\.csv, line 5: time \(column 'Time \[ms\]'\) does not increase: 5 after 10",
        ),
        (lambda s: s.replace("10;1.5;2.5;0.2;36.0;0.6", "10;1.5"), r"mycar\.csv, line 4: expected 6 fields"),
        (lambda s: s.split("\n")[0] + "\n" + s.split("\n")[1] + "\n", r"mycar\.csv, line 3: no data rows"),
    ],
)
def test_student_csv_errors_name_file_line_and_column(tmp_path, edit, message):
    with pytest.raises(RecordingError, match=message):
        load_vehicle_csv(student_csv(tmp_path, edit(STUDENT)), MAPPING, UNITS, delimiter=";")


def test_student_csv_mapping_and_unit_mistakes(tmp_path):
    path = student_csv(tmp_path)
    with pytest.raises(ValueError, match="missing vx"):
        load_vehicle_csv(path, {k: v for k, v in MAPPING.items() if k != "vx"}, UNITS, delimiter=";")
    with pytest.raises(ValueError, match="unknown steering"):
        load_vehicle_csv(path, dict(MAPPING, steering="Steer [deg]"), UNITS, delimiter=";")
    with pytest.raises(ValueError, match="unit 'mph' for vx; choose one of m/s, km/h"):
        load_vehicle_csv(path, MAPPING, dict(UNITS, vx="mph"), delimiter=";")
    with pytest.raises(FileNotFoundError, match="no file at"):
        load_vehicle_csv(tmp_path / "absent.csv", MAPPING, UNITS)


def test_student_csv_speed_zero_is_a_stop_negative_is_an_error(tmp_path):
    stopped = load_vehicle_csv(
        student_csv(tmp_path, STUDENT.replace("20;2.0;3.0;0.3;37.0", "20;2.0;3.0;0.3;0.0")),
        MAPPING,
        UNITS,
        delimiter=";",
    )
    assert stopped["vx"][-1] == 0.0  # standing still is data; the filter's low-speed guard handles it
    res = estimate_sideslip(*(stopped[c] for c in kio.VEHICLE_COLUMNS), CAR)
    assert res.low_speed[-1] and np.all(np.isfinite(res.beta))
    reversing = student_csv(tmp_path, STUDENT.replace("20;2.0;3.0;0.3;37.0", "20;2.0;3.0;0.3;-2.5"))
    with pytest.raises(
        RecordingError, match=r"mycar\.csv, line 5: column 'Speed \[km/h\]' \(vx\): -2\.5 km/h is negative"
    ):
        load_vehicle_csv(reversing, MAPPING, UNITS, delimiter=";")


def test_student_csv_row_shape_and_header_mistakes(tmp_path):
    trailing = STUDENT.replace("0.5\n", "0.5;\n").replace("0.6\n", "0.6;\n")  # spreadsheet exports end rows with ';'
    assert len(load_vehicle_csv(student_csv(tmp_path, trailing), MAPPING, UNITS, delimiter=";")) == 3
    trailing_header = STUDENT.replace("Beta [deg]\n", "Beta [deg];\n")
    assert len(load_vehicle_csv(student_csv(tmp_path, trailing_header), MAPPING, UNITS, delimiter=";")) == 3
    extra = STUDENT.replace("36.0;0.6", "36.0;0.6;12")
    with pytest.raises(RecordingError, match=r"mycar\.csv, line 4: expected 6 fields .* got 7"):
        load_vehicle_csv(student_csv(tmp_path, extra), MAPPING, UNITS, delimiter=";")
    twice = STUDENT.replace("Beta [deg]", "Speed [km/h]")
    with pytest.raises(RecordingError, match=r"mycar\.csv, line 2: column 'Speed \[km/h\]' \(for vx\) appears 2 times"):
        load_vehicle_csv(
            student_csv(tmp_path, twice), {k: v for k, v in MAPPING.items() if k != "true_beta"}, UNITS, delimiter=";"
        )


def test_student_csv_time_starts_at_zero_and_steering_wheel_angle_is_divided(tmp_path):
    text = (
        STUDENT.replace("\n0;", "\n1700000000000;")
        .replace("\n10;", "\n1700000000010;")
        .replace("\n20;", "\n1700000000020;")
    )
    rec = load_vehicle_csv(student_csv(tmp_path, text), MAPPING, UNITS, delimiter=";", steer_ratio=16.0)
    np.testing.assert_allclose(rec.t, [0.0, 0.01, 0.02], atol=1e-9)
    assert rec.meta["t0"] == pytest.approx(1.7e9)
    np.testing.assert_allclose(rec["delta"], np.radians([1.0, 1.5, 2.0]) / 16.0)
    with pytest.raises(ValueError, match="steer_ratio must be a positive number"):
        load_vehicle_csv(student_csv(tmp_path), MAPPING, UNITS, delimiter=";", steer_ratio=0.0)


def logger_export(rec, path, flip=(), kmh=True):
    """A bundled drive written as a logger would: own column names, degrees, km/h, g, trailing ';'."""
    sign = {c: (-1.0 if c in flip else 1.0) for c in ("delta", "yaw_rate", "ay")}
    lines = ["# logger export", "Zeit [s];Lenkwinkel [deg];Gierrate [deg/s];Querbeschl [g];v [km/h];beta [deg];"]
    for row in zip(
        rec.t,
        sign["delta"] * np.degrees(rec["delta"]),
        sign["yaw_rate"] * np.degrees(rec["yaw_rate"]),
        sign["ay"] * rec["ay"] / G,
        rec["vx"] * (3.6 if kmh else 1.0),
        np.degrees(rec["true_beta"]),
    ):
        lines.append(";".join(f"{v:.10g}" for v in row) + ";")
    path.write_text("\n".join(lines) + "\n")
    return path


LOGGER = {
    "t": "Zeit [s]",
    "delta": "Lenkwinkel [deg]",
    "yaw_rate": "Gierrate [deg/s]",
    "ay": "Querbeschl [g]",
    "vx": "v [km/h]",
    "true_beta": "beta [deg]",
}
LOGGER_UNITS = {"delta": "deg", "yaw_rate": "deg/s", "ay": "g", "vx": "km/h", "true_beta": "deg"}


def test_a_logger_export_of_a_drive_loads_back_to_the_same_si_signals(tmp_path, short_drive):
    path = logger_export(short_drive, tmp_path / "export.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # signs are right: no warning
        rec = load_vehicle_csv(path, LOGGER, LOGGER_UNITS, delimiter=";")
    for c in ("t", "delta", "yaw_rate", "ay", "vx", "true_beta"):
        np.testing.assert_allclose(rec[c], short_drive[c], rtol=1e-8, atol=1e-10)
    assert sign_check(*(short_drive[c] for c in ("delta", "yaw_rate", "ay", "vx"))) == []


@pytest.mark.parametrize(
    "flip, advice",
    [
        (("ay",), r"a_y has the wrong sign: pass negate=\('ay',\)"),
        (("yaw_rate",), r"the yaw rate has the wrong sign: pass negate=\('yaw_rate',\)"),
        (("yaw_rate", "ay"), r"negate=\('yaw_rate', 'ay'\) if the logger's axes are y right, z down"),
    ],
)
def test_flipped_signs_are_named_and_negate_fixes_them(tmp_path, short_drive, flip, advice):
    path = logger_export(short_drive, tmp_path / "frd.csv", flip=flip)
    with pytest.warns(
        UserWarning, match=r"frd\.csv: in the turns \(\d+ samples\) the signs of δ, r and a_y disagree.*" + advice
    ):
        load_vehicle_csv(path, LOGGER, LOGGER_UNITS, delimiter=";")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fixed = load_vehicle_csv(path, LOGGER, LOGGER_UNITS, delimiter=";", negate=flip)
    np.testing.assert_allclose(fixed["ay"], short_drive["ay"], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(fixed["yaw_rate"], short_drive["yaw_rate"], rtol=1e-8, atol=1e-10)
    assert fixed.meta["negated"] == list(flip)


# --- bad input to the loaders: cut lines, metadata, numbers, fuzz --------------------------------------------


def test_load_vehicle_rejects_a_cut_last_line_bad_metadata_and_duplicate_columns(tmp_path, short_drive):
    path = kio.save_vehicle(short_drive, tmp_path / "drive.csv")
    text = path.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[:-4])  # '0.0123456' cut to '0.01234': it still parses
    with pytest.raises(RecordingError, match=r"cut\.csv, line \d+: the last line is cut short"):
        kio.load_vehicle(cut)
    header, rest = text.split("\n", 1)
    meta = json.loads(header[len(kio.VEHICLE_MAGIC) :])
    for rate in (0, -100.0, float("nan"), "100", None):
        bad = tmp_path / "rate.csv"
        bad.write_text(kio.VEHICLE_MAGIC + json.dumps({**meta, "rate_hz": rate}) + "\n" + rest)
        with pytest.raises(RecordingError, match=r"rate\.csv, line 1: .*'rate_hz' must be a positive finite number"):
            kio.load_vehicle(bad)
    phases = tmp_path / "phases.csv"
    phases.write_text(
        kio.VEHICLE_MAGIC + json.dumps({**meta, "phases": [{"label": "x", "start": 3, "end": 1}]}) + "\n" + rest
    )
    with pytest.raises(RecordingError, match=r"phases\.csv, line 1: metadata phases\[0\]"):
        kio.load_vehicle(phases)
    dup = tmp_path / "dup.csv"
    columns, rows = rest.split("\n", 1)
    dup.write_text(
        header + "\n" + columns + ",vx\n" + "\n".join(r + ",1" for r in rows.rstrip("\n").split("\n")) + "\n"
    )
    with pytest.raises(RecordingError, match=r"dup\.csv, line 2: duplicate column names: vx"):
        kio.load_vehicle(dup)
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert kio.load_vehicle(bom).meta == kio.load_vehicle(path).meta


def test_student_csv_drops_a_last_line_without_newline_with_a_warning(tmp_path):
    cut = STUDENT.rstrip("\n")[:-2]  # the last row's Beta '0.7' cut to '0': a wrong number that parses
    with pytest.warns(UserWarning, match=r"mycar\.csv, line 5: the last line has no newline.*dropped"):
        rec = load_vehicle_csv(student_csv(tmp_path, cut), MAPPING, UNITS, delimiter=";")
    assert len(rec) == 2 and rec.meta["warnings"] and "line 5" in rec.meta["warnings"][0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_vehicle_csv(student_csv(tmp_path), MAPPING, UNITS, delimiter=";").meta["warnings"] == []


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda s: s.replace("10;1.5;2.5", "10;1_5;2.5"),
            r"line 4: column 'Steer \[deg\]' \(delta\): '1_5' is not a number",
        ),
        (
            lambda s: s.replace("10;1.5;2.5", "10;1e999;2.5"),
            r"line 4: column 'Steer \[deg\]' \(delta\): '1e999' is not a finite",
        ),
        (
            lambda s: s.replace("10;1.5;2.5", "10;\u0661;2.5"),
            r"line 4: column 'Steer \[deg\]' \(delta\): .* is not a number",
        ),
        (lambda s: "\n".join(s.split("\n")[:3]) + "\n", r"line 3: only one data row"),
    ],
    ids=["underscore", "overflow", "unicode-digit", "one-row"],
)
def test_student_csv_numbers_are_plain_decimal_and_a_drive_has_two_rows(tmp_path, edit, message):
    with pytest.raises(RecordingError, match=r"mycar\.csv, " + message):
        load_vehicle_csv(student_csv(tmp_path, edit(STUDENT)), MAPPING, UNITS, delimiter=";")


@pytest.mark.parametrize(
    "loader, where", [("load_vehicle", "row"), ("load_vehicle_csv", "row"), ("load_vehicle_csv", "header")]
)  # load_vehicle splits its header itself
def test_a_field_beyond_the_csv_modules_limit_names_file_and_line(tmp_path, short_drive, loader, where):
    """csv's own "field larger than field limit (131072)" used to escape with no file or line."""
    path = kio.save_vehicle(short_drive, tmp_path / "drive.csv")
    lines = path.read_text().split("\n")
    at = 1 if where == "header" else 9  # the column line, or a data row
    lines[at] = '"' + "9" * 200_000 + '",' + lines[at]
    path.write_text("\n".join(lines))
    with pytest.raises(
        RecordingError,
        match=rf"drive\.csv, line {at + 1}: not readable as CSV \(field larger than "
        r"field limit",
    ):
        if loader == "load_vehicle":
            kio.load_vehicle(path)
        else:
            load_vehicle_csv(path, {c: c for c in kio.VEHICLE_COLUMNS}, comment="#")


def test_fuzzed_vehicle_files_load_the_same_numbers_or_name_the_file(tmp_path, short_drive):
    from test_io import check_fuzzed, same_rows

    own = kio.vehicle_text(kio.Recording(short_drive.meta, {k: v[:60] for k, v in short_drive.data.items()}))
    ref = kio.load_vehicle(student_csv(tmp_path, own))
    outcome = check_fuzzed(tmp_path / "fuzzed.csv", kio.load_vehicle, own.encode(), RecordingError, same_rows(ref))
    assert outcome["rejected"] > 100
    ref = load_vehicle_csv(student_csv(tmp_path), MAPPING, UNITS, delimiter=";")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the dropped-line warnings are the point elsewhere
        outcome = check_fuzzed(
            tmp_path / "fuzzed.csv",
            lambda p: load_vehicle_csv(p, MAPPING, UNITS, delimiter=";"),
            STUDENT.encode(),
            RecordingError,
            same_rows(ref),
        )
    assert outcome["rejected"] > 100 and outcome["loaded"] > 0
