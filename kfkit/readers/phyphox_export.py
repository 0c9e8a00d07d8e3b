"""phyphox's CSV export: read it into a kit :class:`~kfkit.io.Recording`, and write it (simulations).

Also the one phyphox sensor vocabulary the kit uses: :data:`KINDS` (the kit's short names of the
sensors phyphox records, and what to call them), :data:`SET_NAMES` (export file names),
:data:`SOURCES` (the remote interface's ``/config`` input sources, :mod:`kfkit.capture.phyphox_http`)
and :data:`UNIT_OF`.

What phyphox writes (phyphox-android ``DataExport.java``, phyphox-ios ``ExperimentExportSet.swift``):

- The CSV formats are a **zip with one file per export set**, ``<set name>.csv``, plus
  ``meta/device.csv`` and ``meta/time.csv``; unpacked, it is a folder. A single-sensor experiment
  has one set, ``Raw Data`` (``Raw Data.csv``); a "simple experiment" (phyphox's ``+`` → "New
  simple experiment") has one set per ticked sensor: ``Accelerometer``, ``Gyroscope``,
  ``Magnetometer``, ``Linear Acceleration`` (iOS: ``Linear Accelerometer``), ``Gravity``, …
- Five CSV variants: comma + decimal point, tabulator + decimal point, semicolon + decimal point,
  tabulator + decimal comma, semicolon + decimal comma (the remote interface's ``/export?format=1…5``).
- The first line holds the column labels in double quotes, e.g. ``"Time (s)","Acceleration x (m/s^2)"``;
  the labels come from the experiment: ``Acceleration x (m/s^2)``, ``Linear Acceleration x (m/s^2)``,
  ``Gyroscope x (rad/s)``, ``Magnetic Field x (µT)`` (``Magnetic field x (µT)`` in simple
  experiments), ``Absolute acceleration (m/s^2)``, ``Absolute (rad/s)``, ``Absolute field (µT)``;
  iOS simple experiments write ``X (m/s^2)``, ``X (rad/s)``, ``X (µT)``.
- Numbers have ten significant digits in scientific notation (Android ``0.000000000E0``, e.g.
  ``9.806650000E0``; iOS likewise); a column shorter than its set is padded with ``NaN`` (Android)
  or ``""`` (iOS). Android ends every line with a newline, iOS omits the last one.

A last line without its newline may also be a copy cut short (``1.000000000E-3`` cut to ``1.000000``
still parses). One rule, whether the file comes from a zip, a folder or on its own: a last row that is
complete (every field present, each number in phyphox's full format ``d.dddddddddE±x`` or padding) is kept;
one that is visibly cut is dropped, counted (``meta["phone"]["skipped"][sensor]["cut_last_row"]``), noted in
``meta["phone"]["warnings"]`` and warned about (:func:`load_phyphox`): one sample lost against a wrong
value kept. A damaged zip, a zip holding two exports, and a garbled truth file are errors naming the file.
Values a recording cannot hold are errors naming the file, line and column: beyond the phone's counts
(±(2³¹ − 1) LSBs, :data:`kfkit.sensors.PHONE_MAX_COUNTS`), time beyond 2⁵³ µs, or a number longer than
:data:`kfkit.io.MAX_NUMBER_CHARS` characters.

Sensor axes and signs are the phone frame's (:func:`kfkit.sensors.phone_board`); the accelerometer is the
specific force on both platforms. :func:`load_phyphox` puts the sensors on the gyroscope's time base
(:class:`kfkit.clocks.OneClock`), numbers the rows with :class:`kfkit.clocks.SampleCounter` (jitter is
not a gap), stores fixed-point counts (:data:`kfkit.sensors.PHONE_LSB`) and the phone's mounting, and
keeps the phone's experiment time (seconds since its start button) as ``t``.
Simulated exports made by the kit add ``kfkit_truth.csv`` (the true attitude at each gyro row).
"""

from __future__ import annotations

