"""The kit's own file formats: load, validate, save. Foreign formats (phyphox, BROAD, a logger's CSV) are
:mod:`kfkit.readers`'; both kit formats share one header line, ``# kfkit-<kind> v1 {json}`` (:func:`parse_header`,
:func:`format_header`), and the CSV row readers.

The vehicle format (``# kfkit-vehicle v1``, lab 06: SI columns ``t,delta,yaw_rate,ay,vx`` and ``true_*``) is at the
end (:func:`load_vehicle`, :func:`save_vehicle`). The IMU recording format:

A recording is a CSV file with one header comment line holding JSON metadata, a
column-name line, then one row per sample::

    # kfkit-recording v1 {"board": "nucleo-iks02a1", "rate_hz": 104.0, "sensors": {...}, "mount": {...}, ...}
    t,seq,ax,ay,az,gx,gy,gz,mx,my,mz,true_roll,true_pitch,true_yaw
    0.000000,0,12,-35,8190,3,-2,1,,,,0.0,0.0,0.0

- ``t`` is seconds (float) from the recording's start and must increase strictly.
- Raw sensor columns hold integer counts as the board sent them; the metadata's
  ``sensors`` entry gives each sensor's sensitivity (SI per count) and ``mount`` its
  mounting matrix M_bs (body ← sensor). Magnetometer cells may be empty: no new sample.
- Simulated recordings add ``true_roll``, ``true_pitch``, ``true_yaw`` (rad); real ones with a
  reference (motion capture) too, and a ``true_*`` cell may be empty: no truth for that sample (NaN).
- Guided captures and simulations label time windows in the metadata:
  ``"phases": [{"label": "stationary", "start": 0.0, "end": 120.0}, …]`` (s, end excluded).

Loading fails with :class:`RecordingError` naming the file and line: for a header that is not the
format's, metadata without a positive finite ``rate_hz`` or without ``sensors``/``mount`` entries for the
sensor columns present, duplicate or unnamed columns, a count that is not an exact integer within ±2^53
(exact both as int64 and as float64, so no count is ever rounded), a ``seq`` outside 0 … 65535 (a 16-bit
counter), a number that is not plain ASCII decimal or is longer than :data:`MAX_NUMBER_CHARS`, time that
does not increase, and a last line without its newline (see :func:`load_recording`).
A UTF-8 byte-order mark (Excel writes one) is accepted.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .frames import mount_matrix

FORMAT_VERSION = 1  # of both kit formats: kfkit-recording (IMU boards, phones) and kfkit-vehicle (lab 06)


def magic(kind: str) -> str:
    """The start of a kit file's first line: ``# kfkit-<kind> v1 `` (then the JSON metadata)."""
    return f"# kfkit-{kind} v{FORMAT_VERSION} "


MAGIC = magic("recording")
VERSION_PREFIX = "# kfkit-"  # any kit file, of any kind and version: what readers.load_any looks for
REQUIRED_COLUMNS = ("t", "seq")
INT_COLUMNS = frozenset(
    {"seq", "ax", "ay", "az", "gx", "gy", "gz", "t_us", "static_ok"}
)  # t_us, static_ok: lab 05's logger columns
OPTIONAL_INT_COLUMNS = frozenset({"mx", "my", "mz"})  # empty cell = no new sample (NaN)
SENSOR_COLUMNS = {"acc": ("ax", "ay", "az"), "gyr": ("gx", "gy", "gz"), "mag": ("mx", "my", "mz")}
TRUTH_COLUMNS = ("true_roll", "true_pitch", "true_yaw")
BOM = "\ufeff"
#: the largest count magnitude: integers up to 2^53 are exact as int64 and as float64 (counts() and NaN-able mag
#: columns)
MAX_COUNT = 2**53
SEQ_MODULO = 2**16  # ``seq`` is the board's 16-bit sample counter: 0 … 65535
#: the longest number text read: every writer of the kit's formats writes far shorter ones (a count ≤ 2^53 has 17
#: characters, %.9g 16, a time in %.6f 24 below 10^16 s), so a longer one is a corrupted file (a megabyte of digits
#: that parses to 0.0), refused before it is parsed
MAX_NUMBER_CHARS = 64
SHOWN_CHARS = 24  # a value in a message is cut to this many characters
_INTEGER = re.compile(r"[+-]?[0-9]+")
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class RecordingError(ValueError):
    """A recording file that does not follow the format; the message names file and line."""

    def __init__(self, path, line: int | None, message: str):
        where = f"{path}" if line is None else f"{path}, line {line}"
        super().__init__(f"{where}: {message}")
        self.path, self.line = path, line


