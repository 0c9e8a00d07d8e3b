"""Guided capture protocols: what to do with the board, when, and the phase labels.

Each protocol is a simulated motion from :mod:`kfkit.sim` whose ``phases`` are the labelled
windows. The same motion serves twice: the virtual board plays it, and with a real board its
phase timeline drives the prompts ("rest the board with x up…"), so the recording carries the
same labels either way (``meta["phases"]``, ``Recording.phase(label)``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import sim


def _stationary(rate_hz, seed, duration):
    m = sim.stationary(duration, rate_hz)
    m.phases = [(0.0, float(duration), "stationary")]
    return m


@dataclass(frozen=True)
class GuidedProtocol:
    """``make(rate_hz, seed, **durations)`` → Motion; ``full``/``quick`` are the durations.

    ``datasets`` maps each board the protocol can be recorded with to the bundled recording the
    capture replaces (the file name lab 00 saves it under); ``board`` is the virtual board's default.
    """

    name: str
    title: str
    board: str
    datasets: dict
    make: object
    full: dict
    quick: dict
    prompts: dict = field(default_factory=dict)
    move_prompt: str = "turn the board to the next position"


# Prompts name the body axes (x forward, y right, z down) and what a student sees: the sensor's X and
# Y arrows printed on the board, which are the body's x and −y (the chips read +1 g on z when flat).
_FACE_PROMPTS = {
    "z_down": "lay the board flat, components up (body z down), and keep it still",
    "y_down": "stand the board on its right edge, printed Y arrow pointing up (rolled 90°: body y down), still",
    "z_up": "turn the board upside down, components facing the table (body z up), still",
    "y_up": "stand the board on its left edge, printed Y arrow pointing down (body y up), still",
    "x_up": "stand the board on its back edge, printed X arrow pointing up (nose up: body x up), still",
    "x_down": "stand the board on its front edge, printed X arrow pointing down (nose down: body x down), still",
}
_TILT_PROMPTS = {
    "pitch_0": "hold the board level (pitch 0°), still",
    "pitch_90": "pitch the nose up to 90°, printed X arrow pointing up, and hold still",
    "roll_0": "hold the board level (roll 0°), still",
    "roll_90": "roll right to 90°, right edge down (printed Y arrow pointing up), and hold still",
}
_NUCLEO, _MPU = "nucleo-iks02a1", "mpu6050"

PROTOCOLS = {p.name: p for p in (
    GuidedProtocol("stationary", "Stationary (2 min): bias and noise", _NUCLEO,
                   {_NUCLEO: "02_stationary", _MPU: "05_stationary"},
                   lambda r, s, **kw: _stationary(r, s, **kw), {"duration": 120.0}, {"duration": 5.0},
                   {"stationary": "leave the board flat and still on the table; do not touch it"}),
    GuidedProtocol("six-faces", "Six faces: accelerometer bias and scale", _NUCLEO,
                   {_NUCLEO: "02_six_faces", _MPU: "05_six_faces"},
                   lambda r, s, **kw: sim.six_faces(rate_hz=r, seed=s, **kw), {"hold": 5.0, "move": 3.0},
                   {"hold": 1.0, "move": 1.5}, _FACE_PROMPTS),
    GuidedProtocol("tilt", "Tilt protocol: 0°, 90°, 0° per axis (lab 05)", _MPU,
                   {_MPU: "05_tilt_protocol", _NUCLEO: "05_tilt_protocol"},
                   lambda r, s, **kw: sim.tilt_protocol(rate_hz=r, seed=s, **kw), {"hold": 2.0, "move": 1.5},
                   {"hold": 0.6, "move": 1.0}, _TILT_PROMPTS, "turn smoothly to the next angle"),
    GuidedProtocol("mag-rotations", "Magnetometer rotations: figure-eights over the sphere", _NUCLEO,
                   {_NUCLEO: "03_mag_rotations"}, lambda r, s, **kw: sim.mag_rotations(rate_hz=r, seed=s, **kw),
                   {"duration": 60.0}, {"duration": 8.0},
                   {"mag_rotations": "tumble the board slowly in figure-eights, turning it over too, until the "
                                     "sphere coverage passes 90 %; stay away from steel and magnets"}),
)}


def _protocol(name) -> GuidedProtocol:
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ValueError(f"unknown guided protocol {name!r}; known: {', '.join(PROTOCOLS)}") from None


def dataset_name(name: str, board: str | None = None) -> str:
    """The bundled recording that protocol ``name`` recorded on ``board`` replaces ('05_six_faces' on
    an MPU6050, '02_six_faces' on the Nucleo): the file name (+ '.csv') labs 02–05 look for."""
    p = _protocol(name)
    board = board or p.board
    if board not in p.datasets:
        why = " (it has no magnetometer)" if name == "mag-rotations" else ""
        raise ValueError(f"the {name} protocol is not recorded with the {board}{why}; "
                         f"record it with the {' or the '.join(p.datasets)}")
    return p.datasets[board]


def protocol_motion(name: str, rate_hz: float, quick: bool = False, seed: int = 0, **durations):
    """The protocol's motion (with phases) at ``rate_hz``; ``quick`` uses the short CI durations."""
    p = _protocol(name)
    return p.make(rate_hz, seed, **{**(p.quick if quick else p.full), **durations})


