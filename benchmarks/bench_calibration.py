"""Calibration speed and accuracy: Allan deviation vs allantools, ellipsoid fit vs truth, the labs' estimates
on the bundled recordings vs the simulation's true values, and how long a magnetometer rotation must be.

    python benchmarks/bench_calibration.py
"""

import time
from functools import partial

import numpy as np
from timing import best_of

from kfkit import allan, calibration_motions, datasets, mag_calibration, rest_calibration, sim
from kfkit.capture import sphere_coverage
from kfkit.checkpoints.lab03 import heading_errors, random_ellipsoid
from kfkit.frames import G, mount_matrix
from kfkit.labs.lab02 import gyro_bias_truth, noise_truth, six_face_truth
from kfkit.unit_errors import NUCLEO_UNIT

DEG = np.pi / 180
K_FIT_SPREAD = (
    0.2  # relative standard deviation of K fitted on a 40-minute rest (200 simulated rests: tests/test_lab02_q.py)
)


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
        taus, _ = allan.allan_deviation(x, rate)
        _, ours = allan.allan_deviation(x, rate, taus)
        t_k = best_of(partial(allan.allan_deviation, x, rate, taus), repeats=3)
        if allantools is None:
            print(f"| {label} | {len(taus)} | {t_k * 1e3:.1f} ms | not installed | | |")
            continue
        _, theirs, _, _ = allantools.oadev(x, rate=rate, data_type="freq", taus=taus)
        t_a = best_of(partial(allantools.oadev, x, rate=rate, data_type="freq", taus=taus), repeats=3)
        diff = np.max(np.abs(ours / theirs - 1))
        print(f"| {label} | {len(taus)} | {t_k * 1e3:.1f} ms | {t_a * 1e3:.1f} ms | {t_a / t_k:.1f}× | {diff:.1e} |")