def shown(text: str, limit: int = SHOWN_CHARS) -> str:
    """``text`` quoted for a message, cut to ``limit`` characters (saying how long it is) when longer."""
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}… ({len(text):,} characters)"


def _check_length(text: str):
    if len(text) > MAX_NUMBER_CHARS:
        raise ValueError(
            f"{shown(text)} is longer than any number the file's writer produces "
            f"(≤ {MAX_NUMBER_CHARS} characters): a corrupted value?"
        )


def parse_count(text: str) -> int:
    """An integer count in ASCII decimal digits with |n| ≤ :data:`MAX_COUNT` (2^53), never through float.

    Raises ValueError saying why (callers add the file, line and column)."""
    _check_length(text)
    if not _INTEGER.fullmatch(text):
        raise ValueError(f"{shown(text)} is not an integer count")
    n = int(text)
    if abs(n) > MAX_COUNT:
        raise ValueError(f"{text} is out of range for a count (|n| ≤ 2^53 = {MAX_COUNT}): a corrupted value?")
    return n


def parse_number(text: str) -> float:
    """A finite number in plain ASCII decimal or scientific notation (``-1.5``, ``9.80665E0``).

    Stricter than ``float``, which also takes ``1_000``, non-ASCII digits, ``nan`` and ``inf``, and
    overflows ``1e999`` to inf; nor does it take more than :data:`MAX_NUMBER_CHARS` characters. Raises
    ValueError saying why."""
    _check_length(text)
    if text.lower().lstrip("+-") in ("nan", "inf", "infinity"):
        raise ValueError(f"{text!r} is not a finite number")
    if not _DECIMAL.fullmatch(text):
        raise ValueError(f"{shown(text)} is not a number")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{shown(text)} is not a finite number (beyond ±1.8e308)")
    return value