def protocol_steps(name: str, motion) -> list[tuple]:
    """The prompt timeline [(start s, end s, label or None, prompt)] of a protocol's motion."""
    p = _protocol(name)
    end = len(motion.t) / motion.rate_hz
    steps, t = [], 0.0
    for start, stop, label in sorted(motion.phases):
        if start > t + 1e-9:
            steps.append((t, float(start), None, f"{p.move_prompt}: {p.prompts.get(label, label)}"))
        steps.append((float(start), float(stop), label, p.prompts.get(label, label)))
        t = float(stop)
    if end > t + 1e-9:
        steps.append((t, end, None, "done: hold still"))
    return steps


def protocol_capture_options(name: str, port, board=None, quick=False, fast=False, seed=0):
    """(seconds, steps, Recorder options) for recording protocol ``name`` from ``port``.

    With ``port="virtual"`` the virtual board plays the protocol's motion (``fast``: faster than
    real time); with a real board the phases come from the prompt timeline.
    """
    from ..sensors import board as get_board

    board = board or _protocol(name).board
    dataset_name(name, board)  # raises if this board cannot record it
    motion = protocol_motion(name, get_board(board).rate_hz, quick=quick, seed=seed)
    steps = protocol_steps(name, motion)
    if port == "virtual":
        options = {"virtual": {"motion": motion, "board": board, "realtime": not fast, "seed": seed}}
    else:
        options = {"phases": [{"label": lab, "start": a, "end": b} for a, b, lab, _ in steps if lab]}
    return len(motion.t) / motion.rate_hz, steps, options


def record_protocol(name: str, port="virtual", out=None, board=None, quick=False, fast=False, seed=0,
                    baud=115200, prompt=print):
    """Record guided protocol ``name`` into ``out``; ``prompt(text)`` gets each instruction as it comes due.

    Returns the Recording (phases labelled in its metadata). See :func:`protocol_capture_options`.
    """
    from .recorder import capture

    seconds, steps, options = protocol_capture_options(name, port, board, quick, fast, seed)
    shown = []

    def progress(fraction, rec):
        step = step_at(steps, rec.elapsed)
        if prompt is not None and (not shown or shown[-1] is not step):
            shown.append(step)
            prompt(f"{step[0]:6.1f} s  {step[3]}")

    return capture(port, seconds, out, baud=baud, progress=progress if prompt is not None and port != "virtual" else None,
                   **options)


def step_at(steps, t: float):
    """The step of ``steps`` running at time ``t`` (s), or the last one."""
    for step in steps:
        if step[0] <= t < step[1]:
            return step
    return steps[-1]


# 26 directions: the cube's face, edge and corner directions (unit vectors)
_DIRECTIONS = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], dtype=float) - 1.0
_DIRECTIONS /= np.linalg.norm(_DIRECTIONS, axis=1, keepdims=True)


def sphere_coverage(vectors, center=None, min_count: int = 3) -> float:
    """Fraction of 26 sphere directions visited by the directions of ``vectors − center`` (N, 3).

    Each vector is assigned to the nearest of 26 directions (the cube's faces, edges and
    corners); a direction counts once it holds ``min_count`` vectors: 1.0 = every direction
    seen. ``center`` defaults to 0, fine for raw magnetometer counts while the hard-iron offset
    is smaller than the Earth's field; pass a hard-iron estimate otherwise.
    """
    v = np.asarray(vectors, dtype=float)
    v = v[np.all(np.isfinite(v), axis=1)]
    if center is not None:
        v = v - np.asarray(center, dtype=float)
    if len(v) < min_count:
        return 0.0
    nearest = np.argmax(v @ _DIRECTIONS.T, axis=1)
    return float(np.mean(np.bincount(nearest, minlength=len(_DIRECTIONS)) >= min_count))
