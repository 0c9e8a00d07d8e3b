"""Lab 05: accuracy of the [angle, gyro bias] filter on the bundled recording, and its speed vs filterpy.

    python benchmarks/bench_tilt.py

Accuracy: RMSE over the tilt protocol's holds (the known angles) and over the whole record (the
simulation's truth; roll only where |pitch| < 60°, as roll is undefined near ±90°), the gyro bias at
the end vs the simulated one. Speed: the same 60 s at 100 Hz through TiltBiasKF.run and through
filterpy's general KalmanFilter (budget: a lab's filter over 60 s at 100 Hz within 200 ms).
"""
import time

import numpy as np
from filterpy.kalman import KalmanFilter as FilterpyKF

from kfkit import datasets
from kfkit.checkpoints import lab05
from kfkit.filters import TiltBiasKF


def best_of(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def accuracy():
    rec = datasets.load("05_tilt_protocol")
    truth = rec.truth()
    defined = np.abs(truth[:, 1]) < np.radians(60)
    axes, dt, r, q0 = lab05.pipeline_inputs()
    bias = lab05.true_gyro_bias(rec)
    tuned = {name: lab05.tune_reference(*axes[name], dt, r, q0) for name in axes}
    print(f"Lab 05 on 05_tilt_protocol (36 s, 100 Hz); r = {r:.2e} rad², q0 = (σ_ω·Δt)² = {q0:.2e} rad²\n")
    print("| estimate | roll RMSE, holds | pitch RMSE, holds | roll RMSE, whole | pitch RMSE, whole | bias error at 36 s (roll, pitch) |")
    print("| --- | --- | --- | --- | --- | --- |")
    rows = [("accelerometer only (six-face corrected)", None, None)]
    rows += [(f"KF, q0, skip gate", "skip", {n: (q0, 1e-4 * q0) for n in axes})]
    rows += [(f"KF, tuned on the holds, gate = {g}", g, tuned) for g in ("none", "skip", "inflate")]
    for label, gate, q in rows:
        cells, errs = [], []
        est = {}
        for name in ("roll", "pitch"):
            w, z, ok, ref = axes[name]
            if gate is None:
                est[name] = z
            else:
                run = TiltBiasKF(dt, *q[name], r, gate=gate).run(w, z, ok)
                est[name] = run.angle
                errs.append(100 * (run.bias[-1] / bias[0 if name == "roll" else 1] - 1))
            cells.append(f"{np.degrees(lab05.static_rmse(est[name], ref)):.2f}°")
        for name, col in (("roll", 0), ("pitch", 1)):
            mask = defined if name == "roll" else slice(None)
            cells.append(f"{np.degrees(np.sqrt(np.mean((est[name] - truth[:, col])[mask] ** 2))):.2f}°")
        cells.append(", ".join(f"{e:+.1f} %" for e in errs) if errs else "—")
        print(f"| {label} | " + " | ".join(cells) + " |")
    print("\ntuned: " + ", ".join(f"{n}: q_θ = {q[0]:.1e} rad², q_b = {q[1]:.1e} (rad/s)²" for n, q in tuned.items()))


def speed():
    rng = np.random.default_rng(0)
    n, dt = 6000, 0.01
    w, z, ok = rng.normal(0, 0.5, n), rng.normal(0, 0.3, n), rng.random(n) > 0.2
    kf = TiltBiasKF(dt, 2e-6, 2e-10, 1.6e-5, gate="skip")
    ours = best_of(lambda: kf.run(w, z, ok))

    def filterpy_run():
        f = FilterpyKF(dim_x=2, dim_z=1, dim_u=1)
        f.F, f.B, f.H = np.array([[1.0, -dt], [0.0, 1.0]]), np.array([[dt], [0.0]]), np.array([[1.0, 0.0]])
        f.Q, f.R, f.P = np.diag([2e-6, 2e-10]), np.array([[1.6e-5]]), np.diag([1.6e-5, 0.01])
        for k in range(n):
            f.predict(u=np.array([[w[k]]]))
            if ok[k]:
                f.update(np.array([[z[k]]]))

    theirs = best_of(filterpy_run, repeats=3)
    print("\n| problem | kfkit `TiltBiasKF.run` | filterpy 2 `KalmanFilter` | ratio |")
    print("| --- | --- | --- | --- |")
    print(f"| [angle, bias], 60 s at 100 Hz, skip gate | {n / ours:,.0f} steps/s ({1000 * ours:.0f} ms) | "
          f"{n / theirs:,.0f} steps/s ({1000 * theirs:.0f} ms) | {theirs / ours:.0f}× |")


if __name__ == "__main__":
    accuracy()
    speed()