import contextlib
import math
import re
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..clocks import OneClock, SampleCounter
from ..frames import dcm_to_euler, quat_to_dcm
from ..io import BOM, Recording, RecordingError, parse_count, parse_header, parse_number, shown
from ..phone_sim import TRUTH_FILE, TRUTH_KIND
from ..sensors import (
    DEFAULT_PHONE_MOUNT,
    PHONE_BOARD,
    PHONE_LSB,
    PHONE_MAX_COUNTS,
    SI_UNITS,
    phone_counts,
    phone_mount,
    phone_sensor_metadata,
)

SEPARATORS = (",", "\t", ";")
#: sensor kinds phyphox exports, as named in its file format (``<sensor type="…">``)
KINDS = {
    "acc": "accelerometer",
    "gyr": "gyroscope",
    "mag": "magnetometer",
    "lin": "linear acceleration",
    "gra": "gravity",
}
#: export set (file) names → kind; iOS names its linear set "Linear Accelerometer"
SET_NAMES = {
    "accelerometer": "acc",
    "gyroscope": "gyr",
    "magnetometer": "mag",
    "linear acceleration": "lin",
    "linear accelerometer": "lin",
    "gravity": "gra",
}
#: the remote interface's input sources (``/config`` ``inputs[].source``) → kind
SOURCES = {
    "accelerometer": "acc",
    "gyroscope": "gyr",
    "magnetic_field": "mag",
    "linear_acceleration": "lin",
    "gravity": "gra",
}
UNIT_OF = {**SI_UNITS, "lin": "m/s^2", "gra": "m/s^2"}
_UNIT_ALIASES = {
    "m/s^2": "m/s^2",
    "m/s²": "m/s^2",
    "m s^-2": "m/s^2",
    "rad/s": "rad/s",
    "µt": "uT",
    "μt": "uT",
    "ut": "uT",
}
_AXIS = re.compile(r"^(?P<name>.*?)\s*\b(?P<axis>[xyz])\s*\((?P<unit>[^)]*)\)$", re.IGNORECASE)
_TIME = re.compile(r"^time\s*\(s\)$", re.IGNORECASE)
MAX_TIME_S = 2**53 * 1e-6  # the latest time a recording holds exactly to the µs (285 years), s
SIMPLE_EXPERIMENT_HINT = (
    "in phyphox tap '+' → 'New simple experiment', tick Accelerometer, Gyroscope and "
    "Magnetometer, record, then export 'CSV (Comma, decimal point)'"
)
EXPERIMENT_FOR = {"acc": "'Acceleration with g'", "gyr": "'Gyroscope'", "mag": "'Magnetometer'"}


@dataclass
class SensorTable:
    """One sensor's samples from one CSV: times (N,) s and values (N, 3) SI, phone frame."""

    kind: str
    t: np.ndarray
    values: np.ndarray
    where: str  # the file, for messages
    skipped: dict
    file: str = ""  # its name in the export
    warnings: tuple = ()  # rows dropped for a reason the student should see


# --- reading one CSV --------------------------------------------------------------------------------


def _cells(line: str, sep: str) -> list[str]:
    return [c.strip().strip('"').strip() for c in line.rstrip("\r\n").split(sep)]


def _separator(header: str) -> str:
    counts = {sep: header.count(f'"{sep}"') + header.count(f'" {sep}"') for sep in SEPARATORS}
    sep = max(counts, key=counts.get)
    if counts[sep] == 0:  # one column, or labels without quotes
        sep = max(SEPARATORS, key=header.count)
    return sep


