"""Checkpoints of lab 04 beyond its core path: tuning without truth, real sensors, and the questions' coasting yaw.

``04.nis_per_row`` (section 9) judges the NIS of some rows of a run's innovations against kfkit's
(:func:`kfkit.metrics.nis`), naming the classic mistakes (not divided by the rows, only S's diagonal, rows of the
whole S⁻¹, every sample instead of the chosen). ``04.real_ekf`` (section 14) runs the student's filter on a real
recording (BROAD trial 06, bundled): its bar is kfkit's result on the same samples plus the error of the optical
truth itself, measured at rest; the real excerpt and its truth come from :mod:`kfkit.labs.lab04`. ``04.coast_seconds``
(the questions) is how long a level board's yaw σ takes to grow from σ0 to σ on the gyro alone,
t = (σ² − σ0²) / (σ_ω² Δt). The core path's checkpoints are in :mod:`.ekf_attitude_core`; :mod:`.lab04` registers
both.
"""

from __future__ import annotations

import numpy as np

from ..filters.euler_ekf import EulerAttitudeEKFSettings
from ..filters.euler_ekf_fast import FastEulerAttitudeEKF
from ..frames import euler_to_quat
from ..labs.lab04 import (
    ACCEL_GATE,
    REAL_MOVING_SECONDS,
    REAL_RECORDING,
    midpoint_rates,
    movement_start,
    real_inputs,
    truth_error_at_rest,
)
from ..metrics import attitude_rmse, nis
from . import Case, Checkpoint, compare, register, structural
from .ekf_attitude_core import _estimate

# --- 04.real_ekf ------------------------------------------------------------------------------


def _real_cases(rng):
    """One case: the real recording's first rest and REAL_MOVING_SECONDS of movement, with the lab's tuning and gate.
    The bar is kfkit's Euler EKF (the same equations, settings, start and midpoint rate) on the same samples, plus the
    truth's own
    error at rest: a filter that is right reproduces the reference, so its error against this truth can exceed the
    reference's only by what the truth cannot resolve."""
    rec, gyr, acc, mag, field_n, q_true, moving = real_inputs(moving_seconds=REAL_MOVING_SECONDS)
    tuning = EulerAttitudeEKFSettings()
    args = {
        "gyr": gyr,
        "acc": acc,
        "mag": mag,
        "rate_hz": rec.rate_hz,
        "gyro_noise": tuning.gyro_noise,
        "accel_noise": tuning.accel_noise,
        "mag_noise": tuning.mag_noise,
        "field_n": field_n,
        "accel_gate": ACCEL_GATE,
    }
    reference = FastEulerAttitudeEKF(rate_hz=rec.rate_hz, settings=tuning, field_n=field_n, accel_gate=ACCEL_GATE).run(
        midpoint_rates(gyr), acc, mag
    )
    ref_rmse = attitude_rmse(euler_to_quat(reference.euler), q_true, moving)["total"]
    return [
        Case(
            args,
            (q_true, moving, ref_rmse, truth_error_at_rest(rec, acc, mag)),
            f"the real recording {REAL_RECORDING} (BROAD trial 06): its {movement_start(rec):.0f} s at rest and "
            f"the first {REAL_MOVING_SECONDS:g} s of movement",
        )
    ]


def _judge_real(case, got):
    """BROAD's total error over the movement phases within the reference's plus the truth's own error."""
    q_true, moving, ref_rmse, truth_error = case.expected
    x, problem = _estimate(got, len(q_true))
    if x is None:
        return problem
    errors = {k: np.degrees(v) for k, v in attitude_rmse(euler_to_quat(x), q_true, moving).items()}
    limit = np.degrees(ref_rmse + truth_error)
    if errors["total"] <= limit:
        return None
    return (
        f"total rotation error RMSE {errors['total']:.2f}° over the movement (heading {errors['heading']:.2f}°, "
        f"inclination {errors['inclination']:.2f}°), limit {limit:.2f}° = kfkit's {np.degrees(ref_rmse):.2f}° + "
        f"the truth's own {np.degrees(truth_error):.2f}°"
    )


# --- 04.nis_per_row ---------------------------------------------------------------------------


def _innovations(rng, n=300, m=6):
    """A filter's innovations as run_ekf keeps them: y (n, m) ~ N(0, S_k) with S_k (m × m) random, its rows strongly
    correlated (a shared attitude error), and on every other sample the last three rows NaN in y and S (no
    magnetometer update); S's size varies over the run, as a filter's does."""
    y, S = np.full((n, m), np.nan), np.full((n, m, m), np.nan)
    for k in range(n):
        L = rng.normal(0.0, 1.0, (m, m)) + np.eye(m) * rng.uniform(0.3, 1.0)
        S_k = (L @ L.T) * rng.uniform(0.1, 10.0) ** 2
        rows = m if k % 2 == 0 else 3
        S[k, :rows, :rows] = S_k[:rows, :rows]
        y[k, :rows] = rng.multivariate_normal(np.zeros(rows), S_k[:rows, :rows]) * rng.uniform(0.5, 2.0)
    return y, S


def _nis_cases(rng):
    cases = []
    for rows in ([0, 1, 2], [3, 4, 5], [0, 1, 2], [3, 4, 5], [2], [1, 2, 3, 4]):
        y, S = _innovations(rng)
        samples = rng.uniform(size=len(y)) < rng.uniform(0.3, 0.9)
        used = samples & ~np.isnan(y[:, rows]).any(axis=1)
        expected = nis(y[used][:, rows], S[used][:, rows][:, :, rows]).mean() / len(rows)
        what = {0: "accelerometer", 3: "magnetometer"}.get(rows[0], "some") if len(rows) == 3 else "some"
        cases.append(
            Case(
                {"y": y, "S": S, "rows": rows, "samples": samples},
                float(expected),
                f"the {what} rows {rows} of {len(y)} innovations, {samples.sum()} samples selected",
            )
        )
    return cases


