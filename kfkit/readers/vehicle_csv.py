"""Your own drive from a CSV (a logger or spreadsheet export), read by naming its columns and units.

:func:`load_vehicle_csv` maps the file's columns to the kit's vehicle recording (``t``, ``delta``,
``yaw_rate``, ``ay``, ``vx``, SI, ISO 8855 axes: the kit's own ``# kfkit-vehicle`` format is
:func:`kfkit.io.load_vehicle`), and :func:`sign_check` warns when the signs of δ, r and a_y
disagree with ISO 8855 in the turns.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..frames import G
from ..io import VEHICLE_COLUMNS, VEHICLE_TRUTH, Recording, RecordingError, csv_rows, read_csv_rows, read_lines
from ..vehicle import KMH

#: unit name → factor to SI, per kind of quantity (the options of :func:`load_vehicle_csv`)
CSV_UNITS = {
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6},
    "delta": {"rad": 1.0, "deg": math.pi / 180.0},
    "yaw_rate": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "ay": {"m/s^2": 1.0, "m/s2": 1.0, "g": G},
    "vx": {"m/s": 1.0, "km/h": KMH},
    "true_beta": {"rad": 1.0, "deg": math.pi / 180.0},
    "true_yaw_rate": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "true_vy": {"m/s": 1.0, "km/h": KMH},
}


def load_vehicle_csv(
    path,
    columns: dict,
    units: dict | None = None,
    delimiter=",",
    comment="#",
    steer_ratio: float | None = None,
    negate=(),
) -> Recording:
    """Load your own drive from a CSV (a logger or spreadsheet export) by naming its columns.

    ``columns`` maps the kit's names to the file's header names: required ``t``, ``delta``
    (road-wheel steering), ``yaw_rate``, ``ay``, ``vx``; optional ``true_beta``,
    ``true_yaw_rate``, ``true_vy``. ``units`` picks each column's unit (default SI):
    t 's'|'ms'|'us', delta/true_beta 'rad'|'deg', yaw_rate 'rad/s'|'deg/s', ay 'm/s^2'|'g',
    vx/true_vy 'm/s'|'km/h'. ``steer_ratio``: the delta column is the steering-*wheel* angle,
    divided by this ratio (e.g. 16) to give the road-wheel angle. ``negate``: kit names whose
    sign is flipped to ISO 8855 (y left, z up): a y-right/z-down logger needs ('yaw_rate', 'ay').
    Lines starting with ``comment`` are skipped; the first other line is the header; a trailing
    delimiter is allowed. A last line without its newline may be a row cut short mid-number (the
    file copied or written incompletely): it is dropped, with a warning naming the file and line
    that is also kept in ``meta['warnings']`` (most writers end every line; losing one row is
    safer than reading a cut number). Everything is converted to SI and t starts at 0 (the file's first time
    is kept in ``meta['t0']``, s). V_x = 0 (standing) is valid (:func:`~kfkit.filters.estimate_sideslip`
    handles it); V_x < 0 (reversing) is not. Errors name the file, line and column; a warning
    names the file when the signs of δ, r and a_y disagree in the turns (:func:`sign_check`).

        rec = load_vehicle_csv("mycar.csv", columns={"t": "Time", "delta": "RoadWheelAngle",
                               "yaw_rate": "YawRate", "ay": "LatAcc", "vx": "Speed"},
                               units={"delta": "deg", "yaw_rate": "deg/s", "ay": "g", "vx": "km/h"})
    """
    path = Path(path)
    units = dict(units or {})
    missing = [c for c in VEHICLE_COLUMNS if c not in columns]
    unknown = [c for c in dict.fromkeys([*columns, *units, *negate]) if c not in CSV_UNITS]
    if missing or unknown:
        raise ValueError(
            f"load_vehicle_csv({path}): columns must name {', '.join(VEHICLE_COLUMNS)} "
            f"(optional {', '.join(VEHICLE_TRUTH)})"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(unknown)}" if unknown else "")
        )
    if steer_ratio is not None and not (math.isfinite(steer_ratio) and steer_ratio > 0):
        raise ValueError(
            f"load_vehicle_csv({path}): steer_ratio must be a positive number (steering wheel ÷ road wheel), "
            f"got {steer_ratio!r}"
        )
    scale = {}
    for name in columns:
        unit = units.get(name, next(iter(CSV_UNITS[name])))
        if unit not in CSV_UNITS[name]:
            raise ValueError(
                f"load_vehicle_csv({path}): unit {unit!r} for {name}; choose one of {', '.join(CSV_UNITS[name])}"
            )
        scale[name] = CSV_UNITS[name][unit] * (-1.0 if name in negate else 1.0)
    if steer_ratio is not None:
        scale["delta"] /= steer_ratio
    lines, terminated = read_lines(path)
    notes = []
    if not terminated and lines and lines[-1].strip():
        notes.append(
            f"{path}, line {len(lines)}: the last line has no newline, so a number in it may be cut short: dropped"
        )
        lines = lines[:-1]
    skip = 0
    while skip < len(lines) and (not lines[skip].strip() or lines[skip].lstrip().startswith(comment)):
        skip += 1
    if skip == len(lines):
        raise RecordingError(path, None, "the file has no header line")
    header = [c.strip() for c in next(csv_rows(path, [lines[skip]], skip + 1, delimiter))]
    while header and not header[-1]:  # "a;b;c;" from a spreadsheet: the rows may or may not end in ';' too
        header.pop()
    raw, linenos = read_csv_rows(path, lines[skip + 1 :], skip + 2, header, dict(columns), delimiter)
    if np.any(raw["vx"] * scale["vx"] < 0):
        k = int(np.argmax(raw["vx"] * scale["vx"] < 0))
        raise RecordingError(
            path,
            int(linenos[k]),
            f"column {columns['vx']!r} (vx): {raw['vx'][k]:g} "
            f"{units.get('vx', 'm/s')} is negative (reversing): the bicycle model is for forward driving; "
            "cut the reversing part or check the column's sign",
        )
    t0 = float(raw["t"][0])
    raw["t"] = raw["t"] - t0  # before scaling: epoch timestamps in ms keep their resolution
    data = {k: raw[k] * scale[k] for k in VEHICLE_COLUMNS + VEHICLE_TRUTH if k in raw}
    t0 *= scale["t"]
    if len(data["t"]) < 2:
        raise RecordingError(
            path, int(linenos[0]), "only one data row: a drive needs at least two (its rate is the rows' spacing)"
        )
    dt = np.diff(data["t"])
    meta = {
        "rate_hz": float(1.0 / np.median(dt)),
        "source": str(path),
        "t0": t0,
        "columns": dict(columns),
        "units": {k: units.get(k, next(iter(CSV_UNITS[k]))) for k in columns},
        "negated": list(negate),
        "steer_ratio": steer_ratio,
        "warnings": notes,
    }
    for problem in notes + [
        f"{path}: {p}" for p in sign_check(data["delta"], data["yaw_rate"], data["ay"], data["vx"])
    ]:
        warnings.warn(problem, stacklevel=2)
    return Recording(meta, data, path)


def sign_check(delta, yaw_rate, ay, vx, min_ay=1.0, min_samples=20) -> list[str]:
    """What disagrees with ISO 8855 signs (δ, r, a_y all > 0 in a left turn), as messages; [] if all agree.

    Looks only at the turns: samples with V_x > 3 m/s and |V_x·r| > ``min_ay`` (m/s²), at least
    ``min_samples`` of them. In a turn a_y ≈ V_x·r and δ has the sign of r (counter-steering in a
    drift is the exception, hence a warning, not an error).
    """
    delta, r, ay, vx = (np.asarray(v, dtype=float) for v in (delta, yaw_rate, ay, vx))
    turning = (vx > 3.0) & (np.abs(vx * r) > min_ay)
    if turning.sum() < min_samples:
        return []
    ay_vs_r = float(np.sum(ay[turning] * r[turning])) > 0
    delta_vs_r = float(np.sum(delta[turning] * r[turning])) > 0
    if ay_vs_r and delta_vs_r:
        return []
    if not ay_vs_r and delta_vs_r:
        fix = "a_y has the wrong sign: pass negate=('ay',)"
    elif not ay_vs_r:
        fix = "the yaw rate has the wrong sign: pass negate=('yaw_rate',)"
    else:
        fix = (
            "steering disagrees with both: negate=('delta',) if your steering is positive to the right, or "
            "negate=('yaw_rate', 'ay') if the logger's axes are y right, z down"
        )
    return [
        f"in the turns ({int(turning.sum())} samples) the signs of δ, r and a_y disagree with ISO 8855 "
        f"(all three > 0 in a left turn; a_y ≈ V_x·r): {fix}"
    ]
