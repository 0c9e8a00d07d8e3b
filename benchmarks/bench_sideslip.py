"""Sideslip filter: speed of estimate_sideslip vs filterpy on the same model, what the one-BLAS-thread limit
buys, β RMSE per model and drive (the README's results table), and on the real race-track log (the bundled half, and
the shared file when present): what the log shows without β (the straights' noise, the friction µ its lateral
acceleration reaches), every estimator with that µ, and the saturating-tyre EKF's β RMSE against µ.

    python benchmarks/bench_sideslip.py

filterpy gets the same discretised matrices (cached per 0.05 m/s speed bin like kfkit, the D-term moved to
the measurement side) so the comparison is the filter loop, not the discretisation. Both run with one BLAS
thread (threadpoolctl). Speed-table times are the best of 5 CPU times. The BLAS table runs
estimate_sideslip with its thread limit and with the limit replaced by a no-op: wall times (what a user
waits) and CPU times of all the process's threads (what a busy-waiting BLAS pool takes from the machine).
Run it on a quiet machine and again with the cores busy (e.g. two `python -c "while True: pass"`): the
limit matters most when cores are contended, as on a 2-core CI runner or parallel grading.
Budget (docs/design.md): a 60 s, 100 Hz drive within 200 ms, so tuning feels live.

The race track's µ is :func:`kfkit.vehicle.peak_friction` of its a_y (the largest half-second mean, in g; no β used):
the µ the kit ships for that log (lab 06, section 12). The µ table shows what another choice would cost.
"""

import contextlib
import time
from pathlib import Path
from unittest import mock

import numpy as np
from filterpy.kalman import KalmanFilter as FilterpyKF
from threadpoolctl import threadpool_limits
from timing import best_of

from kfkit import datasets, discrete, vehicle
from kfkit.filters import compare_estimators, estimate_sideslip, sideslip
from kfkit.labs import lab06
from kfkit.metrics import rmse
from kfkit.readers import load_vehicle_csv

SIGNALS = ("t", "delta", "yaw_rate", "ay", "vx")
DRIVES = {
    "slalom 20 km/h": "06_slalom_20kmh",
    "slalom 80 km/h": "06_slalom_80kmh",
    "lane change 60 km/h": "06_lane_change",
}
CAR = vehicle.BicycleParams()


def filterpy_sideslip(t, delta, yaw_rate, ay, vx, params=CAR, q=(1e-4, 1e-3), r=(0.003, 0.05), vx_step=0.05):
    """The same filter with filterpy's KalmanFilter (no low-speed guard: drives with V_x ≥ 2 m/s only)."""
    dt = float(np.median(np.diff(t)))
    kf = FilterpyKF(dim_x=2, dim_z=2, dim_u=1)
    kf.R, kf.x, kf.P = np.diag(np.square(r)), np.zeros(2), np.diag([np.radians(2.0) ** 2] * 2)
    cache, beta = {}, np.empty(len(t))
    for k in range(len(t)):
        key = round(vx[k] / vx_step)
        if key not in cache:
            A, B, C, D = vehicle.linear_model(params, key * vx_step)
            cache[key] = discrete.discretize(A, B, dt, np.diag(q)) + (C, D)
        kf.F, kf.B, kf.Q, kf.H, D = cache[key]
        kf.predict(u=np.array([delta[k - 1] if k else delta[0]]))
        kf.update(np.array([yaw_rate[k], ay[k]]) - D[:, 0] * delta[k])
        beta[k] = kf.x[0]
    return beta


