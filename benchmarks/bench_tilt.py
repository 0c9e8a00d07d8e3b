"""Lab 05: accuracy of the [angle, gyro bias] filter on the bundled recording; Python vs C vs filterpy speed.

    python benchmarks/bench_tilt.py

Accuracy: RMSE over the tilt protocol's holds (the known angles) and over the whole record (the
simulation's truth; roll only where |pitch| < 60°, as roll is undefined near ±90°), the gyro bias at
the end vs the simulated one; the C filter (firmware/tilt_kf, float32) against the Python reference.
Speed: 60 s at 100 Hz through TiltBiasKF.run, filterpy's general KalmanFilter and tilt_kf.c built with
gcc -O2 (budget: a lab's filter over 60 s at 100 Hz within 200 ms); and, where avr-gcc and simavr are
installed (Debian: gcc-avr avr-libc simavr), the cycles of one update on an ATmega328P (Arduino Uno).
"""

import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from filterpy.kalman import KalmanFilter as FilterpyKF
from timing import best_of

from kfkit import datasets
from kfkit.filters import TiltBiasKF, TiltBiasKFSettings, tilt
from kfkit.labs import lab05
from kfkit.paths import KIT_ROOT

C_SOURCE = KIT_ROOT / "firmware" / "tilt_kf" / "tilt_kf.c"
HOST_HARNESS = r"""
#define _POSIX_C_SOURCE 199309L /* clock_gettime */
#include <stdio.h>
#include <time.h>
#include "tilt_kf.h"
/* stdin: n dt, then n lines "gyro accel_angle static_ok"; stdout: "ns_per_step", then n lines "angle bias" */
static float w[100000], z[100000]; static int ok[100000];
int main(void) {
    int n, k, repeat; double dt; TiltKf kf; struct timespec t0, t1; double best = 1e30;
    if (scanf("%d %lf", &n, &dt) != 2 || n > 100000) return 2;
    for (k = 0; k < n; k++) if (scanf("%f %f %d", &w[k], &z[k], &ok[k]) != 3) return 2;
    for (repeat = 0; repeat < 20; repeat++) {
        TiltKfInitialise(&kf, (float) dt, &tiltKfDefaultSettings);
        TiltKfReset(&kf, z[0], 0.0f);
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (k = 0; k < n; k++) TiltKfUpdate(&kf, w[k], z[k], ok[k]);
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double ns = (t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec);
        if (ns < best) best = ns;
    }
    printf("%.3f\n", best / n);
    TiltKfInitialise(&kf, (float) dt, &tiltKfDefaultSettings);
    TiltKfReset(&kf, z[0], 0.0f);
    for (k = 0; k < n; k++) { TiltKfUpdate(&kf, w[k], z[k], ok[k]); printf("%.9g %.9g\n", kf.angle, kf.bias); }
    return 0;
}
"""
AVR_HARNESS = r"""
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdio.h>
#include "tilt_kf.h"
/* Timer 1 counts CPU cycles; the result goes out of UART0, which simavr prints. */
static int put(char c, FILE *f) { (void) f; loop_until_bit_is_set(UCSR0A, UDRE0); UDR0 = c; return 0; }
static FILE uart = FDEV_SETUP_STREAM(put, NULL, _FDEV_SETUP_WRITE);
volatile float sink;
#define CYCLES(call) ({ uint16_t a = TCNT1; call; (uint16_t) (TCNT1 - a); })
int main(void) {
    TiltKf kf;
    volatile float w = 0.3f, z = 0.12f, fx = 0.1f, fy = -0.2f, fz = -0.97f;
    UCSR0B = _BV(TXEN0); stdout = &uart;
    TiltKfInitialise(&kf, 0.01f, &tiltKfDefaultSettings);
    TiltKfReset(&kf, 0.1f, 0.0f);
    TCCR1A = 0; TCCR1B = _BV(CS10);
    uint16_t update = CYCLES(TiltKfUpdate(&kf, w, z, true));
    uint16_t coast = CYCLES(TiltKfUpdate(&kf, w, z, false));
    uint16_t roll = CYCLES(sink = TiltKfAccelerometerRoll(fx, fy, fz));
    uint16_t pitch = CYCLES(sink = TiltKfAccelerometerPitch(fx, fy, fz));
    uint16_t gate = CYCLES(sink = TiltKfAccelerometerStatic(fx, fy, fz, 0.05f));
    printf("cycles update=%u coast=%u roll=%u pitch=%u static=%u\n", update, coast, roll, pitch, gate);
    cli(); sleep_cpu();
}
"""