def ellipsoid_table():
    print(
        "\n| readings | noise (µT) | fit time | hard-iron error (µT, RMS) | soft-iron error (max) "
        "| calibrated-norm σ (µT) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for n, noise in ((300, 0.3), (3000, 0.3), (3000, 1.0)):
        rng = np.random.default_rng(1)
        errs_h, errs_s, spreads, times = [], [], [], []
        for _ in range(20):
            mag, h, W = random_ellipsoid(rng, n=n, noise=noise)
            t0 = time.perf_counter()
            h_fit, S = mag_calibration.fit_mag_calibration(mag)
            t = time.perf_counter() - t0
            times.append(t)
            errs_h.append(np.linalg.norm(h_fit - h) / np.sqrt(3))
            errs_s.append(np.abs(S - np.linalg.inv(W)).max())
            spreads.append(np.linalg.norm((mag - h_fit) @ S.T, axis=1).std())
        print(
            f"| {n} | {noise:g} | {np.median(times) * 1e3:.2f} ms | {np.sqrt(np.mean(np.square(errs_h))):.3f} | "
            f"{np.max(errs_s):.4f} | {np.mean(spreads):.2f} |"
        )


def worst(values):
    return float(np.max(np.abs(values)))


def bundled_table():
    """Lab 02/03 estimates (kfkit's reference functions) on the bundled recordings against the simulation."""
    still, faces_rec, rot = (
        datasets.load("02_stationary"),
        datasets.load("02_six_faces"),
        datasets.load("03_mag_rotations"),
    )
    print("\n| quantity (bundled recording) | estimate − truth (worst axis) | in standard uncertainties (worst) |")
    print("| --- | --- | --- |")
    gyr = still.body("gyr")
    truth, u = gyro_bias_truth(still)
    err = rest_calibration.gyro_bias(gyr) - truth
    print(f"| gyro bias (02_stationary, 40 min) | {worst(err) / DEG:.4f} °/s | {worst(err / u):.1f} |")
    for sensor, unit, k in (("gyr", "°/s", 1 / DEG), ("acc", "mm/s²", 1e3)):
        sigma, u, n = noise_truth(still, sensor)
        err = rest_calibration.noise_std(still.body(sensor)[:n]) - sigma
        print(
            f"| {sensor} noise σ per sample at 12.5 Hz (first 2 min) | {worst(err) * k:.4f} {unit} "
            f"({worst(err / sigma) * 100:.1f} %) | {worst(err / u):.1f} |"
        )
    K = still.meta["sim"]["gyro_bias_rw"]
    k_fit = allan.allan_noise_fit(*allan.allan_deviation(gyr, still.rate_hz))[2]
    print(
        f"| gyro rate random walk K (Allan fit, 40 min; true {K * 1e6:.1f} µrad/s/√s) "
        f"| {worst(k_fit - K) * 1e6:.2f} µrad/s/√s "
        f"({worst(k_fit / K - 1) * 100:.0f} %) | {worst(k_fit / K - 1) / K_FIT_SPREAD:.1f} |"
    )
    b, s_, u_b, u_s = six_face_truth(faces_rec)
    b_hat, s_hat = rest_calibration.accel_six_face(
        {f: faces_rec.body("acc")[faces_rec.phase(f)] for f in rest_calibration.FACES}
    )
    print(f"| accel bias, six faces | {worst(b_hat - b) / G * 1e3:.3f} mg | {worst((b_hat - b) / u_b):.1f} |")
    print(f"| accel scale, six faces | {worst(s_hat - s_) * 100:.4f} % | {worst((s_hat - s_) / u_s):.1f} |")
    level = rest_calibration.accel_bias(still.body("acc"), [0.0, 0.0, -G])
    true_b = mount_matrix(still.meta["mount"]["acc"]) @ still.meta["sim"]["accel_bias"]
    print(f"| accel z bias, level rest only (scale error not separable) | {(level - true_b)[2] / G * 1e3:.2f} mg | — |")
    mag = rot.body("mag")
    h, S = mag_calibration.fit_mag_calibration(mag)
    M = mount_matrix(rot.meta["mount"]["mag"])
    h_true = M @ rot.meta["sim"]["mag_hard_iron"]
    S_true = np.linalg.inv(M @ np.asarray(rot.meta["sim"]["mag_soft_iron"]) @ M.T)
    print(f"| mag hard iron (03_mag_rotations) | {worst(h - h_true):.3f} µT | — |")
    print(f"| mag soft iron, max abs(S − W⁻¹) | {worst(S - S_true):.4f} | — |")
    before, after = heading_errors(np.zeros(3), np.eye(3)), heading_errors(h, S)
    print(
        f"| heading RMS on 03_headings (tilt-compensated, declination) | {np.degrees(after):.2f}° calibrated, "
        f"{np.degrees(before):.1f}° uncalibrated | — |"
    )


def rotation_length_table():
    """How long the magnetometer tumble must be: coverage, the fit's verdict and the heading it gives."""
    print("\n| tumbling (s) | sphere coverage | fit | hard-iron error (µT) | heading RMS on 03_headings |")
    print("| --- | --- | --- | --- | --- |")
    unit = {k: np.asarray(v) for k, v in NUCLEO_UNIT.items()}
    for seconds in (8.0, 15.0, 30.0, 60.0):
        rec = sim.simulate_imu(
            calibration_motions.mag_rotations(duration=seconds, rate_hz=104.0, seed=302), seed=303, **unit
        )
        mag = rec.body("mag")
        h_true = mount_matrix(rec.meta["mount"]["mag"]) @ unit["mag_hard_iron"]
        coverage = sphere_coverage(mag)
        try:
            h, S = mag_calibration.fit_mag_calibration(mag)
        except rest_calibration.CalibrationError:
            print(f"| {seconds:g} | {coverage:.0%} | refused: too little of the sphere | — | — |")
            continue
        print(
            f"| {seconds:g} | {coverage:.0%} | ok | {worst(h - h_true):.2f} | {np.degrees(heading_errors(h, S)):.2f}° |"
        )


if __name__ == "__main__":
    allan_table()
    ellipsoid_table()
    bundled_table()
    rotation_length_table()