def positive_number(value) -> bool:
    """True for a JSON number (not a bool) that is finite and > 0: a rate, a sensitivity."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0


@dataclass
class Recording:
    """Metadata plus named columns (NumPy arrays, one value per sample)."""

    meta: dict
    data: dict[str, np.ndarray]
    path: Path | None = field(default=None, compare=False)

    @property
    def columns(self) -> list[str]:
        return list(self.data)

    @property
    def t(self) -> np.ndarray:
        """Sample times, s."""
        return self.data["t"]

    @property
    def rate_hz(self) -> float:
        return float(self.meta["rate_hz"])

    def __len__(self) -> int:
        return len(self.data["t"])

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[name]
        except KeyError:
            raise KeyError(
                f"recording {self.path or ''} has no column {name!r}; columns: {', '.join(self.data)}"
            ) from None

    def counts(self, sensor: str) -> np.ndarray:
        """Raw counts of ``sensor`` ('acc', 'gyr' or 'mag') as an (N, 3) array, sensor frame."""
        return np.column_stack([self[c] for c in SENSOR_COLUMNS[sensor]]).astype(float)

    def sensor_si(self, sensor: str) -> np.ndarray:
        """``sensor`` in SI units, sensor frame: counts · sensitivity, (N, 3)."""
        return self.counts(sensor) * float(self.meta["sensors"][sensor]["sensitivity"])

    def body(self, sensor: str) -> np.ndarray:
        """``sensor`` in SI units, body frame FRD: x_b = M_bs · x_s, (N, 3)."""
        return self.sensor_si(sensor) @ mount_matrix(self.meta["mount"][sensor]).T

    def truth(self) -> np.ndarray:
        """True [roll, pitch, yaw] (rad) as (N, 3); only simulated recordings have it."""
        missing = [c for c in TRUTH_COLUMNS if c not in self.data]
        if missing:
            raise KeyError(
                f"recording {self.path or ''} has no truth columns ({', '.join(missing)}): only simulated recordings do"
            )
        return np.column_stack([self.data[c] for c in TRUTH_COLUMNS])

    @property
    def phases(self) -> list[dict]:
        """Labelled windows ``{"label", "start", "end"}`` (s) from the metadata; [] if none."""
        return list(self.meta.get("phases", []))

    def phase(self, label: str) -> np.ndarray:
        """Boolean mask of the samples inside any window labelled ``label`` (start ≤ t < end)."""
        windows = [p for p in self.phases if p["label"] == label]
        if not windows:
            known = sorted({p["label"] for p in self.phases})
            raise KeyError(f"recording {self.path or ''} has no phase {label!r}; phases: {', '.join(known) or 'none'}")
        mask = np.zeros(len(self), dtype=bool)
        for w in windows:
            mask |= (self.t >= w["start"]) & (self.t < w["end"])
        return mask

    def head(self, seconds: float) -> Recording:
        """The first ``seconds`` of the recording (a new Recording sharing metadata)."""
        keep = self.t < self.t[0] + seconds
        return Recording(dict(self.meta), {k: v[keep] for k, v in self.data.items()}, self.path)


def _count_text(name: str, value) -> str:
    """A count as the loader reads it back; a fractional, non-finite or out-of-range value is an error,
    never truncated by ``int()``."""
    if not isinstance(value, (int, np.integer)) and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"column {name!r}: {value!r} is not an integer count")
    n = int(value)
    if abs(n) > MAX_COUNT:
        raise ValueError(f"column {name!r}: {n} is out of range for a count (|n| ≤ 2^53)")
    if name == "seq" and not 0 <= n < SEQ_MODULO:
        raise ValueError(
            f"column 'seq': {n} is not a 16-bit sample counter (0 … {SEQ_MODULO - 1}): take it modulo 2^16"
        )
    return str(n)


def _format_cell(name: str, value) -> str:
    if name in INT_COLUMNS:
        return _count_text(name, value)
    if name in OPTIONAL_INT_COLUMNS:
        return "" if math.isnan(value) else _count_text(name, value)
    if name == "t":
        return f"{value:.6f}"
    if name.startswith("true_") and math.isnan(value):
        return ""
    return f"{value:.9g}"


def format_header(meta: dict, columns, kind: str = "recording") -> str:
    """The two header lines (``# kfkit-<kind> v1 {json}`` and column names), newline-terminated."""
    return f"{magic(kind)}{json.dumps(meta, ensure_ascii=False)}\n{','.join(columns)}\n"


def format_row(columns, values) -> str:
    """One CSV row, newline-terminated, in the format's number formatting."""
    return ",".join(_format_cell(c, v) for c, v in zip(columns, values)) + "\n"


def recording_text(rec: Recording) -> str:
    """The file contents of ``rec`` in the recording format (deterministic text)."""
    cols = rec.columns
    rows = zip(*(rec.data[c].tolist() for c in cols))
    return format_header(rec.meta, cols) + "".join(format_row(cols, row) for row in rows)


def save_recording(rec: Recording, path) -> Path:
    """Write ``rec`` to ``path`` in the recording format."""
    path = Path(path)
    path.write_text(recording_text(rec), encoding="utf-8", newline="\n")
    return path


def parse_header(path, line: str, kind: str = "recording", hint: str = "", needs_rate: bool = True) -> dict:
    """The metadata of a kit file's first line ``# kfkit-<kind> v1 {json}``: a JSON object with valid ``phases`` and
    (``needs_rate``) a positive finite ``rate_hz``. A file of another kind or version, or bad JSON, is a RecordingError
    on line 1 (``hint``: what to do instead, for a file that is not the kit's at all)."""
    expected = magic(kind)
    if not line.startswith(f"# kfkit-{kind} "):
        shown = line[:60].rstrip("\n")
        raise RecordingError(
            path,
            1,
            f"expected the header '{expected.strip()} {{…json…}}', got {shown!r}: is this a "
            f"kfkit {kind}?{' ' + hint if hint else ''}",
        )
    if not line.startswith(expected):
        version = line[len(f"# kfkit-{kind} ") :].split(" ", 1)[0]
        raise RecordingError(path, 1, f"unsupported {kind} version {version!r}; this kfkit reads v{FORMAT_VERSION}")
    try:
        meta = json.loads(line[len(expected) :])
    except json.JSONDecodeError as e:
        raise RecordingError(
            path, 1, f"the metadata is not valid JSON ({e.msg} at column {e.colno + len(expected)})"
        ) from None
    if not isinstance(meta, dict) or (needs_rate and "rate_hz" not in meta):
        raise RecordingError(
            path, 1, "the metadata must be a JSON object" + (" with at least 'rate_hz'" if needs_rate else "")
        )
    if needs_rate and not positive_number(meta["rate_hz"]):
        raise RecordingError(
            path, 1, f"metadata 'rate_hz' must be a positive finite number (Hz), got {meta['rate_hz']!r}"
        )
    check_phases(path, meta.get("phases", []))
    return meta


def _check_meta(path, meta: dict, cols) -> None:
    """What :class:`Recording`'s helpers read from the metadata, for the sensors whose columns are present:
    ``sensors[s]["sensitivity"]`` > 0 (SI per count) and ``mount[s]`` a rotation; ``phases`` windows."""
    present = [s for s, names in SENSOR_COLUMNS.items() if any(c in cols for c in names)]
    for key in ("sensors", "mount"):
        if present and not isinstance(meta.get(key), dict):
            raise RecordingError(
                path,
                1,
                f"the metadata has no {key!r} object, but the file has columns of "
                f"{', '.join(present)}: each needs its {'sensitivity' if key == 'sensors' else 'mounting matrix'}",
            )
    for s in present:
        spec = meta["sensors"].get(s)
        if not isinstance(spec, dict) or not positive_number(spec.get("sensitivity")):
            got = spec.get("sensitivity") if isinstance(spec, dict) else spec
            raise RecordingError(
                path,
                1,
                f"metadata sensors.{s}.sensitivity must be a positive finite number (SI units per count), got {got!r}",
            )
        try:
            mount_matrix(meta["mount"].get(s))
        except (ValueError, TypeError):
            raise RecordingError(
                path,
                1,
                f"metadata mount.{s} must be a 3×3 rotation matrix M_bs (body ← sensor; "
                f"orthonormal, det +1), got {meta['mount'].get(s)!r}",
            ) from None


def check_phases(path, phases, line=1) -> None:
    """Labelled windows must be a list of ``{"label": text, "start": s, "end": s}``, start < end, finite."""
    if not isinstance(phases, list):
        raise RecordingError(path, line, f"metadata 'phases' must be a list of {{label, start, end}}, got {phases!r}")
    for i, p in enumerate(phases):
        ok = (
            isinstance(p, dict)
            and isinstance(p.get("label"), str)
            and all(
                isinstance(p.get(k), (int, float)) and not isinstance(p.get(k), bool) and math.isfinite(p[k])
                for k in ("start", "end")
            )
            and p["start"] < p["end"]
        )
        if not ok:
            raise RecordingError(
                path,
                line,
                f'metadata phases[{i}] must be {{"label": text, "start": s, "end": s}} with start < end, got {p!r}',
            )


def _parse_columns(path, line: str) -> list[str]:
    cols = [c.strip() for c in line.rstrip("\r\n").split(",")]
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]
    if missing or not line.strip():
        raise RecordingError(
            path, 2, f"the column line must name at least {', '.join(REQUIRED_COLUMNS)}; got {line.strip()!r}"
        )
    dupes = sorted({c for c in cols if cols.count(c) > 1})
    if dupes:
        raise RecordingError(path, 2, f"duplicate column names: {', '.join(dupes)}")
    if "" in cols:
        raise RecordingError(
            path, 2, f"column {cols.index('') + 1} has no name (two commas in a row, or one at the end?)"
        )
    return cols