def accuracy():
    rec = datasets.load("05_tilt_protocol")
    truth = rec.truth()
    defined = np.abs(truth[:, 1]) < np.radians(60)
    axes, dt, r, q0 = lab05.pipeline_inputs()
    bias = lab05.true_gyro_bias(rec)
    tuned = {name: lab05.tune_on_holds(*axes[name], dt, r, q0) for name in axes}
    print(f"Lab 05 on 05_tilt_protocol (36 s, 100 Hz); r = {r:.2e} rad², q0 = (σ_ω·Δt)² = {q0:.2e} rad²\n")
    print(
        "| estimate | roll RMSE, holds | pitch RMSE, holds | roll RMSE, whole | pitch RMSE, whole "
        "| bias error at 36 s (roll, pitch) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    rows = [("accelerometer only (six-face corrected)", None, None)]
    rows += [("KF, q0, skip gate", "skip", dict.fromkeys(axes, (q0, 1e-4 * q0)))]
    shipped = TiltBiasKFSettings()  # = tiltKfDefaultSettings: lab 02's N²Δt and K²Δt
    rows += [
        (
            "KF, shipped defaults (lab 02's N²Δt, K²Δt), skip gate",
            "skip",
            dict.fromkeys(axes, (shipped.q_angle, shipped.q_bias)),
        )
    ]
    rows += [(f"KF, tuned on the holds, gate = {g}", g, tuned) for g in ("none", "skip", "inflate")]
    for label, gate, q in rows:
        cells, errs = [], []
        est = {}
        for name in ("roll", "pitch"):
            w, z, ok, ref = axes[name]
            if gate is None:
                est[name] = z
            else:
                run = TiltBiasKF(dt, q_angle=q[name][0], q_bias=q[name][1], r=r, accel_gating=gate).run(w, z, ok)
                est[name] = run.angle
                errs.append(100 * (run.bias[-1] / bias[0 if name == "roll" else 1] - 1))
            cells.append(f"{np.degrees(lab05.static_rmse(est[name], ref)):.2f}°")
        for name, col in (("roll", 0), ("pitch", 1)):
            mask = defined if name == "roll" else slice(None)
            cells.append(f"{np.degrees(np.sqrt(np.mean((est[name] - truth[:, col])[mask] ** 2))):.2f}°")
        cells.append(", ".join(f"{e:+.1f} %" for e in errs) if errs else "—")
        print(f"| {label} | " + " | ".join(cells) + " |")
    print("\ntuned: " + ", ".join(f"{n}: q_θ = {q[0]:.1e} rad², q_b = {q[1]:.1e} (rad/s)²" for n, q in tuned.items()))


def c_filter(gyro, angle, ok, dt):
    """tilt_kf.c built with gcc -O2: (ns per step, (N, 2) angle and bias), or None without gcc."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    with tempfile.TemporaryDirectory() as folder:
        exe, main = Path(folder) / "bench", Path(folder) / "main.c"
        main.write_text(HOST_HARNESS)
        subprocess.run(
            [gcc, "-std=c99", "-O2", f"-I{C_SOURCE.parent}", str(main), str(C_SOURCE), "-o", str(exe), "-lm"],
            check=True,
        )
        feed = f"{len(gyro)} {dt!r}\n" + "".join(
            f"{w!r} {z!r} {int(k)}\n"
            for w, z, k in zip(
                np.asarray(gyro, float).tolist(), np.asarray(angle, float).tolist(), np.asarray(ok).tolist()
            )
        )
        lines = subprocess.run([str(exe)], input=feed, capture_output=True, text=True, check=True).stdout.splitlines()
    return float(lines[0]), np.loadtxt(lines[1:])


def avr_cycles():
    """Cycles of the C filter's calls on an ATmega328P at 16 MHz (simavr), or None without avr-gcc/simavr."""
    tools = [shutil.which(t) for t in ("avr-gcc", "simavr")]
    if None in tools:
        return None
    with tempfile.TemporaryDirectory() as folder:
        elf, main = Path(folder) / "bench.elf", Path(folder) / "main.c"
        main.write_text(AVR_HARNESS)
        subprocess.run(
            [
                tools[0],
                "-std=gnu99",
                "-Os",
                "-mmcu=atmega328p",
                "-DF_CPU=16000000L",
                f"-I{C_SOURCE.parent}",
                str(main),
                str(C_SOURCE),
                "-o",
                str(elf),
                "-lm",
            ],
            check=True,
        )
        out = subprocess.run(
            [tools[1], "-m", "atmega328p", "-f", "16000000", str(elf)], capture_output=True, text=True, timeout=60
        )
    return {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", out.stdout + out.stderr)}


def c_accuracy():
    """Largest |C − Python| over the whole bundled recording, both axes, the C defaults (skip gate)."""
    axes, dt, _, _ = lab05.pipeline_inputs()
    rows = []
    for name, (w, z, ok, _) in axes.items():
        c = c_filter(w, z, ok, dt)
        if c is None:
            return
        ref = TiltBiasKF(dt, tilt.TiltBiasKFSettings()).run(w, z, ok)
        rows.append((name, np.max(np.abs(c[1][:, 0] - ref.angle)), np.max(np.abs(c[1][:, 1] - ref.bias))))
    print("\n| C (float32) vs Python (float64), whole 05_tilt_protocol | max angle difference | max bias difference |")
    print("| --- | --- | --- |")
    for name, da, db in rows:
        print(f"| {name} | {da:.1e} rad | {db:.1e} rad/s |")


def speed():
    rng = np.random.default_rng(0)
    n, dt = 6000, 0.01
    w, z, ok = rng.normal(0, 0.5, n), rng.normal(0, 0.3, n), rng.random(n) > 0.2
    kf = TiltBiasKF(dt, q_angle=2e-6, q_bias=2e-10, r=1.6e-5, accel_gating="skip")
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
    c = c_filter(w, z, ok, dt)
    print("\n| [angle, bias] filter, 60 s at 100 Hz, skip gate | steps/s | 60 s of data in |")
    print("| --- | --- | --- |")
    print(f"| kfkit `TiltBiasKF.run` (Python floats) | {n / ours:,.0f} | {1000 * ours:.0f} ms |")
    print(f"| filterpy 2 `KalmanFilter` (NumPy matrices) | {n / theirs:,.0f} | {1000 * theirs:.0f} ms |")
    if c is not None:
        print(f"| firmware `tilt_kf.c`, gcc -O2, native | {1e9 / c[0]:,.0f} | {n * c[0] / 1e6:.2f} ms |")
    cycles = avr_cycles()
    if cycles:
        us = {k: v / 16.0 for k, v in cycles.items()}
        per_sample = 2 * us["update"] + us["roll"] + us["pitch"] + us["static"]
        print(
            f"\nATmega328P at 16 MHz (simavr): TiltKfUpdate {us['update']:.0f} µs ({cycles['update']} cycles), "
            f"coasting {us['coast']:.0f} µs, accelerometer roll {us['roll']:.0f} µs, pitch {us['pitch']:.0f} µs, "
            f"static test {us['static']:.0f} µs: the sketch's filter work per sample"
            f" ≈ {per_sample / 1000:.2f} ms of its 10 ms."
        )


if __name__ == "__main__":
    accuracy()
    c_accuracy()
    speed()
