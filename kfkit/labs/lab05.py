"""What lab 05's notebook calls beyond the library: its recordings and their windows, the truth it judges by, the
noise model lab 02 measured, and the two loops section 12 runs on a real IMU turned about every axis.

The checkpoints (:mod:`kfkit.checkpoints.lab05`) build their cases from the same helpers.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from .. import calibration, datasets, rest_calibration, sensors
from ..discrete import angle_bias_process_noise
from ..filters import TiltBiasKF, accel_static_ok, protocol_angles, tilt_kf_predict, tilt_kf_update
from ..frames import G, accel_tilt, body_rates_to_euler_rates, mount_matrix, wrap_angle
from ..metrics import angle_error, rmse

BOARD = sensors.MPU6050_GY521
Q_BIAS_RATIO = 1e-4  # q_b = 10⁻⁴ q_θ while tuning on the holds: the cost is flat in q_b once the bias has converged
ROLL_MIN = 0.5  # g: roll is updated only while √(f_y² + f_z²) ≥ 0.5 g (pitch within ±60°)
#: s cut from each end of a BROAD rest: its movement flag lets the hand still move there (trial 04: the gyro's σ
#: over a whole rest is 3–7 mrad/s, without its outer 2 s 0.9–1.1 mrad/s, as in the middle of the long first rest)
REST_TRIM = 2.0
REAL = "05_broad_rotation_breaks"  # section 12.2: rotations about all axes with rests between them
SINGLE_AXIS = "01_broad_slow_rotation"  # section 12.1: BROAD trial 02, turned mostly about x from 40 s
#: trial 02 turns about x (roll through full circles) until its pitch first passes this (102 s), then about all axes
SINGLE_AXIS_MAX_PITCH = np.radians(15.0)
MAX_TAN_PITCH = np.radians(60.0)  # tan θ of the left-out rates taken at most here: the roll gate stops updates beyond


def bundled():
    """Lab 05's bundled recordings: (tilt protocol, 10 s stationary, six faces)."""
    return datasets.load("05_tilt_protocol"), datasets.load("05_stationary"), datasets.load("05_six_faces")


def body_si(rec, to_body):
    """(f_b in m/s², ω_b in rad/s), (N, 3) each: an MPU6050's counts through ``to_body`` (the student's), any other
    IMU through its own sensitivities and mounting (``rec.body``)."""
    if rec.meta.get("board") == BOARD.name:
        return to_body(rec.counts("acc"), rec.counts("gyr"))
    return rec.body("acc"), rec.body("gyr")


def lab02_calibration(rec, source):
    """Lab 02's calibration of the recording's board: the kit's default for the bundled recordings
    (``source == "bundled"``), else the one the student saved (else the default); None for an IMU that is not an
    MPU6050 (section 12's, calibrated by its dataset's authors)."""
    if rec.meta.get("board") != BOARD.name:
        return None
    return calibration.load_calibration(
        BOARD.name, path=calibration.bundled_calibration_path(BOARD.name) if source == "bundled" else None
    )


def noise_densities(cal, w_still, dt):
    """The gyro's white-noise density N and rate random walk K (3,) each, rad/√s and rad/s/√s: lab 02's
    (``cal.gyro_density``, ``cal.gyro_bias_walk``), or without a calibration N = σ·√Δt of the rates at rest
    ``w_still`` (N, 3) and K = 0 (a rest of seconds cannot show the walk)."""
    if cal is not None:
        return np.asarray(cal.gyro_density), np.asarray(cal.gyro_bias_walk, dtype=float)
    return np.std(w_still, axis=0) * np.sqrt(dt), np.zeros(3)


def shipped_process_noise(dt=0.01):
    """(q_θ, q_b) the firmware ships (rad², (rad/s)²): Van Loan's diagonal from the bundled MPU6050 calibration's N and
    K (:func:`kfkit.discrete.angle_bias_process_noise`), averaged over x and y (one setting serves both axes)."""
    cal = calibration.Calibration.load(calibration.bundled_calibration_path(BOARD.name))
    Q = [angle_bias_process_noise(N, K, dt) for N, K in zip(cal.gyro_density[:2], cal.gyro_bias_walk[:2])]
    return float(np.mean([q[0, 0] for q in Q])), float(np.mean([q[1, 1] for q in Q]))


