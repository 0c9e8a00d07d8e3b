"""Checkpoints of lab 00 (setup and capture): the protocol's checksum and the board's clock."""

from __future__ import annotations

import numpy as np

from ..capture import board_time, checksum
from ..capture.protocol import MICROS_MODULO
from . import Case, Checkpoint, compare, fmt_pair, register, structural


def _checksum_cases(rng):
    bodies = [b"", b"0", b"123456,42,-120,35,16390,12,-8,3", b"KFKIT,1,board=mpu6050"]
    bodies += [bytes(rng.integers(32, 127, int(rng.integers(1, 80)), dtype=np.uint8)) for _ in range(8)]
    return [Case({"body": b}, checksum(b), f"body={b[:40]!r}") for b in bodies]


def _judge_checksum(case, got):
    if isinstance(got, (bytes, str)):
        return f"expected an int (0–255), got {type(got).__name__} {got!r}: return the number, not its hex text"
    return compare(case.expected, got, rtol=0, atol=0)


def _time_cases(rng):
    cases = []
    for start, wrap in ((0, False), (1500, False), (MICROS_MODULO - 35_000, True), (MICROS_MODULO - 1, True)):
        steps = rng.integers(9_000, 11_000, int(rng.integers(5, 30)))
        t_us = (start + np.concatenate([[0], np.cumsum(steps)])) % MICROS_MODULO
        label = "stamps that wrap past 2³² µs" if wrap and t_us[-1] < t_us[0] else f"stamps from {start} µs"
        cases.append(Case({"t_us": t_us}, board_time(t_us), label))
    return cases


def _judge_time(case, got):
    problem = compare(case.expected, got, rtol=0, atol=1e-9)
    if problem is None or structural(problem):
        return problem
    g, e, t_us = np.asarray(got, dtype=float), case.expected, case.args["t_us"]
    k = int(np.argmax(~np.isclose(g, e, rtol=0, atol=1e-9)))
    where = f" (t_us went {int(t_us[k - 1])} → {int(t_us[k])})" if k else ""
    want, have = fmt_pair(e[k], g[k])
    return f"at sample {k}: expected t = {want} s, got {have} s{where}"


register(
    Checkpoint(
        "00.checksum",
        "line_checksum",
        _checksum_cases,
        _judge_checksum,
        points=1,
        hint="start from 0 and XOR (^) every byte of the body in turn; iterating over bytes gives ints.",
    ),
    Checkpoint(
        "00.board_time",
        "board_time",
        _time_cases,
        _judge_time,
        points=2,
        hint="the first sample is t = 0; each step is (t_us[k] − t_us[k−1]) mod 2³² microseconds, "
        "so a wrap from 4294967290 to 20 is a step of 26 µs, not minus 71 minutes.",
    ),
)