def _parse_cell(path, lineno: int, col: str, text: str):
    if text == "" and (col in OPTIONAL_INT_COLUMNS or col.startswith("true_")):
        return math.nan
    try:
        value = parse_count(text) if col in INT_COLUMNS or col in OPTIONAL_INT_COLUMNS else parse_number(text)
    except ValueError as e:
        raise RecordingError(path, lineno, f"column {col!r}: {e}") from None
    if col == "seq" and not 0 <= value < SEQ_MODULO:
        raise RecordingError(
            path,
            lineno,
            f"column 'seq': {value} is not a sample counter: seq counts the board's "
            f"samples modulo 2^16, 0 … {SEQ_MODULO - 1}",
        )
    return value


def load_recording(path) -> Recording:
    """Read and validate a recording; raises :class:`RecordingError` naming file and line.

    A last line without its newline is rejected, not dropped: every writer of this format ends each
    row with one, so its absence means the capture was interrupted mid-line and the line may hold a
    number cut short (``-1234`` cut to ``-12`` still parses). The message says to delete that line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"no recording at {path}") from None
    except UnicodeDecodeError as e:
        raise RecordingError(path, None, f"not a text file ({e.reason} at byte {e.start})") from None
    text = text.removeprefix(BOM)  # Excel's "CSV UTF-8" starts with one
    lines = text.split("\n")
    if len(lines) < 2 or not lines[0]:
        raise RecordingError(path, 1, "the file is empty: expected a metadata header line")
    meta = parse_header(path, lines[0])
    cols = _parse_columns(path, lines[1])
    _check_meta(path, meta, cols)
    truncated_tail = not text.endswith("\n")
    rows = lines[2:] if truncated_tail else lines[2:-1]
    while rows and not truncated_tail and not rows[-1].strip():
        rows.pop()  # blank lines at the end (a hand-edited file) carry no samples
    columns: list[list] = [[] for _ in cols]
    t_col, t_prev = cols.index("t"), None
    for i, raw in enumerate(rows):
        lineno = i + 3
        if truncated_tail and i == len(rows) - 1:
            # Every writer ends a row with a newline: without one, even a full field count may hide a cut number.
            raise RecordingError(
                path,
                lineno,
                f"the last line is cut short (no newline at the end): the capture was "
                f"probably interrupted; the {i} rows before it are complete: delete this line to load them",
            )
        cells = raw.rstrip("\r").split(",")
        if len(cells) != len(cols):
            raise RecordingError(path, lineno, f"expected {len(cols)} fields ({','.join(cols)}), got {len(cells)}")
        values = [_parse_cell(path, lineno, c, s.strip()) for c, s in zip(cols, cells)]
        for column, v in zip(columns, values):
            column.append(v)
        t = values[t_col]
        if t_prev is not None and t <= t_prev:
            raise RecordingError(path, lineno, f"time does not increase: t = {t} s after t = {t_prev} s")
        t_prev = t
    if not rows:
        raise RecordingError(path, 3, "the recording holds no samples")
    data = {}
    for c, column in zip(cols, columns):
        dtype = np.int64 if c in INT_COLUMNS else float
        data[c] = np.asarray(column, dtype=dtype)
    return Recording(meta, data, path)


# --- the kit's vehicle recording format (and the row reader students' CSVs share) ---------------------------------

VEHICLE_MAGIC = magic("vehicle")
VEHICLE_COLUMNS = ("t", "delta", "yaw_rate", "ay", "vx")
VEHICLE_TRUTH = ("true_beta", "true_yaw_rate", "true_vy")


def vehicle_text(rec: Recording) -> str:
    """The file contents of a vehicle recording: ``# kfkit-vehicle v1 {json}``, column names, rows."""
    cols = rec.columns
    fmt = ["{:.6f}" if c == "t" else "{:.9g}" for c in cols]
    rows = zip(*(rec.data[c].tolist() for c in cols))
    lines = [",".join(f.format(v + 0.0) for f, v in zip(fmt, row)) for row in rows]  # + 0.0 writes −0 as 0
    return format_header(rec.meta, cols, "vehicle") + "".join(line + "\n" for line in lines)