def _classify_columns(where, labels, set_kind):
    """{"t": column, "x"/"y"/"z": column} and the kind ('acc', 'gyr', 'mag', 'lin', 'gra')."""
    time = [i for i, label in enumerate(labels) if _TIME.match(label)]
    if len(time) > 1:
        raise RecordingError(
            where,
            1,
            f"{len(time)} time columns ({', '.join(labels[i] for i in time)}): "
            f"one sensor per file, as phyphox exports it",
        )
    if not time:
        raise RecordingError(
            where,
            1,
            f"no time column: the columns are {labels}. phyphox writes 'Time (s)' as the "
            f"first column of every sensor (was the file edited, or exported from one graph?)",
        )
    axes, names, units = {}, set(), set()
    for i, label in enumerate(labels):
        m = _AXIS.match(label)
        if m is None or label.lower().startswith("absolute"):
            continue
        unit = _UNIT_ALIASES.get(m["unit"].strip().lower())
        if unit is None:
            raise RecordingError(
                where, 1, f"column {label!r}: unit {m['unit']!r} is not one phyphox exports (m/s^2, rad/s, µT)"
            )
        if m["axis"].lower() in axes:
            raise RecordingError(
                where,
                1,
                f"two {m['axis'].lower()} columns ({labels[axes[m['axis'].lower()]]!r} and "
                f"{label!r}): one sensor per file, as phyphox exports it",
            )
        axes[m["axis"].lower()] = i
        names.add(m["name"].strip().lower())
        units.add(unit)
    missing = [a for a in "xyz" if a not in axes]
    if missing:
        raise RecordingError(
            where,
            1,
            f"no {', '.join(missing)} column: the columns are {labels}; a 3-axis sensor "
            f"exports '… x (unit)', '… y (unit)', '… z (unit)'",
        )
    if len(units) != 1:
        raise RecordingError(where, 1, f"the x, y, z columns have different units ({', '.join(sorted(units))})")
    unit = units.pop()
    kind = set_kind
    if kind is None:  # Raw Data.csv or a renamed file: the labels tell
        text = " ".join(names)
        kind = (
            "lin"
            if "linear" in text
            else "gra"
            if "gravity" in text
            else {"m/s^2": "acc", "rad/s": "gyr", "uT": "mag"}[unit]
        )
    if UNIT_OF[kind] != unit:
        raise RecordingError(where, 1, f"a {KINDS[kind]} file with columns in {unit}: {labels}")
    return {"t": time[0], **axes}, kind


def _number(where, lineno, label, text, decimal_comma):
    if text in ("", "NaN", "nan"):  # padding of a shorter column (Android NaN, iOS empty)
        return math.nan
    try:
        return parse_number(text.replace(",", ".") if decimal_comma else text)
    except ValueError as e:
        raise RecordingError(where, lineno, f"column {label!r}: {e}") from None


def _full_format(decimal: str) -> re.Pattern:
    """A cell as phyphox writes it in full: ten significant digits in scientific notation (``-1.234567890E-3``),
    or a shorter column's padding (Android ``NaN``, iOS ``""``)."""
    return re.compile(rf'-?[0-9]{re.escape(decimal)}[0-9]{{9}}E-?[0-9]+|NaN|""')


def _visibly_cut(line: str, sep: str, n_fields: int, decimal: str) -> bool:
    """True when a last line (without its newline) may be cut short: a field missing, or one not in phyphox's
    full format (:func:`_full_format`; ``1.000000000E-3`` cut to ``1.000000`` is not). A cut inside a number's
    exponent would look whole only if the exponent had two digits, |v| < 1e-9 or ≥ 1e10: no accelerometer, gyroscope
    or magnetometer reading in SI units (a zero is ``0.000000000E0``, a sensor's resolution far above 1e-9)."""
    cells = [c.strip() for c in line.rstrip("\r\n").split(sep)]
    full = _full_format(decimal)
    return len(cells) != n_fields or not all(full.fullmatch(c) for c in cells)


def _check_range(where, table, linenos, lines, sep, labels, wanted, kind):
    """Every value within what a recording holds: sensor values within the phone's counts (±:data:`PHONE_MAX_COUNTS`
    LSBs: what streams through protocol v1's int32), time within 2^53 µs (exact to the µs). RecordingError naming
    the first value beyond, its line and column."""
    lsb = PHONE_LSB.get(kind, PHONE_LSB["acc"])  # linear acceleration and gravity are m/s² too
    limits = np.array([MAX_TIME_S] + [PHONE_MAX_COUNTS * lsb] * 3)
    with np.errstate(invalid="ignore"):  # NaN padding is not beyond anything
        beyond = np.abs(table) > limits
    if not beyond.any():
        return
    row, col = np.unravel_index(int(np.argmax(beyond)), beyond.shape)
    lineno, label = int(linenos[row]), labels[wanted[col]]
    text = shown(_cells(lines[lineno - 1], sep)[wanted[col]])
    if col == 0:
        why = f"{text} s is beyond the time a recording holds (|t| ≤ 2^53 µs = {MAX_TIME_S:.4g} s, exact to the µs)"
    else:
        unit = UNIT_OF[kind]
        why = (
            f"{text} {unit} is beyond what a phone recording holds (|value| ≤ {limits[col]:,.4f} {unit}: "
            f"2^31 − 1 counts of {lsb:g} {unit}, the serial protocol's int32)"
        )
    raise RecordingError(where, lineno, f"column {label!r}: {why}: a corrupted value?")


