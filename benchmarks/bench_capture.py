"""Capture: parser speed, and a 1 kHz virtual board for 60 s while the live plot redraws.

    python benchmarks/bench_capture.py            # 60 s at 1 kHz
    python benchmarks/bench_capture.py --quick    # 5 s at 1 kHz

Budgets (DESIGN): parser ≥ 50,000 lines/s; 1 kHz for 60 s with zero lost lines while a live plot
refreshes (here the capture panel's own figure, rendered with Agg on the main thread, competing with
the reader thread for the GIL as in a notebook). The serial link's line-rate ceilings at 115,200 and
921,600 baud (8N1: 10 bits a byte) for each board's line length are printed beside them.
"""

import argparse
import os
import re
import time

import numpy as np

from kfkit.capture import Recorder, VirtualBoard, encode_sample, parse_line
from kfkit.capture.virtual import board_header
from kfkit.sensors import board


def mpu6050_lines(n=2_000, seed=0):
    """MPU6050-style lines (8 fields)."""
    rng = np.random.default_rng(seed)
    acc = rng.normal([0, 0, 16384], 60, (n, 3)).astype(int)
    gyr = rng.normal(0, 40, (n, 3)).astype(int)
    return [encode_sample((1_000_000 + 10_000 * k, k % 65536, *acc[k], *gyr[k])) for k in range(n)]


def sample_lines(n=20_000, seed=0):
    """Nucleo-style lines (12 fields) with realistic magnitudes."""
    rng = np.random.default_rng(seed)
    acc = rng.normal([0, 0, 8197], 40, (n, 3)).astype(int)
    gyr = rng.normal(0, 30, (n, 3)).astype(int)
    mag = rng.normal([130, 10, -300], 5, (n, 3)).astype(int)
    return [encode_sample((1_000_000 + 9615 * k, k % 65536, *acc[k], *gyr[k], *mag[k], k % 2)) for k in range(n)]


_SAMPLE = re.compile(rb"\$([-0-9,]+)\*([0-9A-F]{2})\s*")


def naive_parse(line: bytes):
    """A first attempt: regex, XOR byte by byte in a loop, int() per field."""
    m = _SAMPLE.fullmatch(line)
    if m is None:
        return None
    x = 0
    for c in m.group(1):
        x ^= c
    if x != int(m.group(2), 16):
        return None
    return [int(v) for v in m.group(1).split(b",")]


def lines_per_second(parse, lines, repeats=3):
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for line in lines:
            parse(line)
        best = min(best, time.perf_counter() - t0)
    return len(lines) / best


def live_capture(seconds, rate_hz=1000.0, poll_hz=10.0, window_s=5.0):
    """A real-time virtual board at ``rate_hz``; the consumer redraws the capture panel's live figure
    (kfkit.widgets.LiveSignals on a matplotlib Agg canvas) from ``recording(last_seconds)`` at ``poll_hz``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kfkit.widgets import LiveSignals

    live = LiveSignals(Figure(figsize=(9.0, 5.4), layout="constrained"), window_s)
    canvas = FigureCanvasAgg(live.fig)
    poll_times, draws = [], 0
    with VirtualBoard(rate_hz=rate_hz, board="nucleo-iks02a1", seed=1) as vb:
        rec = Recorder(vb, seconds=seconds).start()
        try:
            while not rec.wait(1.0 / poll_hz):
                t0 = time.perf_counter()
                if live.update(rec.recording(last_seconds=window_s)):
                    canvas.draw()  # render the whole figure, as the browser's canvas would get it
                    draws += 1
                poll_times.append(time.perf_counter() - t0)
        finally:
            stats = rec.stop()
    return stats, np.array(poll_times), draws


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 s instead of 60 s")
    args = parser.parse_args()
    seconds = 5.0 if args.quick else 60.0

    lines = sample_lines()
    kfkit_rate = lines_per_second(parse_line, lines)
    naive_rate = lines_per_second(naive_parse, lines)
    print("Parser, 20,000 Nucleo sample lines (12 fields):\n")
    print("| parser | lines/s | ratio |\n| --- | --- | --- |")
    print(f"| kfkit.capture.parse_line | {kfkit_rate:,.0f} | 1.0× |")
    print(f"| regex + per-byte XOR loop | {naive_rate:,.0f} | {naive_rate / kfkit_rate:.2f}× |")
    print(
        f"\nbudget ≥ 50,000 lines/s: {'met' if kfkit_rate >= 50_000 else 'NOT met'} "
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)\n"
    )

    print("Serial link ceilings (8N1: 10 bits a byte) for protocol v1 lines:\n")
    print(
        "| board (fields) | header | mean line | longest line | lines/s at 115,200 baud (mean / longest) "
        "| lines/s at 921,600 baud (mean / longest) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for name, lines_of_board in (("nucleo-iks02a1", lines), ("mpu6050", mpu6050_lines())):
        b = board(name)
        n_fields = len(parse_line(lines_of_board[0]))
        mean_len = np.mean([len(line) for line in lines_of_board])
        values = [-32768] * (n_fields - 2)  # every count at its longest; mag_new (last, Nucleo) is one digit
        values[-1] = 1 if b.mag is not None else values[-1]
        worst = len(encode_sample((4294967295, 65535, *values)))
        ceilings = [f"{baud / 10 / mean_len:,.0f} / {baud / 10 / worst:,.0f}" for baud in (115_200, 921_600)]
        print(
            f"| {name} ({n_fields}) | {len(board_header(b, b.rate_hz))} B once | {mean_len:.1f} B | {worst} B | "
            f"{ceilings[0]} | {ceilings[1]} |"
        )
    print(
        "\n(The boards stream 104 and 100 Hz: inside the 115,200 baud ceiling. 1 kHz of 12-field lines needs\n"
        "≈ 0.5 Mbaud: over a real UART use 921,600 baud. The virtual board is a pty: no baud limit.)\n"
    )

    stats, polls, draws = live_capture(seconds)
    made = int(round(seconds * 1000.0))  # samples the board made with t < seconds: all should arrive
    lost = made - stats.samples
    print(
        f"Virtual board at 1 kHz for {seconds:g} s; the live figure redrawn (Agg) from recording(last_seconds=5) "
        f"at 10 Hz on the main thread:\n"
    )
    print(
        "| samples made | received | lost lines | bad lines | dropped (seq) | effective rate | redraws | "
        "redraw time mean / max |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    print(
        f"| {made:,} | {stats.samples:,} | {lost} | {stats.bad_lines} | {stats.dropped} | {stats.rate_hz:.1f} Hz | "
        f"{draws} | {1e3 * polls.mean():.0f} ms / {1e3 * polls.max():.0f} ms |"
    )
    print(f"\nbudget 0 lost lines: {'met' if lost == 0 and stats.dropped == 0 else 'NOT met'}")
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"(machine load average during the run: {load} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