def speed_table():
    rows = []
    for label in ("slalom 80 km/h", "lane change 60 km/h"):
        rec = datasets.load(DRIVES[label])
        sig = [rec[c] for c in SIGNALS]
        ours = estimate_sideslip(*sig, CAR, model=vehicle.linear_model).beta
        theirs = filterpy_sideslip(*sig)
        agree = np.max(np.abs(ours - theirs))
        t_ours = best_of(
            lambda sig=sig: estimate_sideslip(*sig, CAR, model=vehicle.linear_model), clock=time.process_time
        )
        t_bias = best_of(
            lambda sig=sig: estimate_sideslip(*sig, CAR, model=vehicle.linear_model, bias_ay=True),
            clock=time.process_time,
        )
        with threadpool_limits(1, user_api="blas"):
            t_fp = best_of(lambda sig=sig: filterpy_sideslip(*sig), clock=time.process_time)
        n = len(rec)
        rows.append((label, n, n / t_ours, n / t_bias, n / t_fp, t_fp / t_ours, agree))
    print(
        f"{'drive':22s} {'samples':>8s} {'kfkit steps/s':>14s} {'+bias state':>12s} {'filterpy steps/s':>17s} "
        f"{'ratio':>6s} {'max |Δβ| (rad)':>15s} {'60 s @ 100 Hz':>14s}"
    )
    for label, n, ours, bias, fp, ratio, agree in rows:
        print(
            f"{label:22s} {n:8d} {ours:14.0f} {bias:12.0f} {fp:17.0f} {ratio:6.2f} {agree:15.1e}"
            f" {6000 / ours * 1e3:11.0f} ms"
        )


class _NoLimit:
    """Stands in for threadpoolctl's controller: limit() does nothing."""

    def limit(self, **_):
        return contextlib.nullcontext()


def blas_table(repeats=7):
    rec = datasets.load(DRIVES["slalom 20 km/h"])  # 94 speed bins: the most matrix exponentials of the three
    sig = [rec[c] for c in SIGNALS]
    print(f"\n{'BLAS threads (slalom 20 km/h)':38s} {'wall best':>10s} {'wall median':>12s} {'CPU median':>11s}")
    for bias in (False, True):
        for label, patch in (
            ("1 thread (threadpoolctl)", contextlib.nullcontext()),
            ("library default", mock.patch.object(sideslip, "_blas_controller", _NoLimit)),
        ):
            walls, cpus = [], []
            with patch:
                for _ in range(repeats):
                    w, c = time.perf_counter(), time.process_time()
                    estimate_sideslip(*sig, CAR, model=vehicle.linear_model, bias_ay=bias)
                    walls.append(time.perf_counter() - w)
                    cpus.append(time.process_time() - c)
            name = ("+bias state, " if bias else "") + label
            print(
                f"{name:38s} {1e3 * min(walls):8.1f} ms {1e3 * np.median(walls):10.1f} ms"
                f" {1e3 * np.median(cpus):9.1f} ms"
            )


def rmse_table():
    table = {}
    for label, name in DRIVES.items():
        rec = datasets.load(name)
        for est, beta in compare_estimators(rec, CAR).items():
            table.setdefault(est, {})[label] = np.degrees(rmse(beta, rec["true_beta"]))
        for factor in (0.8, 1.2):
            beta = estimate_sideslip(*(rec[c] for c in SIGNALS), CAR.scaled(factor), model=vehicle.linear_model).beta
            table.setdefault(f"KF, C ×{factor:g}", {})[label] = np.degrees(rmse(beta, rec["true_beta"]))
    print(f"\n{'β RMSE (°)':24s}" + "".join(f"{s:>21s}" for s in DRIVES))
    for est, row in table.items():
        print(f"{est:24s}" + "".join(f"{row[s]:21.3f}" for s in DRIVES))


SHARED_TRACK = Path(__file__).resolve().parents[2] / "shared/data/racetrack/racetrack_first_half.csv"
TRACK_COLUMNS = {
    "t": "t_s",
    "delta": "steer_road_wheel_rad",
    "yaw_rate": "yaw_rate_rad_s",
    "ay": "ay_cg_m_s2",
    "vx": "vx_m_s",
    "true_beta": "beta_true_rad",
}


def race_track_logs():
    """The race-track logs present: the bundled half, and the shared original's first half when it is there."""
    logs = {"bundled 06_racetrack": datasets.load("06_racetrack")}
    if SHARED_TRACK.exists():
        logs["shared first half"] = load_vehicle_csv(SHARED_TRACK, TRACK_COLUMNS)
    return logs


def shipped_car(rec):
    """The published parameters with the friction the log's lateral acceleration shows (no β used)."""
    return vehicle.BicycleParams(
        **datasets.load("06_racetrack").meta["vehicle"], mu=vehicle.peak_friction(rec.t, rec["ay"])
    )