def save_vehicle(rec: Recording, path) -> Path:
    """Write a vehicle recording to ``path``."""
    path = Path(path)
    path.write_text(vehicle_text(rec), encoding="utf-8", newline="\n")
    return path


def read_csv_rows(path, lines, first_lineno, header, columns, delimiter=","):
    """Parse CSV ``lines`` (after the header) into arrays for ``columns`` {kit name: file column}, in the file's units.

    Returns (data, line numbers of the rows). Errors name the file, the line and the column.
    """
    index = {}
    for name, col in columns.items():
        if col not in header:
            raise RecordingError(
                path, first_lineno - 1, f"no column {col!r} for {name} (columns in the file: {', '.join(header)})"
            )
        if header.count(col) > 1:
            raise RecordingError(
                path, first_lineno - 1, f"column {col!r} (for {name}) appears {header.count(col)} times in the header"
            )
        index[name] = header.index(col)
    values = {name: [] for name in columns}
    linenos = []
    t_prev = None
    for offset, cells in enumerate(csv_rows(path, lines, first_lineno, delimiter)):
        lineno = first_lineno + offset
        if not cells or all(not c.strip() for c in cells):
            continue
        # a trailing delimiter (spreadsheet exports) adds empty cells: allowed; anything else must match the header
        if len(cells) < len(header) or any(c.strip() for c in cells[len(header) :]):
            raise RecordingError(
                path, lineno, f"expected {len(header)} fields ({delimiter.join(header)}), got {len(cells)}"
            )
        for name, i in index.items():
            text = cells[i].strip()
            try:
                values[name].append(parse_number(text))
            except ValueError as e:
                raise RecordingError(
                    path, lineno, f"column {header[i]!r} ({name}): {'is empty' if not text else e}"
                ) from None
        t = values["t"][-1]
        if t_prev is not None and t <= t_prev:
            raise RecordingError(
                path, lineno, f"time (column {header[index['t']]!r}) does not increase: {t:.10g} after {t_prev:.10g}"
            )
        t_prev = t
        linenos.append(lineno)
    if t_prev is None:
        raise RecordingError(path, first_lineno, "no data rows")
    return {name: np.asarray(v) for name, v in values.items()}, np.asarray(linenos)