def read_sensor_csv(text: str, where, set_kind=None) -> SensorTable:
    """One phyphox CSV (any of its five variants) → :class:`SensorTable`. ``set_kind`` is the kind its
    file name says, None to tell it from the labels. A last line without its newline is kept when it is
    complete (iOS writes none after its last row), dropped and noted when visibly cut (:func:`_visibly_cut`;
    see the module docstring). Errors name ``where``, the line and the column."""
    text = text.removeprefix(BOM)
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise RecordingError(where, 1, 'the file is empty: expected phyphox\'s column labels, e.g. "Time (s)"')
    sep = _separator(lines[0])
    labels = _cells(lines[0], sep)
    columns, kind = _classify_columns(where, labels, set_kind)
    body = [(i + 2, line) for i, line in enumerate(lines[1:]) if line.strip()]
    decimal_comma = sep != "," and any("," in line for _, line in body[:50])
    unterminated = bool(body) and body[-1][0] == len(lines) and not text.endswith(("\n", "\r"))
    cut = unterminated and _visibly_cut(body[-1][1], sep, len(labels), "," if decimal_comma else ".")
    notes = ()
    if cut:
        lineno, _ = body.pop()
        notes = (
            f"{where}, line {lineno}: the last line has no newline and is cut short (a field missing, or a "
            f"number not in phyphox's full format): dropped",
        )
    wanted = [columns[c] for c in ("t", "x", "y", "z")]
    table = np.empty((len(body), 4))
    for row, (lineno, line) in enumerate(body):
        cells = _cells(line, sep)
        if len(cells) != len(labels):
            raise RecordingError(where, lineno, f"expected {len(labels)} fields separated by {sep!r}, got {len(cells)}")
        table[row] = [_number(where, lineno, labels[c], cells[c], decimal_comma) for c in wanted]
    linenos = np.array([n for n, _ in body], dtype=np.int64)
    _check_range(where, table, linenos, lines, sep, labels, wanted, kind)
    padded = np.isnan(table[:, 0])  # rows past the end of a shorter column
    table, linenos = table[~padded], linenos[~padded]
    bad = np.isnan(table[:, 1:]).any(axis=1)
    table, linenos = table[~bad], linenos[~bad]
    if not len(table):
        raise RecordingError(where, 2, f"the file holds no samples of the {KINDS[kind]}")
    table[:, 0] = np.round(table[:, 0], 6)  # µs, as the kit's recordings hold time
    dt = np.diff(table[:, 0])
    back = np.flatnonzero(dt < 0)
    if back.size:
        k = back[0] + 1
        raise RecordingError(
            where,
            int(linenos[k]),
            f"time goes back from {table[k - 1, 0]:.6f} s to {table[k, 0]:.6f} s (two recordings in one file?)",
        )
    same = np.concatenate(
        [[False], dt == 0]
    )  # a repeated timestamp (to the µs) cannot be placed in time: keep the first
    table = table[~same]
    skipped = {
        "empty_rows": int(padded.sum()),
        "incomplete_rows": int(bad.sum()),
        "repeated_times": int(same.sum()),
        "cut_last_row": int(cut),
    }
    return SensorTable(kind, table[:, 0].copy(), table[:, 1:].copy(), str(where), skipped, warnings=notes)


# --- the export: folder, zip or single file ------------------------------------------------------------


