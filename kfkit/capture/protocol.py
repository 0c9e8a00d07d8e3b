"""Serial protocol v1 (board → host): parse and encode one line.

ASCII lines, ``\\n``-terminated (a ``\\r`` before it is ignored)::

    #KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250
    $123456,42,-120,35,16390,12,-8,3*2D

- ``#KFKIT,<version>,key=value,…`` is the metadata header (sent at start and on ``h``);
  ``board``, ``rate_hz`` and ``fields`` (``|``-separated, starting ``t_us|seq``) are required.
  An optional ``*HH`` at its end is checked like a sample's.
- ``$v0,v1,…*HH`` is a sample: integers in the header's ``fields`` order; ``HH`` (upper-case hex) is the
  XOR of every byte between ``$`` and ``*`` (NMEA 0183 style). ``t_us`` is the board's
  32-bit ``micros()``, ``seq`` a 16-bit counter that wraps at 65536.
- Integer range (the firmware's types, ``kfkit_protocol.h``): 0 ≤ ``t_us`` < 2³² (uint32),
  0 ≤ ``seq`` < 2¹⁶ (uint16), every other field −2³¹ ≤ v < 2³¹ (int32), written as an optional ``-``
  and decimal digits. A field outside its range is a malformed line (counted and skipped, like any
  bad line): every accepted value is exact in float64 and int64, so what the recorder streams and what
  its final file holds are the same numbers.
- ``$TAG,f1,f2,…*HH`` (first field starts with a letter) is a tagged message, e.g. the tilt
  firmware's ``$ATT,roll_deg,pitch_deg*HH``; decoders for tags live in :data:`MESSAGE_DECODERS`.
- Other ``#`` lines are notes (``#ERROR,ISM330DHCX not found`` from a sketch that failed).

Host → board: single characters, ``h`` (send the header) and ``s`` (start/stop streaming).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import reduce
from operator import xor

import numpy as np

VERSION = 1
HEADER_PREFIX = b"#KFKIT,"
REQUIRED_HEADER_KEYS = ("board", "rate_hz", "fields")
TIME_FIELDS = ("t_us", "seq")
SEQ_MODULO = 1 << 16
MICROS_MODULO = 1 << 32
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1  # a sample's fields after t_us and seq
_INTEGER_BYTES = b"0123456789-,"  # all a sample body may hold (no '+', spaces or '_', which int() would take)


@dataclass(frozen=True)
class Header:
    """A ``#KFKIT`` metadata line. ``params`` holds every key=value as text."""

    version: int
    board: str
    rate_hz: float
    fields: tuple
    params: dict = field(default_factory=dict)
    text: str = ""


class Sample(tuple):
    """A ``$`` sample line: the tuple of its integers in the header's ``fields`` order.

    A tuple subclass (not a dataclass) because the reader makes one per line: it is cheaper.
    """

    __slots__ = ()

    @property
    def values(self) -> tuple:
        return tuple(self)

    @property
    def t_us(self) -> int:
        return self[0]

    @property
    def seq(self) -> int:
        return self[1]

    def __repr__(self):
        return f"Sample({tuple(self)})"


@dataclass(frozen=True)
class Message:
    """A tagged ``$TAG,…*HH`` line; ``values`` is decoded by :data:`MESSAGE_DECODERS` if known."""

    tag: str
    values: tuple


@dataclass(frozen=True)
class Note:
    """A ``#`` line that is not a header (e.g. ``#ERROR,…`` from a sketch)."""

    text: str


@dataclass(frozen=True)
class BadLine:
    """A line the host rejects. ``kind`` is one of :data:`BAD_KINDS`; ``detail`` says why."""

    kind: str
    detail: str
    line: bytes = b""


#: "checksum": the ``*HH`` does not match; "malformed": not a protocol line, no ``*HH``,
#: non-integer or missing fields; "version": a ``#KFKIT`` header of another protocol version;
#: "empty": a blank line (ignored, not counted).
BAD_KINDS = ("checksum", "malformed", "version", "empty")

#: tag → function(list of field strings) → tuple; unknown tags keep their text fields.
MESSAGE_DECODERS = {
    "ATT": lambda fields: tuple(float(f) for f in fields),  # $ATT,roll_deg,pitch_deg (tilt firmware)
}


_HEX = {b"%02X" % i: i for i in range(256)}  # "*HH": upper case only, as the sketches send


def checksum(body: bytes) -> int:
    """XOR of every byte of ``body`` (the text between ``$``/``#`` and ``*``)."""
    return reduce(xor, body, 0)


def _split_checksum(line: bytes):
    """(body, None) without ``*HH``; (body, ok) with; raises ValueError if HH is not hex."""
    star = line.rfind(b"*")
    if star < 0:
        return line[1:], None
    body, wanted = line[1:star], _HEX.get(line[star + 1 :])
    if wanted is None:
        raise ValueError("the checksum after '*' must be two upper-case hex digits")
    return body, checksum(body) == wanted


