"""Guided capture protocols: what to do with the board, when, and the phase labels.

Each protocol is a simulated motion (:mod:`kfkit.motions`, :mod:`kfkit.calibration_motions`) whose ``phases`` are
the labelled windows. The same motion serves twice: the virtual board plays it, and with a real board its
phase timeline drives the prompts ("rest the board with x up…"), so the recording carries the
same labels either way (``meta["phases"]``, ``Recording.phase(label)``).

A label's prompt is one text, or a list of texts for the label's segments in time order: its
windows, each cut where the board starts or stops moving (the six headings share one label and
get one prompt each; an axis turn's window gets five: rest, turn, rest, turn back, rest).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import calibration_motions, motions
from ..sensors import board as get_board
from .recorder import capture


def _stationary(rate_hz, seed, duration):
    m = motions.stationary(duration, rate_hz)
    m.phases = [(0.0, float(duration), "stationary")]
    return m


@dataclass(frozen=True)
class GuidedProtocol:
    """``make(rate_hz, seed, **durations)`` → Motion; ``full``/``quick`` are the durations.

    ``datasets`` maps each board the protocol can be recorded with to the bundled recording the
    capture replaces (the file name lab 00 saves it under); ``board`` is the virtual board's default.
    ``prompts`` maps a phase label to its instruction, or to a list of them (module docstring).
    """

    name: str
    title: str
    board: str
    datasets: dict
    make: object
    full: dict
    quick: dict
    prompts: dict = field(default_factory=dict)
    move_prompt: str = "turn the board to the next position: {next}"  # between phases; {next}: what comes


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
# Lab 03's alignment check (axis_turns): per axis, rest / turn 90° / rest / turn back / rest, one phase.
_TURN_PROMPTS = {
    "turn_x": [
        "lay the board flat and still, printed X arrow pointing away from you",
        "roll it 90° about its X arrow, right edge down (printed Y arrow pointing up)",
        "hold it on its right edge, still",
        "roll it back flat",
        "flat and still",
    ],
    "turn_y": [
        "flat and still (the nose goes up next)",
        "pitch the nose up 90° (printed X arrow pointing up), turning about the Y arrow",
        "hold it standing on its back edge, still",
        "lower the nose back flat",
        "flat and still",
    ],
    "turn_z": [
        "flat and still (a turn on the table next)",
        "turn it 90° clockwise (seen from above), flat on the table",
        "hold still",
        "turn it back anticlockwise to where it was",
        "flat and still",
    ],
}
# Lab 03's heading test (heading_steps): headings east of true north, flat, then tilted in reverse order.
HEADINGS_DEG = (0, 60, 120, 180, 240, 300)
HEADING_TILT_DEG = (20, -15)  # (roll, pitch) of the tilted rests
_POINTS = {
    0: "north",
    60: "east-north-east",
    120: "east-south-east",
    180: "south",
    240: "west-south-west",
    300: "west-north-west",
}


def _heading_prompt(deg, tilted, first):
    where = "north" if deg == 0 else f"{_POINTS[deg]} ({deg}° clockwise from north)"
    where = f"nose (printed X arrow) pointing {where}, still"
    if not tilted:
        return f"flat on the table, {where}" + (
            "; find true north first (a map, or a phone's compass set to true north), away from steel and magnets"
            if first
            else ""
        )
    roll, pitch = HEADING_TILT_DEG
    how = (
        f"tilt the board, right edge about {roll}° down and nose about {-pitch}° down (prop up its back-left "
        f"corner on a book), "
        if first
        else "keep the tilt, "
    )
    return how + where


_HEADING_PROMPTS = {
    "heading_flat": [_heading_prompt(d, False, i == 0) for i, d in enumerate(HEADINGS_DEG)],
    "heading_tilted": [_heading_prompt(d, True, i == 0) for i, d in enumerate(HEADINGS_DEG[::-1])],
}
_NUCLEO, _MPU = "nucleo-iks02a1", "mpu6050"

PROTOCOLS = {
    p.name: p
    for p in (
        GuidedProtocol(
            "stationary",
            "Stationary (2 min): bias and noise",
            _NUCLEO,
            {_NUCLEO: "02_stationary", _MPU: "05_stationary"},
            lambda r, s, **kw: _stationary(r, s, **kw),
            {"duration": 120.0},
            {"duration": 5.0},
            {"stationary": "leave the board flat and still on the table; do not touch it"},
        ),
        GuidedProtocol(
            "six-faces",
            "Six faces: accelerometer bias and scale",
            _NUCLEO,
            {_NUCLEO: "02_six_faces", _MPU: "05_six_faces"},
            lambda r, s, **kw: calibration_motions.six_faces(rate_hz=r, seed=s, **kw),
            {"hold": 5.0, "move": 3.0},
            {"hold": 1.0, "move": 1.5},
            _FACE_PROMPTS,
        ),
        GuidedProtocol(
            "tilt",
            "Tilt protocol: 0°, 90°, 0° per axis (lab 05)",
            _MPU,
            {_MPU: "05_tilt_protocol", _NUCLEO: "05_tilt_protocol"},
            lambda r, s, **kw: motions.tilt_protocol(rate_hz=r, seed=s, **kw),
            {"hold": 2.0, "move": 1.5},
            {"hold": 0.6, "move": 1.0},
            _TILT_PROMPTS,
            "turn smoothly to the next angle: {next}",
        ),
        GuidedProtocol(
            "mag-rotations",
            "Magnetometer rotations: figure-eights over the sphere",
            _NUCLEO,
            {_NUCLEO: "03_mag_rotations"},
            lambda r, s, **kw: calibration_motions.mag_rotations(rate_hz=r, seed=s, **kw),
            {"duration": 60.0},
            {"duration": 8.0},
            {
                "mag_rotations": "tumble the board slowly in figure-eights, turning it over too, until the "
                "sphere coverage passes 90 %; stay away from steel and magnets"
            },
        ),
        GuidedProtocol(
            "axis-turns",
            "Axis turns: 90° about x, y, z and back (lab 03)",
            _NUCLEO,
            {_NUCLEO: "03_axis_turns"},
            lambda r, s, **kw: calibration_motions.axis_turns(rate_hz=r, **kw),
            {"hold": 3.0, "move": 3.0},
            {"hold": 1.0, "move": 1.5},
            _TURN_PROMPTS,
            "keep it flat and still",
        ),
        GuidedProtocol(
            "headings",
            "Headings: six flat, then six tilted (lab 03)",
            _NUCLEO,
            {_NUCLEO: "03_headings"},
            lambda r, s, **kw: calibration_motions.heading_steps(
                np.radians(HEADINGS_DEG), np.radians(HEADING_TILT_DEG), rate_hz=r, **kw
            ),
            {"hold": 4.0, "move": 4.0},
            {"hold": 1.0, "move": 1.5},
            _HEADING_PROMPTS,
            "turn the board to the next heading: {next}",
        ),
    )
}


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
        why = " (it has no magnetometer)" if get_board(board).mag is None else ""
        raise ValueError(
            f"the {name} protocol is not recorded with the {board}{why}; "
            f"record it with the {' or the '.join(p.datasets)}"
        )
    return p.datasets[board]


def protocol_motion(name: str, rate_hz: float, quick: bool = False, seed: int = 0, **durations):
    """The protocol's motion (with phases) at ``rate_hz``; ``quick`` uses the short CI durations."""
    p = _protocol(name)
    return p.make(rate_hz, seed, **{**(p.quick if quick else p.full), **durations})


