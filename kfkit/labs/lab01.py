"""Lab 01 (the scalar roll filter): its recordings, where its q comes from, and the figure and table only it draws.

The notebook's exercises (``accel_roll``, ``fuse_gaussians``, ``kf_predict``, ``kf_update``, ``run_kf``) stay in the
notebook; :func:`recipe` takes the student's ``accel_roll`` and ``run_kf`` as arguments, so section 10 runs the
student's own filter on the simulation and on the real IMU.
"""

from __future__ import annotations

from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np

from .. import allan, calibration, datasets, filters, metrics
from ..frames import G, accel_tilt
from ..paths import bundled_calibration_path
from ..plots import COLORS, STYLES

STILL_SECONDS = 5.0  # the bundled recording starts with the board at rest
SHAKES = ((22.0, 25.0), (42.0, 45.0))  # s: the bundled recording's sideways shakes

REAL_RECORDING = "01_broad_slow_rotation"
#: BROAD trial 02 turns mostly about x until its pitch first passes this (at 102 s), then about all axes
REAL_MAX_PITCH = np.radians(15.0)
REAL_REST = "02_broad_rest"  # the same IMU's first rest at its native rate: lab 02, section 8 measures its noise
REAL_BOARD = "broad-myon-aktos-t"
#: the q the sweeps of section 10 try (rad²): eight decades, four points per decade
SWEEP_Q = np.logspace(-12, -4, 33)


def bundled_inputs():
    """Lab 01's inputs from the bundled recording: t, raw gyro x rate, accel roll, true roll, rest mask."""
    rec = datasets.load("01_roll_sine")
    roll_acc, _ = accel_tilt(rec.body("acc"))
    return rec.t, rec.body("gyr")[:, 0], roll_acc, rec["true_roll"], rec.t < STILL_SECONDS


def real_excerpt():
    """The real recording of lab 01's section 10: BROAD trial 02 from its start (the first rest: bias, x0 and r)
    to the end of its rotations mostly about x, where |pitch| first exceeds :data:`REAL_MAX_PITCH` in the movement.

    ``true_roll`` is made continuous (np.unwrap over the samples the markers saw, NaN kept): the rotations pass
    ±180°, and the lab's 1-D filter does not wrap its innovation, so it is fed np.unwrap of the accelerometer roll.
    """
    rec = datasets.load(REAL_RECORDING)
    tilted = rec.phase("movement") & (np.abs(rec["true_pitch"]) > REAL_MAX_PITCH)
    excerpt = rec.head(rec.t[np.argmax(tilted)] - rec.t[0])
    roll = excerpt["true_roll"].copy()
    seen = ~np.isnan(roll)
    roll[seen] = np.unwrap(roll[seen])
    excerpt.data["true_roll"] = roll
    return excerpt


def roll_gyro_density(rec) -> tuple[float, str]:
    """(N, where it comes from): the white-noise density of the roll-rate gyro (body x), rad/√s = rad/s/√Hz, as lab 02
    measures it. A board or a phone: the calibration :func:`kfkit.calibration.calibration_for` picks (the one lab 02
    saved for your board, else the kit's bundled one, lab 02's analysis of the board's bundled rest), σ/√f_s of its
    white noise. The real IMU (BROAD's Myon, which has no calibration file): its Allan deviation at τ = 1 s over the
    rest lab 02's section 8 reads (:data:`REAL_REST`, at the IMU's native rate: a density does not depend on the
    rate)."""
    if rec.meta.get("board") == REAL_BOARD:
        rest = datasets.load(REAL_REST)
        taus, adev = allan.allan_deviation(rest.body("gyr")[:, 0], rest.rate_hz)
        return float(allan.angle_random_walk(taus, adev)), f"lab 02, section 8: the Allan curve of {REAL_REST}"
    cal = calibration.calibration_for(rec)
    bundled = cal == calibration.Calibration.load(bundled_calibration_path(cal.board))
    return float(cal.gyro_density[0]), (
        f"the kit's bundled calibration of the {cal.board}"
        if bundled
        else f"your lab 02 calibration of the {cal.board}"
    )


def gaussian(x, mean, var):
    """The normal density N(mean, var) at x (same unit as mean; var in that unit²)."""
    return np.exp(-0.5 * (x - mean) ** 2 / var) / np.sqrt(2.0 * np.pi * var)


def fusion_figure(prior, measurement, posterior, title="Prior × measurement = posterior"):
    """The three densities of section 4's fusion, each (mean (rad), variance (rad²)), drawn in degrees."""
    (m0, v0), (mz, vz) = prior, measurement
    spread = 4.0 * np.sqrt(max(v0, vz))
    x = np.linspace(min(m0, mz) - spread, max(m0, mz) + spread, 600)
    deg = np.degrees(1.0)
    fig, ax = plt.subplots(figsize=(8.0, 3.4))
    for (mean, var), label, kind in (
        (prior, "prior: the gyro's prediction", "gyro"),
        (measurement, "measurement: the accelerometer roll", "accel"),
        (posterior, "posterior: their normalised product", "kf"),
    ):
        ax.plot(
            x * deg,
            gaussian(x, mean, var) / deg,
            color=COLORS[kind],
            ls=STYLES[kind],
            lw=1.8,
            label=f"{label}, {mean * deg:.1f}° ± {np.sqrt(var) * deg:.1f}°",
        )
        ax.axvline(mean * deg, color=COLORS[kind], ls=":", lw=0.9)
    ax.set_xlabel("roll (°)")
    ax.set_ylabel("probability density (1/°)")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_ylim(0, ax.get_ylim()[1] * 1.25)
    return fig