def parse_line(line: bytes):
    """Parse one line (bytes, with or without its newline).

    Returns a :class:`Header`, :class:`Sample`, :class:`Message`, :class:`Note`, or a
    :class:`BadLine` whose ``kind`` is ``"checksum"``, ``"malformed"``, ``"version"`` or
    ``"empty"``. Never raises on bad input.
    """
    line = line.strip()
    if not line:
        return BadLine("empty", "blank line", line)
    first = line[0]
    if first == 0x24:  # "$"
        star = line.rfind(b"*")
        if star < 0 or len(line) - star != 3:
            return BadLine("malformed", "a sample line must end in *HH (two hex digits)", line)
        body = line[1:star]
        wanted = _HEX.get(line[star + 1 :])
        if wanted is None:
            return BadLine("malformed", "the checksum after '*' is not two upper-case hex digits", line)
        got = reduce(xor, body, 0)
        if got != wanted:
            return BadLine("checksum", f"checksum {got:02X} computed, {wanted:02X} sent", line)
        parts = body.split(b",")
        if parts[0][:1].isalpha():
            return _message(parts, line)
        try:
            if body.translate(None, _INTEGER_BYTES):
                raise ValueError
            values = Sample(map(int, parts))
        except ValueError:
            return BadLine("malformed", "a field is not an integer", line)
        if len(values) < 2:
            return BadLine("malformed", "a sample needs at least t_us and seq", line)
        if values[0] >> 32 or values[1] >> 16:  # non-zero for a negative value too
            return BadLine(
                "malformed", f"t_us must be in [0, 2^32) and seq in [0, 2^16), got {values[0]}, {values[1]}", line
            )
        if len(values) > 2 and (min(values[2:]) < INT32_MIN or max(values[2:]) > INT32_MAX):
            return BadLine("malformed", "a field is outside the protocol's int32 range [-2^31, 2^31)", line)
        return values
    if first == 0x23:  # "#"
        if line.startswith(HEADER_PREFIX):
            return _header(line)
        return Note(line[1:].decode("ascii", "replace"))
    return BadLine("malformed", "not a protocol line (starts with neither '$' nor '#')", line)


def _message(parts, line):
    tag = parts[0].decode("ascii", "replace")
    fields = [p.decode("ascii", "replace") for p in parts[1:]]
    decode = MESSAGE_DECODERS.get(tag)
    if decode is None:
        return Message(tag, tuple(fields))
    try:
        return Message(tag, decode(fields))
    except ValueError:
        return BadLine("malformed", f"the fields of a ${tag} line do not decode", line)


def _header(line: bytes):
    try:
        body, ok = _split_checksum(line)
        text = body.decode("ascii")
    except (ValueError, UnicodeDecodeError) as e:
        return BadLine("malformed", f"unreadable header ({e})", line)
    if ok is False:
        return BadLine("checksum", "header checksum does not match", line)
    parts = text.split(",")
    try:
        version = int(parts[1])
    except (IndexError, ValueError):
        return BadLine("malformed", "the header must start '#KFKIT,<version>,'", line)
    if version != VERSION:
        return BadLine("version", f"protocol version {version}; this kfkit reads version {VERSION}", line)
    params = dict(p.split("=", 1) for p in parts[2:] if "=" in p)
    missing = [k for k in REQUIRED_HEADER_KEYS if k not in params]
    if missing:
        return BadLine("malformed", f"the header lacks {', '.join(missing)}", line)
    fields = tuple(params["fields"].split("|"))
    if fields[:2] != TIME_FIELDS:
        return BadLine("malformed", f"fields must start with t_us|seq, got {params['fields']}", line)
    try:
        rate = float(params["rate_hz"])
    except ValueError:
        rate = float("nan")
    if not (0.0 < rate < float("inf")):
        return BadLine("malformed", f"rate_hz={params['rate_hz']} is not a positive number", line)
    return Header(version, params["board"], rate, fields, params, text)


def board_time(t_us):
    """Seconds from the first sample, from 32-bit ``micros()`` stamps that wrap every 2³² µs (71.6 min).

    t_k = Σ_{i≤k} ((t_us[i] − t_us[i−1]) mod 2³²) · 10⁻⁶,  t_0 = 0 (no board reset in between).
    """
    t_us = np.asarray(t_us, dtype=np.int64)
    steps = np.diff(t_us) % MICROS_MODULO
    return np.concatenate([[0.0], np.cumsum(steps) * 1e-6])


def encode_sample(values) -> bytes:
    """``$v0,v1,…*HH\\n`` for integer ``values``."""
    body = ",".join(str(int(v)) for v in values).encode("ascii")
    return b"$%s*%02X\n" % (body, checksum(body))


def encode_message(tag: str, values, fmt="{:.2f}") -> bytes:
    """``$TAG,f1,…*HH\\n`` (floats formatted with ``fmt``)."""
    body = ",".join([tag, *(fmt.format(v) for v in values)]).encode("ascii")
    return b"$%s*%02X\n" % (body, checksum(body))


def encode_header(board: str, rate_hz: float, fields, version: int = VERSION, **params) -> bytes:
    """``#KFKIT,1,board=…,rate_hz=…,fields=a|b|…,key=value…\\n`` (no checksum, as the sketches send)."""
    items = [f"board={board}", f"rate_hz={rate_hz:g}", "fields=" + "|".join(fields)]
    items += [f"{k}={v}" for k, v in params.items()]
    return ("#KFKIT," + ",".join([str(version), *items]) + "\n").encode("ascii")