def _still_or_moving(motion, start, stop) -> list[tuple]:
    """[start, stop) (s) cut where the motion starts or stops turning (|ω| > 1e-6 rad/s): [(a, b), …]."""
    inside = (motion.t >= start) & (motion.t < stop)
    moving = np.linalg.norm(motion.omega_b[inside], axis=1) > 1e-6
    cuts = motion.t[inside][1:][np.diff(moving.astype(int)) != 0]
    edges = [float(start), *map(float, cuts), float(stop)]
    return list(zip(edges[:-1], edges[1:]))


def protocol_steps(name: str, motion) -> list[tuple]:
    """The prompt timeline [(start s, end s, label or None, prompt)] of a protocol's motion.

    Each phase window is one step, or one per segment where its label has a list of prompts;
    unlabelled gaps (turns between rests) say what comes next.
    """
    p = _protocol(name)
    end = len(motion.t) / motion.rate_hz
    segments, used = [], {}
    for start, stop, label in sorted(motion.phases):
        text = p.prompts.get(label, label)
        if isinstance(text, str):
            segments.append((float(start), float(stop), label, text))
            continue
        for a, b in _still_or_moving(motion, start, stop):
            segments.append((a, b, label, text[used.get(label, 0)]))
            used[label] = used.get(label, 0) + 1
    steps, t = [], 0.0
    for start, stop, label, text in segments:
        if start > t + 1e-9:
            steps.append((t, start, None, p.move_prompt.format(next=text)))
        steps.append((start, stop, label, text))
        t = stop
    if end > t + 1e-9:
        steps.append((t, end, None, "done: hold still"))
    return steps


def step_phases(steps) -> list[dict]:
    """The phase windows [{label, start, end}] of a prompt timeline: its labelled steps, neighbours of one
    label joined (the segments of one phase)."""
    phases = []
    for start, stop, label, _ in steps:
        if label is None:
            continue
        if phases and phases[-1]["label"] == label and abs(phases[-1]["end"] - start) < 1e-9:
            phases[-1]["end"] = stop
        else:
            phases.append({"label": label, "start": start, "end": stop})
    return phases


def protocol_capture_options(name: str, port, board=None, quick=False, fast=False, seed=0):
    """(seconds, steps, Recorder options) for recording protocol ``name`` from ``port``.

    With ``port="virtual"`` the virtual board plays the protocol's motion (``fast``: faster than
    real time); with a real board the phases come from the prompt timeline.
    """

    board = board or _protocol(name).board
    dataset_name(name, board)  # raises if this board cannot record it
    motion = protocol_motion(name, get_board(board).rate_hz, quick=quick, seed=seed)
    steps = protocol_steps(name, motion)
    if port == "virtual":
        options = {"virtual": {"motion": motion, "board": board, "realtime": not fast, "seed": seed}}
    else:
        options = {"phases": step_phases(steps)}
    return len(motion.t) / motion.rate_hz, steps, options


def record_protocol(
    name: str, port="virtual", out=None, board=None, quick=False, fast=False, seed=0, baud=115200, prompt=print
):
    """Record guided protocol ``name`` into ``out``; ``prompt(text)`` gets each instruction as it comes due.

    Returns the Recording (phases labelled in its metadata). See :func:`protocol_capture_options`.
    """

    seconds, steps, options = protocol_capture_options(name, port, board, quick, fast, seed)
    if prompt is None or port == "virtual":
        return capture(port, seconds, out, baud=baud, **options)
    shown = [0]  # steps prompted so far

    def say(upto):  # every step up to ``upto`` in turn, however seldom progress() is called
        while shown[0] <= upto:
            start, _, _, text = steps[shown[0]]
            prompt(f"{start:6.1f} s  {text}")
            shown[0] += 1

    say(0)  # the first instruction applies from the start
    return capture(
        port, seconds, out, baud=baud, progress=lambda _, rec: say(steps.index(step_at(steps, rec.elapsed))), **options
    )


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