# --- where the angles are known ------------------------------------------------------------------------------------


def rest_windows(rec, trim=REST_TRIM) -> list[tuple[float, float]]:
    """The (start, end) windows (s) of a recording's ``rest`` phases, ``trim`` s shorter at each end."""
    return [
        (p["start"] + trim, p["end"] - trim)
        for p in rec.phases
        if p["label"] == "rest" and p["end"] - p["start"] > 2 * trim
    ]


def in_windows(rec, windows):
    """(N,) True where the recording's time lies in one of the (start, end) windows (s)."""
    mask = np.zeros(len(rec), dtype=bool)
    for a, b in windows:
        mask |= (rec.t >= a) & (rec.t < b)
    return mask


def known_angles(rec):
    """(roll, pitch) in rad where the recording itself tells the angle, NaN elsewhere, each (N,): the tilt
    protocol's holds (:func:`~kfkit.filters.protocol_angles`), or for a recording with motion-capture truth and
    ``rest`` phases (BROAD) the truth during its rests (:func:`rest_windows`)."""
    if "true_roll" not in rec.columns or not any(p["label"] == "rest" for p in rec.phases):
        return protocol_angles(rec)
    still = in_windows(rec, rest_windows(rec))
    return tuple(np.where(still, rec[name], np.nan) for name in ("true_roll", "true_pitch"))


def true_gyro_bias(rec) -> np.ndarray:
    """The simulated gyro bias in the body frame (rad/s): M_bs · b_s from the recording's metadata."""
    return mount_matrix(rec.meta["mount"]["gyr"]) @ np.asarray(rec.meta["sim"]["gyro_bias"], float)


def static_rmse(angle, reference):
    """RMSE (rad) of ``angle`` over the samples where the protocol's angle is known (``reference`` not NaN)."""
    known = ~np.isnan(reference)
    return float(np.sqrt(np.mean((np.asarray(angle)[known] - reference[known]) ** 2)))


def hold_rmse_deg(angle, known):
    """RMSE (°) over the holds, where the protocol's angle is known."""
    return np.degrees(static_rmse(angle, known))


def motion_rmse_deg(angle, truth, col, where=None):
    """RMSE (°) of ``angle`` against ``truth[:, col]`` (N, ≥ 2: roll, pitch; rad) over the samples ``where`` (default
    all) whose truth is known; roll only where it is defined, |pitch| < 60°. Angle differences are wrapped."""
    use = ~np.isnan(truth[:, col]) if where is None else where & ~np.isnan(truth[:, col])
    if col == 0:
        use &= np.abs(truth[:, 1]) < np.radians(60)
    return float(np.degrees(rmse(angle_error(np.asarray(angle)[use], truth[use, col]), 0.0)))


def single_axis_stretch():
    """Section 12.1's real recording: BROAD trial 02 from its start (40 s at rest) to the end of its turns mostly
    about x (roll through full circles), where |pitch| first passes :data:`SINGLE_AXIS_MAX_PITCH` (102 s)."""
    rec = datasets.load(SINGLE_AXIS)
    tilted = rec.phase("movement") & (np.abs(rec["true_pitch"]) > SINGLE_AXIS_MAX_PITCH)
    return rec.head(rec.t[np.argmax(tilted)] - rec.t[0])


# --- the reference pipeline and tuning -----------------------------------------------------------------------------


def pipeline_inputs(tilt=None, still=None, faces=None):
    """kfkit's reference pipeline up to the filter: per axis (gyro rate, accel angle, static_ok, known angle), dt, r,
    q0."""
    if tilt is None:
        tilt, still, faces = bundled()
    bias, scale = rest_calibration.accel_six_face(
        {f: faces.body("acc")[faces.phase(f)] for f in rest_calibration.FACES}
    )
    f = (tilt.body("acc") - bias) / scale
    roll, pitch = accel_tilt(f)
    ok = accel_static_ok(f)
    roll_ok = ok & (np.hypot(f[:, 1], f[:, 2]) >= ROLL_MIN * G)
    roll_ref, pitch_ref = protocol_angles(tilt)
    gyr = tilt.body("gyr")
    still_roll, still_pitch = accel_tilt((still.body("acc") - bias) / scale)
    dt = 1.0 / tilt.rate_hz
    r = float(np.mean([np.var(still_roll), np.var(still_pitch)]))
    q0 = float(np.mean(np.var(still.body("gyr")[:, :2], axis=0))) * dt**2
    axes = {"roll": (gyr[:, 0], roll, roll_ok, roll_ref), "pitch": (gyr[:, 1], pitch, ok, pitch_ref)}
    return axes, dt, r, q0