def _export_files(path: Path) -> tuple[dict[str, tuple[str, str]], str]:
    """{file name: (text, where)} of the top-level CSVs and meta/device.csv, and how to name the export."""
    if path.is_dir():
        files = {p.name: p for p in sorted(path.glob("*.csv"))}
        device = path / "meta" / "device.csv"
        if device.is_file():
            files["meta/device.csv"] = device
        return {name: (_decode(p.read_bytes()), str(p)) for name, p in files.items()}, str(path)
    if zipfile.is_zipfile(path):
        return _zip_files(path), str(path)
    with open(path, "rb") as f:
        looks_zip = f.read(2) == b"PK"
    if looks_zip or path.suffix.lower() == ".zip":
        raise RecordingError(
            path,
            None,
            "a damaged .zip file (cut short or corrupted: its table of contents is "
            "missing): copy or download the export from the phone again",
        )
    return {path.name: (_decode(path.read_bytes()), str(path))}, str(path)


def _zip_files(path: Path) -> dict[str, tuple[str, str]]:
    """The CSVs of one export in a zip; files may sit at the top or in one folder (a zipped export folder).
    macOS's ``__MACOSX/`` copies are skipped; two exports in one zip are an error."""
    out, roots = {}, {}
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                name = info.filename
                parts = name.split("/")
                if (
                    info.is_dir()
                    or not name.lower().endswith(".csv")
                    or "__MACOSX" in parts
                    or parts[-1].startswith("._")
                ):
                    continue
                folder = "/".join(parts[:-2] if len(parts) > 1 and parts[-2] == "meta" else parts[:-1])
                roots.setdefault(folder, name)
                if len(roots) > 1:
                    first, second = roots.values()
                    raise RecordingError(
                        path,
                        None,
                        f"two exports in one zip ({first} and {second}): load each "
                        f"phyphox export on its own (unzip it and pass the folder of one)",
                    )
                key = "meta/device.csv" if name.endswith("meta/device.csv") else parts[-1]
                if len(parts) > 1 and parts[-2] == "meta" and key != "meta/device.csv":
                    continue
                out[key] = (_decode(z.read(info)), f"{name} in {path}")
    except RecordingError:
        raise
    except (
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        EOFError,
        OSError,
        NotImplementedError,
        ValueError,
        zlib.error,
    ) as e:
        raise RecordingError(
            path, None, f"a damaged .zip file ({e}): copy or download the export from the phone again"
        ) from None
    return out