def nis_mistakes(y, S, rows, samples):
    """What the classic mistakes give: {what they forgot: value}."""
    used = samples & ~np.isnan(y[:, rows]).any(axis=1)
    y_r, S_r = y[used][:, rows], S[used][:, rows][:, :, rows]
    per_sample = nis(y_r, S_r)
    diagonal = np.sum(y_r**2 / np.diagonal(S_r, axis1=1, axis2=2), axis=1)
    mistakes = {
        "not divided by the number of rows: the NIS of r rows averages r, so per row it is the NIS / r": (
            per_sample.mean()
        ),
        "only the diagonal of S: the rows' innovations are correlated (one attitude error moves them all), so "
        "the NIS needs the whole block S_rr⁻¹": diagonal.mean() / len(rows),
    }
    S_full = S[used]
    if not np.isnan(S_full).any():
        inverse_block = np.linalg.inv(S_full)[:, rows][:, :, rows]
        mistakes[
            "rows of the whole S⁻¹: the NIS of some rows needs the inverse of their own block, (S_rr)⁻¹, not the "
            "block of S⁻¹"
        ] = np.einsum("ni,nij,nj->n", y_r, inverse_block, y_r).mean() / len(rows)
    everywhere = ~np.isnan(y[:, rows]).any(axis=1)
    mistakes["every updated sample, not only those in `samples`"] = nis(
        y[everywhere][:, rows], S[everywhere][:, rows][:, :, rows]
    ).mean() / len(rows)
    return mistakes


def _judge_nis(case, got):
    problem = compare(case.expected, got, rtol=1e-6, atol=1e-9)
    if problem is None or structural(problem):
        return problem
    for what, value in nis_mistakes(**case.args).items():
        if np.isclose(float(np.asarray(got, dtype=float)), value, rtol=1e-6):
            return f"{problem} — {what}"
    return problem


# --- 04.coast_seconds -------------------------------------------------------------------------


def coast_time(sigma0, sigma, gyro_noise, rate_hz):
    """How long (s) a level board's yaw σ takes from ``sigma0`` to ``sigma`` on the gyro alone: Q_ψψ = (σ_ω Δt)² per
    step, so σ² = σ0² + n (σ_ω Δt)² after n steps, t = nΔt = (σ² − σ0²) / (σ_ω² Δt). Any one angle unit."""
    dt = 1.0 / rate_hz
    return (sigma**2 - sigma0**2) / (gyro_noise * dt) ** 2 * dt


def _coast_cases(rng):
    cases = [
        Case(
            {"sigma0": 0.2, "sigma": 2.0, "gyro_noise": 0.3, "rate_hz": 104.0},
            coast_time(0.2, 2.0, 0.3, 104.0),
            "this lab's filter: σ_ψ from 0.2° to 2°, σ_ω = 0.3 °/s at 104 Hz",
        )
    ]
    for _ in range(11):
        args = {
            "sigma0": rng.uniform(0.05, 1.0),
            "sigma": rng.uniform(1.5, 10.0),
            "gyro_noise": rng.uniform(0.02, 1.0),
            "rate_hz": float(rng.choice([50.0, 100.0, 104.0, 200.0, 400.0])),
        }
        cases.append(Case(args, coast_time(**args)))
    return cases


def _judge_coast(case, got):
    problem = compare(case.expected, got, rtol=1e-4, atol=0.0)
    if problem is None or structural(problem):
        return problem
    a, value = case.args, float(np.asarray(got, dtype=float))
    dt = 1.0 / a["rate_hz"]
    mistakes = {
        "that is the number of steps: multiply by Δt for seconds": case.expected / dt,
        "the start σ0 is left out: the variance grows from σ0², not from 0": coast_time(
            0.0, a["sigma"], a["gyro_noise"], a["rate_hz"]
        ),
        "σ grows like this only if σ's add: it is the variances that add, step by step": (a["sigma"] - a["sigma0"])
        / (a["gyro_noise"] * dt)
        * dt,
        "Q per step is (σ_ω Δt)², the rate's noise integrated over one step, not σ_ω² Δt": (
            a["sigma"] ** 2 - a["sigma0"] ** 2
        )
        / (a["gyro_noise"] ** 2 * dt)
        * dt,
    }
    for what, wrong in mistakes.items():
        if np.isclose(value, wrong, rtol=1e-4):
            return f"{problem} — {what}"
    return problem


register(
    Checkpoint(
        "04.nis_per_row",
        "nis_per_row",
        _nis_cases,
        _judge_nis,
        points=1,
        what="runs' innovations",
        hint="keep the samples in `samples` whose rows are not NaN; for each, yᵣᵀ (S_rr)⁻¹ yᵣ with yᵣ the chosen rows "
        "of y and S_rr the block of S on those rows and columns; average, then divide by the number of rows.",
    ),
    Checkpoint(
        "04.coast_seconds",
        "coast_seconds",
        _coast_cases,
        _judge_coast,
        points=1,
        hint="each step adds (σ_ω Δt)² to a level board's yaw variance; count the steps from σ0² to σ², then "
        "turn steps into seconds.",
    ),
    Checkpoint(
        "04.real_ekf",
        "run_ekf",
        _real_cases,
        _judge_real,
        points=1,
        what="runs on a bundled real recording",
        hint="if 04.ekf_rmse passes, the real recording differs: every row has a magnetometer sample, the "
        "truth has gaps (NaN), the rotations are fast; run_ekf must take them as they come.",
    ),
)