def tune_on_holds(gyro_rate, accel_angle, static_ok, reference, dt, r, q0):
    """kfkit's tuning, skip gate: q_θ minimising the MSE over the holds (``reference`` not NaN), q_b = 10⁻⁴ q_θ.

    The cost is not unimodal over the decades above the gyro-noise q0, so first scan
    log₁₀ q_θ = log₁₀ q0 + 0, 0.5, …, 6, then refine with a bounded scalar search (Brent) within
    half a decade of the best. Returns (q_angle, q_bias).
    """

    def mse(log_q):
        run = TiltBiasKF(dt, q_angle=10**log_q, q_bias=Q_BIAS_RATIO * 10**log_q, r=r).run(
            gyro_rate, accel_angle, static_ok
        )
        return static_rmse(run.angle, reference) ** 2

    grid = np.log10(q0) + np.arange(0.0, 6.5, 0.5)
    start = min(grid, key=mse)
    best = minimize_scalar(mse, bounds=(start - 0.5, start + 0.5), method="bounded", options={"xatol": 0.02})
    return 10**best.x, Q_BIAS_RATIO * 10**best.x


# --- section 12: a known term in the prediction, or in Q -----------------------------------------------------------


def left_out_rates(w, roll, pitch):
    """(roll, pitch) rates the per-axis model leaves out (rad/s), each (N,): [φ̇, θ̇] − [p, q] by ZYX kinematics
    (:func:`~kfkit.frames.body_rates_to_euler_rates`), from body rates ``w`` (N, 3, rad/s, bias removed) and the
    angles (rad), tan θ taken at most at :data:`MAX_TAN_PITCH`:

        c_φ = tan θ (q sin φ + r cos φ),    c_θ = q (cos φ − 1) − r sin φ
    """
    euler = np.column_stack([roll, np.clip(pitch, -MAX_TAN_PITCH, MAX_TAN_PITCH), np.zeros(len(roll))])
    left_out = body_rates_to_euler_rates(euler, w)[:, :2] - np.asarray(w)[:, :2]
    return left_out[:, 0], left_out[:, 1]


def run_nearest(gyro_rate, accel_angle, static_ok, dt, Q, r, x0=None, P0=None, q_extra=None):
    """The skip-gated filter on :func:`~kfkit.filters.tilt_kf_predict` and :func:`~kfkit.filters.tilt_kf_update`
    for angles that go round: each accelerometer angle is taken within ±180° of the prediction, θ⁻ + wrap(z − θ⁻).
    ``q_extra`` (N,) rad², if given, is added to q_θ at each step (Q_k = Q + diag(q_extra_k, 0)).
    x0 None: [first accelerometer angle, 0]; P0 None: diag(r, (0.1 rad/s)²). Returns [angle, bias] (N, 2)."""
    x = np.array([accel_angle[0], 0.0] if x0 is None else x0, dtype=float)
    P = np.diag([r, 0.1**2]) if P0 is None else np.asarray(P0, dtype=float)
    extra = np.zeros(len(accel_angle)) if q_extra is None else np.asarray(q_extra, dtype=float)
    xs = np.empty((len(accel_angle), 2))
    for k, (w, z, ok, q) in enumerate(zip(gyro_rate, accel_angle, static_ok, extra)):
        x, P = tilt_kf_predict(x, P, w, dt, Q + np.diag([q, 0.0]))
        if ok:
            x, P, _, _ = tilt_kf_update(x, P, x[0] + wrap_angle(z - x[0]), r)
        xs[k] = x
    return xs