def _decode(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # µ in a file re-saved by a spreadsheet on Windows


def _device_properties(text: str) -> dict:
    """meta/device.csv ("property","value" rows) → {property: value}."""
    lines = text.splitlines()
    if not lines:
        return {}
    sep = _separator(lines[0])
    props = {}
    for line in lines[1:]:
        cells = _cells(line, sep)
        if len(cells) >= 2 and cells[0]:
            props[cells[0]] = sep.join(cells[1:])
    return props


def read_export(path) -> tuple[dict[str, SensorTable], dict, tuple | None, str]:
    """The sensors of a phyphox export (folder, .zip or one CSV): ({kind: SensorTable}, device
    properties, the truth file's (text, where) or None, the export's name). Two files of one kind are an error.
    In a folder or zip, a CSV that is neither a known set nor a 3-axis sensor with a time column
    (another experiment's results) is left out; a single file given by path is always read."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no phyphox export at {path}")
    files, name = _export_files(path)
    single = path.is_file() and not zipfile.is_zipfile(path)
    truth = files.pop(TRUTH_FILE, None)
    device = _device_properties(files.pop("meta/device.csv", ("", ""))[0])
    tables: dict[str, SensorTable] = {}
    for file_name, (text, where) in files.items():
        stem = file_name[:-4] if file_name.lower().endswith(".csv") else file_name
        set_kind = SET_NAMES.get(stem.strip().lower())
        if set_kind is None and not single and stem.strip().lower() != "raw data" and not _is_sensor_header(text):
            continue
        table = read_sensor_csv(text, where, set_kind)
        table.file = file_name
        if table.kind in tables:
            raise RecordingError(
                where,
                None,
                f"a second {KINDS[table.kind]} file besides {tables[table.kind].where}: keep one export per folder",
            )
        tables[table.kind] = table
    if not tables:
        raise RecordingError(
            name, None, f"no sensor CSV found (files: {', '.join(files) or 'none'}); {SIMPLE_EXPERIMENT_HINT}"
        )
    return tables, device, truth, name


def _is_sensor_header(text: str) -> bool:
    header = text.lstrip("\ufeff").split("\n", 1)[0]
    labels = _cells(header, _separator(header))
    return any(_TIME.match(label) for label in labels) and {
        m["axis"].lower() for m in map(_AXIS.match, labels) if m
    } == set("xyz")


def _missing_message(tables, needed):
    found = ", ".join(f"{KINDS[k]} ({t.file})" for k, t in tables.items())
    msg = f"no {KINDS[needed]} in this phyphox export (found: {found})."
    if needed == "acc" and ("lin" in tables or "gra" in tables):
        other = "linear acceleration (gravity removed)" if "lin" in tables else "gravity alone"
        msg += (
            f" It holds the {other}, but the filters need the accelerometer's specific force including gravity: "
            f"record with phyphox's 'Acceleration with g' experiment, or tick 'Accelerometer' (not 'Linear "
            f"Acceleration') in a simple experiment."
        )
    else:
        msg += (
            f" phyphox's single-sensor experiments ({EXPERIMENT_FOR[needed]}, …) export one sensor each; "
            f"{SIMPLE_EXPERIMENT_HINT}."
        )
    return msg


# --- the Recording ----------------------------------------------------------------------------------------


def _sensor_meta(kind, device):
    android = {"acc": "accelerometer", "gyr": "gyroscope", "mag": "magnetic_field"}[kind]
    chip = device.get(f"{android} Name") or None
    full_scale = None
    with contextlib.suppress(KeyError, ValueError):
        full_scale = float(device[f"{android} Range"])
    return phone_sensor_metadata(kind, chip, full_scale)


def _truth_euler(where, text, index, M):
    """True [roll, pitch, yaw] (N, 3) of the body frame at the kept gyro rows, from kfkit_truth.csv
    (quaternions phone → NED per gyro row): R_nb = R_ns M_bsᵀ. Also its metadata. The kit writes every
    line with its newline, so a last line without one is an error (it may be cut short), wherever it is."""
    lines = text.removeprefix(BOM).splitlines()
    meta = parse_header(where, lines[0] if lines else "", TRUTH_KIND, needs_rate=False)
    if len(lines) > 2 and not text.endswith(("\n", "\r")):
        raise RecordingError(
            where, len(lines), "the last line is cut short (no newline at the end): regenerate the export"
        )
    table = np.empty((len(lines) - 2, 5)) if len(lines) > 2 else np.empty((0, 5))
    for row, line in enumerate(lines[2:]):
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 5:
            raise RecordingError(
                where, row + 3, f"expected 5 fields (row,true_qw,true_qx,true_qy,true_qz), got {len(cells)}"
            )
        try:
            table[row] = [parse_count(cells[0])] + [parse_number(c) for c in cells[1:]]
        except ValueError as e:
            raise RecordingError(where, row + 3, str(e)) from None
        if abs(np.linalg.norm(table[row, 1:]) - 1.0) > 1e-6:
            raise RecordingError(where, row + 3, f"not a unit quaternion (norm {np.linalg.norm(table[row, 1:]):.9g})")
    if not np.array_equal(table[:, 0], np.arange(len(table))) or (len(index) and index[-1] >= len(table)):
        raise RecordingError(
            where,
            None,
            f"its rows must number the gyro rows 0, 1, 2, … ({len(table)} rows; "
            f"the export's last used gyro row is {index[-1] if len(index) else None})",
        )
    q = table[index, 1:]
    R_nb = quat_to_dcm(q) @ M.T
    return dcm_to_euler(R_nb), meta


def load_phyphox(path, mount=DEFAULT_PHONE_MOUNT, require=("acc", "gyr")) -> Recording:
    """A phyphox CSV export (folder, .zip or one ``Raw Data.csv``) as a kit :class:`Recording`.

    mount    how the phone was held: a name in :data:`kfkit.sensors.PHONE_MOUNTS` ("flat": lying flat,
             screen up, top edge forward; "flat_landscape"; "upright") or a 3×3 rotation M_bs
    require  the sensors the lab needs ('acc', 'gyr', 'mag'); a missing one is an error saying
             which phyphox experiment records it. Sensors present beyond these are loaded too.

    The time base is the gyroscope's (the accelerometer's without a gyroscope); ``t`` is the phone's
    experiment time, s. Columns hold fixed-point counts (``meta["sensors"][s]["sensitivity"]``) in
    the phone frame and ``meta["mount"]`` maps them to the body frame FRD, so ``rec.body("gyr")`` etc.
    give rad/s, m/s², µT. Magnetometer rows without a new sample are NaN. Rows the merge cannot use
    (before the accelerometer starts, repeated timestamps, …) are counted in ``meta["phone"]``; a last row
    visibly cut short is dropped, counted, noted in ``meta["phone"]["warnings"]`` and warned about (module
    docstring). Errors name the file, line and column.
    """
    tables, device, truth_text, name = read_export(path)
    for needed in require:
        if needed not in tables:
            raise RecordingError(name, None, _missing_message(tables, needed))
    present = [k for k in ("gyr", "acc", "mag") if k in tables]
    if not present or ("gyr" not in present and "acc" not in present):
        raise RecordingError(name, None, _missing_message(tables, "acc"))
    base = "gyr" if "gyr" in present else "acc"
    clock = OneClock(
        base=base,
        interpolated=tuple(k for k in ("acc",) if k in present and k != base),
        held=tuple(k for k in ("mag",) if k in present),
    )
    for k in present:
        clock.push(k, tables[k].t, tables[k].values)
    t, values, index = clock.pop(final=True)
    if len(t) < 2:
        raise RecordingError(
            name,
            None,
            f"the {KINDS[base]} and the accelerometer do not overlap in time "
            f"({KINDS[base]} {tables[base].t[0]:.3f}–{tables[base].t[-1]:.3f} s)",
        )
    mount_name, M = phone_mount(mount)
    data = {"t": t, "seq": SampleCounter(float(np.median(np.diff(t)))).count(t) % 65536}
    for k, prefix in (("acc", "a"), ("gyr", "g"), ("mag", "m")):
        if k in present:
            counts = phone_counts(k, values[k])
            for i, axis in enumerate("xyz"):
                data[prefix + axis] = counts[:, i]
    meta = {
        "board": PHONE_BOARD,
        "rate_hz": float((len(t) - 1) / (t[-1] - t[0])),
        "source": "phone (phyphox export)",
        "units": {"t": "s (the phone's experiment time)", "sensors": "counts (see sensors.*.sensitivity)"},
        "sensors": {k: _sensor_meta(k, device) for k in present},
        "mount": {k: M.tolist() for k in present},
        "mount_name": mount_name,
        "phone": {
            "export": Path(name).name,
            "time_base": KINDS[base],
            "files": {k: tables[k].file for k in present},
            "rates_hz": {
                k: float((len(tables[k].t) - 1) / np.ptp(tables[k].t)) if len(tables[k].t) > 1 else None
                for k in present
            },
            "dt_jitter_s": float(np.std(np.diff(t))),
            "skipped": {k: tables[k].skipped for k in present},
            "merge": clock.stats,
            "device": device,
            "warnings": [w for k in present for w in tables[k].warnings],
        },
    }
    if truth_text is not None:
        text, where = truth_text
        euler, truth_meta = _truth_euler(where, text, index, M)
        for i, c in enumerate(("true_roll", "true_pitch", "true_yaw")):
            data[c] = euler[:, i]
        meta["source"] = "simulated phone (phyphox export)"
        meta["units"]["true_*"] = "rad"
        meta.update({k: truth_meta[k] for k in ("description", "phases", "sim") if k in truth_meta})
    for note in meta["phone"]["warnings"]:  # a dropped row: in the metadata and said now, as load_vehicle_csv does
        warnings.warn(note, stacklevel=2)
    return Recording(meta, data, Path(path))