def log_table(logs):
    """What each log shows without β: the straights' sensor noise, and the peak of a_y averaged over a window."""
    print(f"\n{'race track, without β':40s}" + "".join(f"{name:>22s}" for name in logs))
    rows = {
        "straights (|a_y| < 1, |r| < 0.02), share": [f"{lab06.straights(r).mean():.1%}" for r in logs.values()],
        "  a_y σ (m/s²)": [f"{np.std(r['ay'][lab06.straights(r)]):.3f}" for r in logs.values()],
        "  yaw rate σ (rad/s)": [f"{np.std(r['yaw_rate'][lab06.straights(r)]):.4f}" for r in logs.values()],
    }
    for window in (0.01, 0.1, 0.25, 0.5, 1.0, 2.0):
        label = f"peak |a_y| over {window:g} s (g)" + ("  ← µ shipped" if window == 0.5 else "")
        rows[label] = [f"{vehicle.peak_friction(r.t, r['ay'], window):.3f}" for r in logs.values()]
    for label, row in rows.items():
        print(f"{label:40s}" + "".join(f"{v:>22s}" for v in row))


def real_table(logs):
    """β RMSE (°, first 5 samples skipped) of every estimator on the real race-track log, the published parameters
    with the µ the log shows; the EKF's CPU time per log."""
    rows, cpu = {}, []
    for rec in logs.values():
        car, sig = shipped_car(rec), [rec[k] for k in SIGNALS]
        c = time.process_time()
        estimate_sideslip(*sig, car)
        cpu.append(time.process_time() - c)
        betas = compare_estimators(rec, car)
        betas["open loop (linear, no a_y)"] = estimate_sideslip(
            *sig, car, model=vehicle.linear_model, accel_noise=1e6
        ).beta
        for factor in (0.8, 1.2):
            betas[f"KF, C ×{factor:g}"] = estimate_sideslip(*sig, car.scaled(factor), model=vehicle.linear_model).beta
        for est, beta in betas.items():
            rows.setdefault(est, []).append(np.degrees(rmse(beta[5:], rec["true_beta"][5:])))
    print(f"\n{'β RMSE (°), race track, µ from the log':40s}" + "".join(f"{name:>22s}" for name in logs))
    for est, row in rows.items():
        print(f"{est:40s}" + "".join(f"{v:22.3f}" for v in row))
    print(
        f"{'true β (RMS)':40s}"
        + "".join(f"{np.degrees(rmse(0 * r['true_beta'][5:], r['true_beta'][5:])):22.3f}" for r in logs.values())
    )
    print(
        f"{'EKF CPU time (s)':40s}"
        + "".join(f"{c:22.1f}" for c in cpu)
        + "   ("
        + ", ".join(f"{len(r):,}" for r in logs.values())
        + " samples)"
    )


def mu_table(logs):
    """The saturating-tyre EKF's β RMSE (°) against the µ of its tyre curves (the shipped µ marked)."""
    print(f"\n{'EKF β RMSE (°) against µ':40s}" + "".join(f"{name:>22s}" for name in logs))
    shipped = {name: vehicle.peak_friction(r.t, r["ay"]) for name, r in logs.items()}
    mus = sorted(
        {0.8, 0.9, 1.0, 1.05, 1.1, 1.2, 1.3, 1.5, 1.7, 2.0, 2.5, 10.0} | {round(m, 3) for m in shipped.values()}
    )
    for mu in mus:
        row = [
            np.degrees(
                rmse(
                    estimate_sideslip(
                        *(r[k] for k in SIGNALS), vehicle.BicycleParams(**{**shipped_car(r).__dict__, "mu": mu})
                    ).beta[5:],
                    r["true_beta"][5:],
                )
            )
            for r in logs.values()
        ]
        mark = "  ← shipped" if any(abs(mu - m) < 5e-4 for m in shipped.values()) else ""
        print(f"{f'µ = {mu:g}{mark}':40s}" + "".join(f"{v:22.3f}" for v in row))


if __name__ == "__main__":
    speed_table()
    blas_table()
    rmse_table()
    track_logs = race_track_logs()
    log_table(track_logs)
    real_table(track_logs)
    mu_table(track_logs)