@dataclass
class RecipeRun:
    """This lab's recipe on one recording: the estimates ({name: (roll (rad), colour kind)}), the gyro bias removed
    (rad/s), the gyro's density N (rad/√s), q = N²Δt, the best q of a sweep against the truth and r (rad²)."""

    estimates: dict
    bias: float
    N: float
    q_N: float
    q_best: float
    r: float


def recipe(rec, rest, accel_roll, run_kf, qs=SWEEP_Q) -> RecipeRun:
    """The lab's recipe on a recording with truth, with the student's ``accel_roll`` and ``run_kf``: the gyro bias
    (its mean over ``rest``) removed, x0 and r from the accelerometer roll at rest (unwrapped), q = N²Δt from
    :func:`roll_gyro_density`, and the best q of ``qs`` by the roll RMSE against the truth (kfkit's filter sweeps,
    the student's runs the two filters shown)."""
    dt, truth = 1.0 / rec.rate_hz, rec["true_roll"]
    bias = float(np.mean(rec.body("gyr")[rest, 0]))
    gyro = rec.body("gyr")[:, 0] - bias
    z = np.unwrap(accel_roll(rec.body("acc")[:, 1], rec.body("acc")[:, 2]))
    x0, r = float(np.mean(z[rest])), float(np.var(z[rest]))
    N = roll_gyro_density(rec)[0]
    q_N = N**2 * dt
    rmses = [metrics.angle_rmse_deg(filters.roll_kf(gyro, z, dt, q, r, x0, P0=r).x, truth) for q in qs]
    best = float(qs[np.argmin(rmses)])
    return RecipeRun(
        {
            "accel only": (z, "accel"),
            "gyro only, bias removed": (filters.integrate_rate(gyro, dt, x0), "gyro"),
            "KF, q = N²Δt": (run_kf(gyro, z, dt, q_N, r, x0, P0=r)[0], "other"),
            "KF, best q": (run_kf(gyro, z, dt, best, r, x0, P0=r)[0], "kf"),
        },
        bias,
        N,
        q_N,
        best,
        r,
    )


def across_gravity(rec):
    """The board's acceleration across gravity in the roll plane (m/s², (N,)), from the truth's roll φ and pitch θ:
    a_b = f_b + R_bn g_n (the specific force less the gravity it would read at rest), along e_φ = [0, cos φ, −sin φ],
    the direction in which it turns the accelerometer's "up" and so its roll (by about −a/g rad)."""
    f, phi, theta = rec.body("acc"), rec["true_roll"], rec["true_pitch"]
    gravity = G * np.column_stack([-np.sin(theta), np.sin(phi) * np.cos(theta), np.cos(phi) * np.cos(theta)])
    a = f + gravity
    return a[:, 1] * np.cos(phi) - a[:, 2] * np.sin(phi)


def _rms(x):
    return float(np.sqrt(np.nanmean(np.square(x))))


#: section 10's table: (label, format, value(rec, rest, moving, run))
TABLE_ROWS = (
    ("gyro x bias at rest (°/s)", "14.3f", lambda rec, rest, mov, run: np.degrees(run.bias)),
    ("gyro x density N, lab 02 (mdps/√Hz)", "14.2f", lambda rec, rest, mov, run: np.degrees(run.N) * 1e3),
    ("accel roll σ at rest, √r (°)", "14.2f", lambda rec, rest, mov, run: np.degrees(np.sqrt(run.r))),
    (
        "‖f‖ − g while moving, RMS (m/s²)",
        "14.2f",
        lambda rec, rest, mov, run: _rms(np.linalg.norm(rec.body("acc")[mov], axis=1) - G),
    ),
    ("across gravity while moving, RMS (m/s²)", "14.2f", lambda rec, rest, mov, run: _rms(across_gravity(rec)[mov])),
)


def side_by_side(cases: dict) -> None:
    """Print section 10's table for two columns: ``cases`` maps a column name to (recording, rest mask, moving mask,
    RecipeRun). The last row gives each column's filter (its q and Δt) the other column's r."""

    def row(label, values, fmt):
        print(f"{label:42s}" + "".join(f"{v:{fmt}}" for v in values))

    def each(value):
        return [value(*case) for case in cases.values()]

    runs = [case[3] for case in cases.values()]
    row("", cases, ">14s")
    for label, fmt, value in TABLE_ROWS:
        row(label, each(value), fmt)
    print("RMSE while moving (°)")
    for est in runs[0].estimates:
        row(
            f"  {est}",
            each(
                lambda rec, rest, mov, run, est=est: metrics.angle_rmse_deg(
                    run.estimates[est][0][mov], rec["true_roll"][mov]
                )
            ),
            "14.2f",
        )
    row("q = N²Δt (rad²)", [run.q_N for run in runs], "14.1e")
    row("best q (rad²)", [run.q_best for run in runs], "14.1e")
    row("  best q / (N²Δt)", [run.q_best / run.q_N for run in runs], "14.0f")
    row("its time constant Δt/K∞ (s)", each(lambda rec, rest, mov, run: time_constant(run.q_best, run.r, rec)), "14.2f")
    row(
        "  with the other column's r (s)",
        [time_constant(run.q_best, other.r, case[0]) for case, run, other in zip(cases.values(), runs, runs[::-1])],
        "14.2f",
    )


def time_constant(q, r, rec) -> float:
    """τ = Δt/K∞ (s) of the scalar filter at the recording's rate (section 8)."""
    return 1.0 / rec.rate_hz / filters.roll_kf_steady_state(q, r)[1]
