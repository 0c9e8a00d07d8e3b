"""Lab 04 (the Euler-angle EKF): what a gyro sample means for a step, the consistency section's Monte Carlo, the
tuning recipe's NIS table, the real BROAD excerpts and their truth, and the ablation that separates why the Euler EKF
breaks on BROAD's fast rotations.

The notebook's exercises (``euler_rates``, ``ekf_predict``, ``measurement``, ``jacobian``, ``numerical_jacobian``,
``ekf_update``, ``run_ekf``, ``nis_per_row``, ``coast_seconds``) stay in the notebook; :func:`nis_table` takes the
student's ``nis_per_row`` as an argument, so the recipe reads the student's own NIS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import datasets, filters, metrics, motions
from ..calibration import Calibration, calibration_for
from ..filters.attitude_run import learn_field, tilt_heading
from ..filters.euler_ekf import (
    EulerAttitudeEKFSettings,
    attitude_measurement,
    euler_kinematics_jacobian,
    euler_rate_matrix,
    jacobian_rows,
)
from ..frames import (
    MAG_FIELD_LONDON,
    G,
    dcm_to_euler,
    euler_rates_to_body_rates,
    euler_to_dcm,
    euler_to_quat,
    quat_multiply,
    quat_to_dcm,
    wrap_angle,
)
from ..rest_calibration import gyro_bias

# --- the gyro sample and the step ------------------------------------------------------------------------------


def midpoint_rates(gyr):
    """The mean body rate over each step t_{k−1} → t_k (rad/s, (N, 3)) from gyro samples that are the rate *at* their
    instants (a simulation's; a sensor whose filter does not average over its sample interval): the trapezoid
    ½(ω_{k−1} + ω_k), exact for a rate that changes linearly over the step; the first row is ω_0 (no step before it).
    A gyro whose sample is already the mean over the interval before it is used as it is."""
    gyr = np.asarray(gyr, dtype=float)
    return np.vstack([gyr[:1], 0.5 * (gyr[:-1] + gyr[1:])])


# --- section 8: consistency by Monte Carlo ------------------------------------------------------------------------

#: the Monte Carlo's start: each run starts this uncertain, and its x0 is drawn from it (rad²)
P0_MC = np.diag(np.radians([2.0, 2.0, 4.0]) ** 2)


def simulate_white(motion, sigmas, field_n, rng):
    """The Euler EKF's own model, exactly: the rate ω_b at each sample's instant, f_b = R_bn(−g_n), m_b = R_bn m_n,
    each plus white noise of σ = ``sigmas`` (rad/s, m/s², µT); the magnetometer on every other row (NaN between)."""
    sigma_gyro, sigma_acc, sigma_mag = sigmas
    R_bn = np.swapaxes(euler_to_dcm(motion.euler), 1, 2)
    n = len(motion.t)
    gyr = motion.omega_b + rng.normal(0.0, sigma_gyro, (n, 3))
    acc = R_bn @ np.array([0.0, 0.0, -G]) + rng.normal(0.0, sigma_acc, (n, 3))
    mag = R_bn @ np.asarray(field_n, dtype=float) + rng.normal(0.0, sigma_mag, (n, 3))
    mag[1::2] = np.nan
    return gyr, acc, mag


def one_run(motion, sigmas, field_n, rng, midpoint=True):
    """One simulated run of ``motion`` through kfkit's Euler EKF told the true σ's and started as uncertain as its P0
    says: (NEES at each step (N − 1,), Σ NIS, Σ dof). The step t_{k−1} → t_k is fed the midpoint rate, or with
    ``midpoint=False`` the sample at its end, ω_k."""
    gyr, acc, mag = simulate_white(motion, sigmas, field_n, rng)
    x0 = motion.euler[0] + rng.multivariate_normal(np.zeros(3), P0_MC)
    settings = EulerAttitudeEKFSettings(*sigmas, accel_gate=None)  # σ_ω, σ_a, σ_m
    ekf = filters.FastEulerAttitudeEKF(rate_hz=motion.rate_hz, settings=settings, field_n=field_n, x0=x0, P0=P0_MC)
    steps = midpoint_rates(gyr)[1:] if midpoint else gyr[1:]
    run = ekf.run(steps, acc[1:], mag[1:])
    return metrics.nees(metrics.angle_error(run.euler, motion.euler[1:]), run.P), run.nis.sum(), run.dof.sum()


def monte_carlo(motion, sigmas, field_n, runs=20, seed=11, midpoint=True):
    """``runs`` runs of :func:`one_run`: (the NEES averaged over the runs at each step, Σ NIS, Σ dof of them all)."""
    rng = np.random.default_rng(seed)
    nees_runs, nis_sums, dof_sums = zip(*(one_run(motion, sigmas, field_n, rng, midpoint) for _ in range(runs)))
    return np.mean(nees_runs, axis=0), sum(nis_sums), sum(dof_sums)


def nees_summary(name, result, motion, runs, moving=(5.0, 57.0)):
    """One line on a :func:`monte_carlo` result of ``motion`` (its phases (start, end, label) in s): how much of the
    time
    the run-averaged NEES is inside its 95 % bounds, its median while moving (``moving``: from, to, s) and in the
    tumble, and the NIS per row against its bounds."""
    avg_nees, nis_total, dof_total = result
    lo, hi = metrics.chi2_bounds(3, runs)
    t = motion.t[1:]
    within = (t >= moving[0]) & (t < moving[1])
    tumble = np.any([(t >= a) & (t < b) for a, b, label in motion.phases if label == "tumble"], axis=0)
    nis_lo, nis_hi = metrics.chi2_bounds(1, dof_total)
    return (
        f"{name}: average NEES inside its bounds {100 * ((avg_nees >= lo) & (avg_nees <= hi)).mean():3.0f} % of the "
        f"time, median {np.median(avg_nees[within]):5.1f} while moving ({np.median(avg_nees[tumble]):.1f} in the "
        f"tumble); NIS per row {nis_total / dof_total:.3f} (bounds {nis_lo:.3f} … {nis_hi:.3f})"
    )


# --- section 9: tuning without truth ------------------------------------------------------------------------------

#: the innovation rows of each sensor in the Euler EKF's y = [f_b; m_b]
SENSOR_ROWS = {"accelerometer": [0, 1, 2], "magnetometer": [3, 4, 5]}
#: the recipe's phases, found without truth: at rest the gyro and the specific force's norm stay quiet for a second
REST_RATE, REST_ACCEL, REST_SECONDS = np.radians(2.0), 0.1, 1.0  # rad/s, m/s², s


def rest_and_motion(gyr, acc, rate_hz, rest_rate=REST_RATE, rest_accel=REST_ACCEL, seconds=REST_SECONDS):
    """{"at rest": mask, "moving": mask} (N,) of a recording without truth or labels: at rest where, for ``seconds``
    around the sample, ‖ω‖ < ``rest_rate`` (rad/s) and |‖f‖ − g| < ``rest_accel`` (m/s²); moving everywhere else."""
    quiet = (np.linalg.norm(gyr, axis=1) < rest_rate) & (np.abs(np.linalg.norm(acc, axis=1) - G) < rest_accel)
    half = max(1, int(round(seconds * rate_hz / 2)))
    loud = np.convolve(~quiet, np.ones(2 * half + 1), mode="same") > 0
    return {"at rest": ~loud, "moving": loud}


def noise_at_rest(gyr, acc, mag, rest):
    """Lab 02's measurement on the first stretch of ``rest`` (a mask): each sensor's σ per sample, the mean of its
    three axes (rad/s, m/s², µT; the magnetometer's NaN rows skipped). One stretch: at another attitude the
    accelerometer and magnetometer read other means."""
    start = int(np.argmax(rest))
    end = start + (int(np.argmin(rest[start:])) or len(rest) - start)
    first = slice(start, end)
    return (
        float(gyr[first].std(axis=0).mean()),
        float(acc[first].std(axis=0).mean()),
        float(np.nanstd(mag[first], axis=0).mean()),
    )


def nis_table(run, masks, nis_per_row, out=print):
    """The recipe's table: the NIS per row of each sensor's innovations (:data:`SENSOR_ROWS`) in each phase
    (``masks``: {phase: mask}), by the student's ``nis_per_row(y, S, rows, samples)``. Prints it; returns
    {sensor: {phase: NIS per row}}."""
    table = {
        sensor: {group: float(nis_per_row(run.y, run.S, rows, mask)) for group, mask in masks.items()}
        for sensor, rows in SENSOR_ROWS.items()
    }
    out(f"{'NIS per row (1 expected)':26s}" + "".join(f"{group:>10s}" for group in masks))
    for sensor, row in table.items():
        out(f"{sensor:26s}" + "".join(f"{value:10.2f}" for value in row.values()))
    return table


# --- section 14: real sensors (BROAD) ------------------------------------------------------------------------------

#: the real recording the student's filter runs on (BROAD trial 06) and how much of it: the whole first rest (where the
#: gyro bias and the field are learned), then the first REAL_MOVING_SECONDS of rotations by hand, up to 7 rad/s and
#: 77° of pitch (the fast part after them, up to 16 rad/s, is where the ablation below looks)
#: the simulated tour the lab (and its graded runs) filter
RECORDING = "04_attitude_tour"
REAL_RECORDING, REAL_MOVING_SECONDS = "04_broad_fast_rotation", 30.0
#: both bundled BROAD excerpts: 06 (fast rotations) and 28 (a magnet near the path)
REAL_TRIALS = ("04_broad_fast_rotation", "04_broad_stationary_magnet")
#: the part of the first rest the truth's own error is measured on (s): before anything moves
TRUTH_CHECK_SECONDS = 10.0


def rest_calibration(rec) -> Calibration:
    """A BROAD recording's calibration: the dataset comes calibrated by its authors, but its gyro keeps a
    bias, measured as in lab 02: the mean rate over the first rest (rad/s); nothing else is corrected."""
    first_rest = rec.phase("rest") & (rec.t < rec.phases[0]["end"])
    return Calibration(
        board=rec.meta["board"],
        rate_hz=rec.rate_hz,
        gyro_bias=gyro_bias(rec.body("gyr")[first_rest]),
        source=f"{rec.meta['source']}: calibrated by its authors; gyro bias = mean of the first rest",
    )


def movement_start(rec) -> float:
    """When the recording's first movement phase starts (s from its first sample)."""
    moving = rec.phase("movement")
    if not moving.any():
        raise ValueError(f"recording {rec.path or ''}: its 'movement' phase holds no sample")
    return float(rec.t[np.argmax(moving)] - rec.t[0])


def real_inputs(name=REAL_RECORDING, seconds=None, moving_seconds=None):
    """A bundled BROAD excerpt as lab 04 uses it: (recording, gyr rad/s, acc m/s², mag µT, field_n µT NED
    learned at the start (magnetic north, as the truth's), truth quaternions body → NED (NaN where the
    markers were not seen), BROAD's movement mask); only the first ``seconds`` if given, or only up to
    ``moving_seconds`` after the first movement starts (the whole first rest kept)."""
    rec = datasets.load(name)
    if moving_seconds is not None:
        seconds = movement_start(rec) + moving_seconds
    rec = rec if seconds is None else rec.head(seconds)
    gyr, acc, mag = rest_calibration(rec).apply(rec)
    return rec, gyr, acc, mag, learn_field(acc, mag), euler_to_quat(rec.truth()), rec.phase("movement")


def to_movement_end(name):
    """:func:`real_inputs` of a whole trial cut at the end of its movement (BROAD counts nothing after it and the
    filters are causal): (recording, gyr, acc, mag, field_n, truth quaternions, movement mask)."""
    rec, gyr, acc, mag, field_n, q_true, moving = real_inputs(name)
    end = np.flatnonzero(moving)[-1] + 1
    return rec, gyr[:end], acc[:end], mag[:end], field_n, q_true[:end], moving[:end]


def truth_error_at_rest(rec, acc, mag, seconds=TRUTH_CHECK_SECONDS):
    """How far the optical truth itself is from what the IMU senses, before anything moves (rad): the angle
    between the accelerometer's "down" and the truth's (the sensor-to-marker alignment, the accelerometer's
    bias) and the heading of the measured field in the truth's frame (the truth's north against the
    magnetometer's, which is the filter's), combined as √(inclination² + heading²)."""
    still = (rec.t - rec.t[0] < seconds) & rec.phase("rest") & ~np.isnan(rec["true_roll"])
    R_nb = euler_to_dcm(rec.truth()[still])
    f_n = np.einsum("nij,nj->ni", R_nb, acc[still]).mean(axis=0)
    m_n = np.einsum("nij,nj->ni", R_nb, mag[still]).mean(axis=0)
    return float(np.hypot(np.arccos(-f_n[2] / np.linalg.norm(f_n)), np.arctan2(m_n[1], m_n[0])))


def broad_errors(q, q_true, moving):
    """BROAD's total (heading / inclination) RMSE over the movement of the first len(q) samples, as text (°)."""
    e = {k: np.degrees(v) for k, v in metrics.attitude_rmse(q, q_true[: len(q)], moving[: len(q)]).items()}
    return f"{e['total']:5.2f} ({e['heading']:.2f} / {e['inclination']:.2f})"


# --- the ablation: the Euler EKF plus one of the MEKF's features at a time ----------------------------------------


@dataclass(frozen=True)
class Variant:
    """One row of the ablation: the lab's Euler EKF (midpoint rate, one Euler step per sample, all six rows) with
    some of the MEKF's features added.

    substeps       the state integrated in this many Euler steps per sample, the rate interpolated linearly
                   between ω_{k−1} and ω_k (the same information; F and Q once per sample, as the lab's)
    bias_state     a gyro-bias state b (3 more states): ω − b drives the kinematics, F's bias block −G(x)Δt,
                   b a random walk (the MEKF's 1e-5 rad/s/√s, P0 (0.5 °/s)²)
    heading_only   the magnetometer as a heading (the tilt-compensated field's, H = [0, 0, 1]: a turn about the
                   vertical changes ψ alone) instead of three rows, and only while the field's norm and dip agree
                   with the reference's within 10 % and 10° (for a second after it last did not: the MEKF's gates)
    accel_lowpass  the accelerometer low-passed (τ = 1 s) in a frame turned by the gyro alone, where rotation does
                   not move gravity and the hand's linear acceleration averages out (VQF's idea; the MEKF's)
    """

    label: str
    substeps: int = 1
    bias_state: bool = False
    heading_only: bool = False
    accel_lowpass: bool = False


ABLATION = (
    Variant("Euler EKF, as in the lab"),
    Variant("+ 5 substeps", substeps=5),
    Variant("+ 5 substeps + gyro-bias state", substeps=5, bias_state=True),
    Variant("+ 5 substeps + heading-only gated magnetometer", substeps=5, heading_only=True),
    Variant("+ 5 substeps + stabilised accelerometer", substeps=5, accel_lowpass=True),
    Variant("+ 5 substeps + all three", substeps=5, bias_state=True, heading_only=True, accel_lowpass=True),
)
#: the heading-only magnetometer's gates: relative norm, dip (rad), and how long (s) the field must pass them again
MAG_NORM_GATE, MAG_DIP_GATE, MAG_RECOVERY = 0.1, math.radians(10.0), 1.0
ACCEL_TAU = 1.0  # s
BIAS_WALK, BIAS_SIGMA0 = 1e-5, math.radians(0.5)  # rad/s/√s, rad/s


def stabilised_accel(gyr, acc, rate_hz, tau=ACCEL_TAU):
    """The accelerometer low-passed with time constant ``tau`` (s) in a frame I turned by the gyro alone:
    q_I ← q_I ⊗ exp(ω Δt/2), f_I = R(q_I) f_b low-passed, f̄_b = R(q_I)ᵀ f̄_I ((N, 3), m/s²). Rotation does not move
    gravity in I (for the seconds the gyro holds it), so only what changes there, the linear acceleration, is
    averaged out."""
    dt = 1.0 / rate_hz
    angle = np.linalg.norm(gyr, axis=1) * dt
    half = 0.5 * angle
    axis = np.divide(gyr, np.linalg.norm(gyr, axis=1, keepdims=True), out=np.zeros_like(gyr), where=angle[:, None] > 0)
    steps = np.column_stack([np.cos(half), axis * np.sin(half)[:, None]])
    q, a = np.array([1.0, 0.0, 0.0, 0.0]), 1.0 - math.exp(-dt / tau)
    f_I, out = np.array(acc[0], dtype=float), np.empty_like(acc)
    for k in range(len(acc)):
        q = quat_multiply(q, steps[k]) if k else q
        q /= np.linalg.norm(q)
        R = quat_to_dcm(q)
        f_I += a * (R @ acc[k] - f_I)
        out[k] = R.T @ f_I
    return out


def ablation_run(variant: Variant, gyr, acc, mag, rate_hz, field_n, settings=EulerAttitudeEKFSettings()):
    """The lab's Euler EKF with ``variant``'s features over a recording (gyr (N, 3) rad/s, acc m/s², mag µT with
    NaN rows = no sample): [φ, θ, ψ] (N, 3), rad. ``settings``: the lab's σ's and accelerometer gate."""
    dt, st = 1.0 / rate_hz, settings
    field_n = np.asarray(field_n, dtype=float)
    if variant.accel_lowpass:
        acc = stabilised_accel(gyr, acc, rate_hz)
    n = 6 if variant.bias_state else 3
    fresh = ~np.isnan(mag[:, 0])
    x = np.zeros(n)
    x[:3] = tilt_heading(acc[0], mag[np.argmax(fresh)], field_n)
    P = np.diag(np.r_[np.radians([5.0, 5.0, 10.0]) ** 2, [BIAS_SIGMA0**2] * 3][:n])
    gate = _HeadingGate(field_n)
    out, previous = np.empty((len(gyr), 3)), gyr[0]
    for k, (w, f, m) in enumerate(zip(gyr, acc, mag)):
        x, P = _ablation_predict(x, P, previous, w, dt, st.gyro_noise, variant.substeps)
        previous = w
        gated = st.accel_gate is not None and abs(np.linalg.norm(f) - G) > st.accel_gate
        r_acc = st.accel_noise**2 * (st.accel_inflation if gated else 1.0)
        rows = 6 if fresh[k] and not variant.heading_only else 3
        x, P = _update(
            x,
            P,
            np.r_[f, m][:rows],
            attitude_measurement(x[:3], field_n)[:rows],
            _jacobian(x, field_n)[:rows],
            [r_acc] * 3 + [st.mag_noise**2] * (rows - 3),
        )
        if fresh[k] and variant.heading_only:
            y = gate.innovation(k * dt, euler_to_dcm(x[:3]) @ m)
            if y is not None:
                x, P = _update(
                    x, P, np.array([y]), np.zeros(1), np.array([[0.0, 0.0, 1.0]]), [gate.r_psi(st.mag_noise)]
                )
        out[k] = x[:3]
    return out


def _ablation_predict(x, P, w0, w1, dt, gyro_noise, substeps):
    """F and Q at the step's start with the midpoint rate (the lab's); the state in ``substeps`` Euler steps."""
    n = len(x)
    b = x[3:] if n == 6 else np.zeros(3)
    E = euler_rate_matrix(x[:3])
    F = np.eye(n)
    F[:3, :3] += dt * euler_kinematics_jacobian(x[:3], 0.5 * (w0 + w1) - b)
    Q = np.zeros((n, n))
    Q[:3, :3] = E @ E.T * (gyro_noise * dt) ** 2
    if n == 6:
        F[:3, 3:] = -dt * E
        Q[3:, 3:] = np.eye(3) * BIAS_WALK**2 * dt
    x = x.copy()
    for j in range(substeps):
        w = w0 + (j + 0.5) / substeps * (w1 - w0) - b
        x[:3] = x[:3] + euler_rate_matrix(x[:3]) @ w * dt / substeps
    x[2] = wrap_angle(x[2])
    return x, F @ P @ F.T + Q


def _jacobian(x, field_n):
    """H (6×3) of the lab's h(x) at one state, from the same rows as :func:`attitude_jacobian` (on floats: faster)."""
    sf, cf, st, ct, sp, cp = (f(a) for a in x[:3] for f in (math.sin, math.cos))
    return np.array(jacobian_rows(sf, cf, st, ct, sp, cp, *(float(v) for v in field_n)))


def _update(x, P, z, h, H_angles, variances):
    """The EKF update (Joseph form) of the state's angles with z, h(x), H (rows × 3) and R = diag(variances)."""
    H = np.zeros((len(z), len(x)))
    H[:, :3] = H_angles
    R = np.diag(variances)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ (z - h)
    x[2] = wrap_angle(x[2])
    IKH = np.eye(len(x)) - K @ H
    return x, IKH @ P @ IKH.T + K @ R @ K.T


class _HeadingGate:
    """The heading of a magnetometer sample, and whether to use it: the field turned into NED with the current
    attitude must agree with the reference in norm (:data:`MAG_NORM_GATE`) and dip (:data:`MAG_DIP_GATE`), and have
    agreed for :data:`MAG_RECOVERY` s since it last did not."""

    def __init__(self, field_n):
        m_n, e_n, d_n = field_n
        self.horizontal, self.psi_ref = math.hypot(m_n, e_n), math.atan2(e_n, m_n)
        self.norm, self.dip = float(np.linalg.norm(field_n)), math.atan2(d_n, self.horizontal)
        self.good_since = -math.inf

    def r_psi(self, mag_noise):
        """The variance of one sample's heading (rad²): σ_m over the horizontal field."""
        return (mag_noise / self.horizontal) ** 2

    def innovation(self, t, m_n):
        """ψ_ref − the heading of the field ``m_n`` (NED, µT), wrapped (rad), or None if the gates refuse it."""
        horizontal = math.hypot(m_n[0], m_n[1])
        if (
            abs(np.linalg.norm(m_n) - self.norm) > MAG_NORM_GATE * self.norm
            or abs(math.atan2(m_n[2], horizontal) - self.dip) > MAG_DIP_GATE
        ):
            self.good_since = math.inf
        elif self.good_since > t:
            self.good_since = t
        if t - self.good_since < MAG_RECOVERY:
            return None
        return float(wrap_angle(self.psi_ref - math.atan2(m_n[1], m_n[0])))


def ablation(trials=REAL_TRIALS, variants=ABLATION, settings=EulerAttitudeEKFSettings()):
    """BROAD's errors of each variant on each whole trial (to the end of its movement): {label: {trial: {"total",
    "heading", "inclination"} (°)}}. About ten seconds per row and trial."""
    table = {v.label: {} for v in variants}
    for name in trials:
        rec, gyr, acc, mag, field_n, q_true, moving = to_movement_end(name)
        for v in variants:
            errors = metrics.attitude_rmse(
                euler_to_quat(ablation_run(v, gyr, acc, mag, rec.rate_hz, field_n, settings)), q_true, moving
            )
            table[v.label][name] = {k: float(np.degrees(e)) for k, e in errors.items()}
    return table


# --- the graded runs' inputs (lab 04's checkpoints judge run_ekf on them) ----------------------------------------

#: noise_free_turns' number of one-second turns
TURNS = 5


def bundled_inputs():
    """Lab 04's inputs: the bundled recording corrected with the calibration that belongs to it, the
    bundled unit's (:func:`kfkit.calibration.calibration_for`; the student's own file is not used, so
    every grader agrees).

    Returns (recording, gyr rad/s, acc m/s², mag µT), body frame.
    """
    rec = datasets.load(RECORDING)
    gyr, acc, mag = calibration_for(rec).apply(rec)
    return rec, gyr, acc, mag


#: The gated run: the recording with BURSTS horizontal accelerations of BURST_ACCEL m/s² for BURST_SECONDS each
#: (random start and direction), judged at the plain limits with ``accel_gate`` = ACCEL_GATE. A horizontal a
#: tilts the measured specific force by atan(a/g) = 31° and lengthens it by √(g² + a²) − g = 1.7 m/s² > the gate,
#: so a gated filter rides the bursts on the gyro (kfkit: ≤ 0.3° RMSE on every angle), while a filter that ignores
#: ``accel_gate`` follows the tilted force (1.5–4° roll/pitch, 5–8° yaw RMSE over 50 seeds).
BURSTS, BURST_ACCEL, BURST_SECONDS, ACCEL_GATE = 4, 6.0, 2.0, 1.0


def accelerated(acc, truth, t, rng):
    """``acc`` plus the specific force R_bn·a_n of BURSTS horizontal accelerations a_n (NED), and their mask."""
    a_n, during = np.zeros_like(acc), np.zeros(len(t), bool)
    slots = np.linspace(t[0] + 3.0, t[-1] - 3.0 - BURST_SECONDS, BURSTS + 1)
    for t0, t1 in zip(slots[:-1], slots[1:]):
        start = rng.uniform(t0, t1 - BURST_SECONDS)
        w = (t >= start) & (t < start + BURST_SECONDS)
        heading = rng.uniform(-np.pi, np.pi)
        a_n[w] = BURST_ACCEL * np.array([np.cos(heading), np.sin(heading), 0.0])
        during |= w
    R_bn = np.swapaxes(euler_to_dcm(truth), -1, -2)
    return acc + np.einsum("nij,nj->ni", R_bn, a_n), during


def noise_free_turns(rng, rate_hz=104.0, field_n=MAG_FIELD_LONDON):
    """TURNS one-second turns by hand about one Euler axis at a time (roll ±60–120°, yaw ±90–180°, pitch to ±60°), from
    a random attitude, seen by noise-free sensors: (gyr at each sample's instant, acc, mag on every other row, truth),
    rad/s, m/s², µT, rad. Up to 6 rad/s: a step fed the rate at its end runs ½ωΔt (1.6°) ahead of the truth."""
    t = np.arange(int((2 * TURNS + 2) * rate_hz)) / rate_hz
    start = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-np.pi, np.pi)])
    moves, pitch = [], start[1]
    for i in range(TURNS):
        axis = int(rng.integers(0, 3))
        if axis == 1:
            target = rng.uniform(np.radians(30.0), np.radians(60.0)) * -np.sign(pitch or 1.0)
            delta, pitch = target - pitch, target
        else:
            delta = rng.choice([-1.0, 1.0]) * np.radians(
                rng.uniform(60.0, 120.0) if axis == 0 else rng.uniform(90.0, 180.0)
            )
        moves.append((1.0 + 2 * i, 2.0 + 2 * i, axis, delta))
    euler, euler_dot = motions.euler_moves(t, start, moves)
    R_bn = np.swapaxes(euler_to_dcm(euler), 1, 2)
    mag = R_bn @ np.asarray(field_n, dtype=float)
    mag[1::2] = np.nan
    return (
        euler_rates_to_body_rates(euler, euler_dot),
        R_bn @ np.array([0.0, 0.0, -G]),
        mag,
        dcm_to_euler(euler_to_dcm(euler)),
    )
