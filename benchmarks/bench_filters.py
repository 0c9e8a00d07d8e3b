"""Filter speed: kfkit vs filterpy on the same problems, as steps/s and ratios from one run.

    python benchmarks/bench_filters.py

Budget (DESIGN): re-running a lab's filter over 60 s at 100 Hz within 200 ms, so sliders feel live.
"""

import numpy as np
from filterpy.kalman import KalmanFilter as FilterpyKF
from timing import best_of

from kfkit import datasets
from kfkit.filters import KalmanFilter, roll_kf
from kfkit.frames import accel_tilt


def two_state_problem(n=6000, dt=0.01, seed=0):
    """[angle, gyro bias] with gyro input and angle measurement (lab 05's model)."""
    rng = np.random.default_rng(seed)
    F = np.array([[1.0, -dt], [0.0, 1.0]])
    B = np.array([[dt], [0.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.diag([1e-6, 1e-9])
    R = np.array([[1e-3]])
    return F, B, H, Q, R, rng.normal(0, 0.5, (n, 1)), rng.normal(0, 0.03, (n, 1))


def kfkit_general(F, B, H, Q, R, us, zs):
    return KalmanFilter(F, H, Q, R, np.zeros(2), np.eye(2), B=B).run(zs, us)


def filterpy_general(F, B, H, Q, R, us, zs):
    kf = FilterpyKF(dim_x=2, dim_z=1, dim_u=1)
    kf.F, kf.B, kf.H, kf.Q, kf.R, kf.x, kf.P = F, B, H, Q, R, np.zeros(2), np.eye(2)
    xs = np.empty((len(zs), 2))
    for k in range(len(zs)):
        kf.predict(u=us[k])
        kf.update(zs[k])
        xs[k] = kf.x
    return xs


def filterpy_scalar(gyro, z, dt, q, r):
    kf = FilterpyKF(dim_x=1, dim_z=1, dim_u=1)
    kf.F, kf.B, kf.H, kf.Q, kf.R = np.eye(1), np.array([[dt]]), np.eye(1), np.array([[q]]), np.array([[r]])
    kf.x, kf.P = np.array([z[0]]), np.eye(1)
    out = np.empty(len(z))
    for k in range(len(z)):
        kf.predict(u=np.array([gyro[k]]))
        kf.update(np.array([z[k]]))
        out[k] = kf.x[0]
    return out


def main():
    rows = []
    problem = two_state_problem()
    n = len(problem[-1])
    ours = best_of(lambda: kfkit_general(*problem))
    theirs = best_of(lambda: filterpy_general(*problem))
    rows.append(("2-state KF (angle, bias), KalmanFilter", n, ours, theirs))

    rec = datasets.load("01_roll_sine")
    gyro, (z, _) = rec.body("gyr")[:, 0], accel_tilt(rec.body("acc"))
    dt = 1.0 / rec.rate_hz
    ours = best_of(lambda: roll_kf(gyro, z, dt, 1e-7, 1e-3))
    theirs = best_of(lambda: filterpy_scalar(gyro, z, dt, 1e-7, 1e-3))
    rows.append(("lab 01 roll KF, 60 s at 104 Hz", len(z), ours, theirs))

    print(
        f"{'problem':42s} {'steps':>6s} {'kfkit ms':>9s} {'kfkit steps/s':>14s} {'filterpy ms':>12s} "
        f"{'filterpy steps/s':>17s} {'speed-up':>9s}"
    )
    for name, steps, a, b in rows:
        print(
            f"{name:42s} {steps:6d} {1e3 * a:9.1f} {steps / a:14,.0f} {1e3 * b:12.1f} {steps / b:17,.0f} {b / a:8.1f}×"
        )


if __name__ == "__main__":
    main()
