"""Calibration speed and accuracy: Allan deviation vs allantools, ellipsoid fit vs truth.

    python benchmarks/bench_calibration.py
"""
import time

import numpy as np

from kfkit import calibration
from kfkit.checkpoints.lab03 import random_ellipsoid


def best_of(func, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t0)
    return min(times), out


def allan_table():
    try:
        import allantools
    except ImportError:
        allantools = None
    print("| signal | τ values | kfkit `allan_deviation` | allantools `oadev` | ratio | max rel. difference |")
    print("| --- | --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(0)
    for n, rate, label in ((30000, 12.5, "40 min at 12.5 Hz (lab 02)"), (1_000_000, 100.0, "2.8 h at 100 Hz")):
        x = rng.normal(0, 1e-3, n) + np.cumsum(rng.normal(0, 1e-6, n))
        taus, _ = calibration.allan_deviation(x, rate)
        t_k, (_, ours) = best_of(lambda: calibration.allan_deviation(x, rate, taus))
        if allantools is None:
            print(f"| {label} | {len(taus)} | {t_k * 1e3:.1f} ms | not installed | | |")
            continue
        t_a, (_, theirs, _, _) = best_of(lambda: allantools.oadev(x, rate=rate, data_type="freq", taus=taus))
        diff = np.max(np.abs(ours / theirs - 1))
        print(f"| {label} | {len(taus)} | {t_k * 1e3:.1f} ms | {t_a * 1e3:.1f} ms | {t_a / t_k:.1f}× | {diff:.1e} |")


def ellipsoid_table():
    print("\n| readings | noise (µT) | fit time | hard-iron error (µT, RMS) | soft-iron error (max) | calibrated-norm σ (µT) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for n, noise in ((300, 0.3), (3000, 0.3), (3000, 1.0)):
        rng = np.random.default_rng(1)
        errs_h, errs_s, spreads, times = [], [], [], []
        for _ in range(20):
            mag, h, W = random_ellipsoid(rng, n=n, noise=noise)
            t, (h_fit, S) = best_of(lambda: calibration.fit_mag_calibration(mag), repeat=1)
            times.append(t)
            errs_h.append(np.linalg.norm(h_fit - h) / np.sqrt(3))
            errs_s.append(np.abs(S - np.linalg.inv(W)).max())
            spreads.append(np.linalg.norm((mag - h_fit) @ S.T, axis=1).std())
        print(f"| {n} | {noise:g} | {np.median(times) * 1e3:.2f} ms | {np.sqrt(np.mean(np.square(errs_h))):.3f} | "
              f"{np.max(errs_s):.4f} | {np.mean(spreads):.2f} |")


if __name__ == "__main__":
    allan_table()
    ellipsoid_table()