def csv_rows(path, lines, first_lineno, delimiter=","):
    """The cells of each of ``lines`` (one row per line) as :func:`csv.reader` splits them; what it cannot read (a field
    over its limit of 131,072 characters, a NUL byte) is a RecordingError naming the file and line."""
    reader = csv.reader(lines, delimiter=delimiter)
    while True:
        try:
            cells = next(reader)
        except StopIteration:
            return
        except csv.Error as e:
            raise RecordingError(
                path,
                first_lineno + reader.line_num - 1,
                f"not readable as CSV ({e}): no number is that long or holds such a character; a corrupted file?",
            ) from None
        yield cells


def read_lines(path) -> tuple[list[str], bool]:
    """The file's lines (a UTF-8 byte-order mark dropped) and whether the last one ends in a newline."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise FileNotFoundError(f"no file at {path}") from None
    except UnicodeDecodeError as e:
        raise RecordingError(path, None, f"not a text file ({e.reason} at byte {e.start})") from None
    return text.splitlines(), text.endswith(("\n", "\r"))


def load_vehicle(path) -> Recording:
    """Read a vehicle recording (``# kfkit-vehicle v1`` format); errors name the file and line.

    The kit writes every line with its newline, so a last line without one is rejected (a copy cut
    short may have cut a number in it: ``0.0123`` to ``0.01`` still parses)."""
    path = Path(path)
    lines, terminated = read_lines(path)
    meta = parse_header(
        path,
        lines[0] if lines else "",
        "vehicle",
        hint="For your own CSV use kfkit.readers.load_vehicle_csv(path, columns=…, units=…).",
    )
    if len(lines) < 2:
        raise RecordingError(path, 2, "no column-name line")
    if not terminated and len(lines) > 2:
        raise RecordingError(
            path,
            len(lines),
            "the last line is cut short (no newline at the end): the file was "
            "probably copied or written incompletely; delete this line to load the rows before it",
        )
    header = [c.strip() for c in lines[1].split(",")]
    dupes = sorted({c for c in header if header.count(c) > 1})
    if dupes:
        raise RecordingError(path, 2, f"duplicate column names: {', '.join(dupes)}")
    wanted = [c for c in VEHICLE_COLUMNS + VEHICLE_TRUTH if c in header or c in VEHICLE_COLUMNS]
    data, _ = read_csv_rows(path, lines[2:], 3, header, {c: c for c in wanted})
    return Recording(meta, data, path)
