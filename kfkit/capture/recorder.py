"""Recording from a port: a reader thread, statistics, the streamed file, snapshots.

The reader thread only reads bytes, parses lines, appends rows under a lock and streams them
to the output file (flushed every ``flush_s``, ≤ 1 s), so a board unplugged mid-capture leaves
every received sample on disk. Live views poll :meth:`Recorder.recording` from their own
(main-thread) timer; nothing on the reader thread plots.

Time, drops and resets: :class:`kfkit.capture.timeline.Timeline` places each sample in board time
(``t_us`` unwrapped, relative to the first sample) and counts ``seq`` gaps and board resets; the
reader thread only feeds it.

A port is a device path, a pyserial URL, ``phyphox://…`` or a *board object* that serves a port:
anything with ``start()`` (returns itself; ``port`` is then what to open), ``close()``, ``description``,
``source`` (the recording's metadata "source"), ``phases`` (labelled windows of what it plays, or
[]) and optionally ``error`` (the exception that stopped it, None while it runs).
:class:`kfkit.capture.virtual.VirtualBoard` is one; a name of :data:`kfkit.capture.ports.NAMED_PORTS`
("virtual") makes a new one.

Magnetometer: the Nucleo sketch sends ``mx,my,mz`` on every line (the last reading repeated) and
a last field ``mag_new`` (1 = a new reading, 0 = a repeat); rows with ``mag_new = 0`` get NaN
magnetometer cells, the recording format's "no new sample".
"""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path

import numpy as np

from .. import sensors
from ..filters.contract import require_positive
from ..io import INT_COLUMNS, Recording, format_header, format_row, save_recording
from .errors import BoardDisconnectedError, CaptureError, NoDataError, ProtocolVersionError, WrongBaudError
from .ports import NAMED_PORTS, SKETCHES, open_port, resolve_auto
from .protocol import BadLine, Header, Message, Note, Sample, parse_line
from .timeline import CaptureStats, Timeline

DEFAULT_BAUD = 115200
MAX_LINE_BYTES = 1024  # no newline in this many bytes: noise (a wrong baud rate), not a line
MAG_FLAG = "mag_new"  # Nucleo sketch: 1 = mx,my,mz is a new reading, 0 = the last one repeated
_SPEC_AT_RANGE = {  # chip → (accel spec at ±g, gyro spec at ±°/s), for headers that name a range
    "ISM330DHCX": (sensors.ism330dhcx_accel, sensors.ism330dhcx_gyro),
    "MPU6050": (sensors.mpu6050_accel, sensors.mpu6050_gyro),
}


def header_metadata(header: Header) -> dict:
    """Recording metadata from a board header: sensitivities and mounts from ``kfkit.sensors``."""
    meta = {
        "board": header.board,
        "rate_hz": header.rate_hz,
        "source": "capture",
        "units": {"t": "s", "sensors": "counts (see sensors.*.sensitivity)"},
        "protocol": {"version": header.version, "header": "#" + header.text},
    }
    try:
        b = sensors.board(header.board)
    except ValueError:
        meta["note"] = f"board {header.board!r} is not in kfkit.sensors.BOARDS: counts have no sensitivities"
        return meta
    acc, gyr = b.accel, b.gyro
    ranges = _SPEC_AT_RANGE.get(acc.chip)
    try:
        if ranges and "accel_fs_g" in header.params:
            acc = ranges[0](int(header.params["accel_fs_g"]))
        if ranges and "gyro_fs_dps" in header.params:
            gyr = ranges[1](int(header.params["gyro_fs_dps"]))
    except (KeyError, ValueError):
        raise CaptureError(f"the board header names a range kfkit does not know: {header.text}") from None
    specs = {"acc": acc, "gyr": gyr}
    if b.mag is not None and "mx" in header.fields:
        specs["mag"] = b.mag
    meta["sensors"] = {k: s.metadata() for k, s in specs.items()}
    meta["mount"] = {k: b.mount[k] for k in specs}
    if "mag_rate_hz" in header.params:
        meta["mag_rate_hz"] = float(header.params["mag_rate_hz"])
    return meta


def _columns(header: Header) -> list[str]:
    """Recording columns for a header: t, seq, then its sensor fields (t_us and mag_new are consumed)."""
    return ["t", "seq", *(f for f in header.fields[2:] if f != MAG_FLAG)]


class Recorder:
    """Record from ``port`` on a reader thread; a context manager (``start``/``stop``).

    port      device path, pyserial URL (loop://, socket://host:port, hwgrep://0483:374B),
              phyphox://HOST:PORT, "auto" (the single detected board), "virtual" (a new
              :class:`VirtualBoard` built from ``virtual=dict(...)``; any name of ``NAMED_PORTS``) or a board
              object (module docstring)
    out       recording file streamed as samples arrive, rewritten with the final metadata
              (statistics, phases) by ``stop()``
    baud      the port's baud rate, a whole number > 0
    seconds   stop by itself once this much board time (s) has arrived, a finite number > 0 (None: until stop())
    phases    labelled windows [{"label", "start", "end"}] for the metadata; a board object's
              ``phases`` (a virtual board playing a motion with phases) by default
    no_data_s NoDataError when nothing valid arrives this long (s): at the start (no sketch,
              no samples after the header) or mid-capture (the board stopped sending)
    garbage_s WrongBaudError when ≥ 90 % of what arrived in this long (s) is not protocol v1
    flush_s   the streamed file is flushed at least this often (s, at most 1)

    Errors are :class:`CaptureError` subclasses saying what to do; one that ends a capture after
    samples arrived also says where they are saved.
    """

    def __init__(
        self,
        port="auto",
        baud=DEFAULT_BAUD,
        out=None,
        *,
        seconds=None,
        phases=None,
        virtual=None,
        request_header=True,
        no_data_s=3.0,
        garbage_s=2.0,
        flush_s=0.5,
        read_timeout=0.05,
    ):
        require_positive(
            "Recorder",
            none_ok=("seconds",),
            seconds=seconds,
            no_data_s=no_data_s,
            garbage_s=garbage_s,
            flush_s=flush_s,
            read_timeout=read_timeout,
        )
        if isinstance(baud, bool) or not isinstance(baud, (int, np.integer)) or baud <= 0:
            raise ValueError(f"Recorder: baud must be a whole number > 0, got {baud!r}")
        self.port, self.baud, self.seconds = port, int(baud), seconds
        self.out = Path(out).resolve() if out is not None else None
        self.phases = list(phases) if phases is not None else None
        self.virtual_options = dict(virtual or {})
        self.request_header, self.no_data_s, self.garbage_s = request_header, no_data_s, garbage_s
        self.flush_s, self.read_timeout = min(flush_s, 1.0), read_timeout
        self.board = None  # the board object started or given, if any
        self._own_board = False
        self.stats = CaptureStats()
        self.header: Header | None = None
        self.meta: dict | None = None
        self.columns: list[str] = []
        self.messages: dict[str, list] = {}  # tag → [(sample index, values)]
        self.error: CaptureError | None = None
        self.description = ""
        self.device = port  # what was opened (a resolved "auto" or the virtual board's pty) once start() ran
        self.opened = False  # the port was opened (statistics mean something)
        self._rows: list[tuple] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.done = threading.Event()  # set when the reader thread ends (stop, seconds reached, error)
        self._thread = None
        self._serial = None
        self._file = None
        self.timeline: Timeline | None = None  # from the first header on
        self._mag_index = None

    # -- life cycle --------------------------------------------------------------------------------
    def start(self) -> Recorder:
        if self._thread is not None:
            raise CaptureError("this Recorder has already been started; make a new one for a new capture")
        port = self.port
        if isinstance(port, str) and port in NAMED_PORTS:
            port, self._own_board = NAMED_PORTS[port].make(**self.virtual_options), True
        if not isinstance(port, str):  # a board object: start it (unless running) and open the port it serves
            self.board = port
            if self.board.port is None:
                self.board.start()
                self._own_board = True
            if self.phases is None:
                self.phases = list(self.board.phases) or None
            self.description = self.board.description
            port = self.board.port
        elif port == "auto":
            found, why = resolve_auto()
            port, self.description = found.port, why
        else:
            self.description = str(port)
        self.device = port
        try:
            self._serial = open_port(port, self.baud, self.read_timeout)
        except BaseException:
            self._close_board()
            raise
        self.opened = True
        if self.request_header:
            self._serial.write(b"h")
        self._t_open = time.monotonic()
        self._thread = threading.Thread(target=self._read_loop, name=f"kfkit-recorder {port}", daemon=True)
        self._thread.start()
        return self

    def stop(self, raise_error=True) -> CaptureStats:
        """Stop reading, close the port, write the final file; raise the capture's error if any."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)
        if self._serial is not None:
            self._serial.close()
            self._serial = None
        self._close_board()
        if self.timeline is not None:
            self.timeline.summarise()
        self._finish_file()
        if raise_error and self.error is not None:
            raise self.error
        return self.stats

    def run(self, progress=None) -> Recording:
        """Start, call ``progress(fraction, self)`` about ten times a second (fraction of ``seconds`` of board
        time), stop when the capture ends, and return the Recording; raises the capture's error (its statistics
        stay in ``self.stats``, what arrived in ``self.out``)."""
        with self:
            while not self.wait(0.1):
                if progress is not None:
                    progress(min(self.elapsed / self.seconds, 1.0) if self.seconds else 0.0, self)
            if progress is not None and self.error is None:
                progress(1.0, self)
        return self.recording()

    def _close_board(self):
        if self._own_board and self.board is not None:
            self.board.close()

    def wait(self, timeout=None) -> bool:
        """Wait until the reader ends (``seconds`` reached or an error); True if it ended."""
        return self.done.wait(timeout)

    def check(self):
        """Raise the capture's error now, if one happened (for polling loops)."""
        if self.error is not None:
            raise self.error

    def __enter__(self):
        return self.start()

    def __exit__(self, exc_type, *exc):
        self.stop(raise_error=exc_type is None)

    @property
    def elapsed(self) -> float:
        """Board time received so far, s."""
        return self.timeline.elapsed if self.timeline is not None else 0.0

    # -- the reader thread ----------------------------------------------------------------------------
    def _read_loop(self):
        ser, buf = self._serial, b""
        tail = True  # the first piece may be the end of a line the board was already sending
        discarding = False  # inside a run of bytes without a newline, already counted once
        last_flush = last_data = time.monotonic()
        try:
            while not self._stop.is_set():
                try:
                    data = ser.read(max(1, ser.in_waiting))
                except CaptureError as e:  # a port that knows what went wrong (a phone: kfkit.capture.phyphox_http)
                    self._fail(type(e), str(e))
                    break
                except Exception as e:  # SerialException/OSError: the device went away
                    failed = getattr(
                        self.board, "error", None
                    )  # a board object that stopped on an error closes its port
                    if failed is not None:
                        self._fail(
                            CaptureError,
                            f"{self.description} stopped on an error ({type(failed).__name__}: "
                            f"{failed}); please report it",
                        )
                    else:
                        self._fail(BoardDisconnectedError, f"the board disconnected ({self.device}: {e})")
                    break
                now = time.monotonic()
                if data:
                    last_data = now
                    self.stats.bytes += len(data)
                    lines = (buf + data).split(b"\n")
                    buf = lines.pop()
                    discarding = discarding and not lines
                    for line in lines:
                        if tail:  # use it only if it is a whole line: parse, do not count
                            tail = False
                            item = parse_line(line)
                            if isinstance(item, BadLine) and item.kind != "version":
                                continue
                        self._handle(line)
                        if self._over():
                            break
                    if len(buf) > MAX_LINE_BYTES:  # far longer than any line: noise, counted once per run
                        self.stats.malformed += not discarding
                        buf, tail, discarding = b"", True, True
                    if self._over():
                        break
                if self.header is None or self.stats.samples == 0:
                    self._check_startup(now - self._t_open)
                elif now - last_data >= self.no_data_s:
                    self._fail(
                        NoDataError,
                        f"{self.device}: the board stopped sending {now - last_data:.1f} s ago, "
                        f"after {self.stats.samples} samples{self._notes()}: a loose cable, a crashed "
                        f"sketch or another program that took the port",
                    )
                if self.error is not None:
                    break
                if self._file is not None and now - last_flush >= self.flush_s:
                    self._file.flush()
                    last_flush = now
        except Exception as e:  # a bug must not end a capture silently: say so, keep what arrived
            self._fail(
                CaptureError,
                f"{self.device}: the recorder stopped on an unexpected error ({e!r}); please report it with the file",
            )
        finally:
            if self._file is not None:
                self._file.flush()
            self.done.set()

    def _fail(self, kind, message):
        if self.error is None:
            self.error = kind(message)

    def _over(self) -> bool:
        return self.error is not None or (self.timeline is not None and self.timeline.reached)

    def _check_startup(self, waited):
        s = self.stats
        valid = s.samples + s.before_header + (self.header is not None) + len(s.notes)  # a '#' note is protocol v1
        if waited >= self.garbage_s and s.bytes >= 20 and valid <= 0.1 * (valid + s.bad_lines):
            hint = (
                "check Serial.begin(...) in the sketch"
                if self.baud == DEFAULT_BAUD
                else f"pass baud={DEFAULT_BAUD} (kfkit capture --baud {DEFAULT_BAUD})"
            )
            self._fail(
                WrongBaudError,
                f"{self.device}: {s.bytes} bytes in {waited:.1f} s but no valid protocol line, "
                f"which is what a wrong baud rate looks like: kfkit sketches send at {DEFAULT_BAUD} baud and "
                f"this port is open at {self.baud}; {hint}",
            )
        elif waited >= self.no_data_s and s.before_header and self.header is None:
            self._fail(
                CaptureError,
                f"{self.device}: {s.before_header} samples but no #KFKIT header in {waited:.1f} s, "
                f"although 'h' was sent: is the sketch from this kit ({SKETCHES})?",
            )
        elif waited >= self.no_data_s and self.header is not None and s.samples == 0:
            self._fail(
                NoDataError,
                f"{self.device}: the board sent its header but no samples in {waited:.1f} s: "
                f"it may be stopped (the 's' command toggles streaming) or its sensor failed to start"
                f"{self._notes()}; press the board's reset button",
            )
        elif waited >= self.no_data_s and self.header is None and s.notes and not s.before_header:
            self._fail(
                NoDataError,
                f"{self.device}: no header and no samples in {waited:.1f} s, only notes from the board"
                f"{self._notes()}: its sketch runs but cannot start; fix what it says, then press the board's "
                f"reset button",
            )
        elif waited >= self.no_data_s and valid == 0 and s.bytes < 20:
            notes = self._notes() + (f" except {s.bytes} stray bytes" if s.bytes else "")
            self._fail(
                NoDataError,
                f"{self.device}: nothing received in {waited:.1f} s{notes}. Check that the logger "
                f"sketch is flashed ({SKETCHES}), press the board's reset button, and that no other "
                f"program reads the port",
            )

    def _notes(self) -> str:
        return (
            f" (the board said: {'; '.join(dict.fromkeys(self.stats.notes))})" if self.stats.notes else ""
        )  # each once

    def _handle(self, line: bytes):
        item = parse_line(line)
        if isinstance(item, Sample):
            self._sample(item)
        elif isinstance(item, BadLine):
            if item.kind == "checksum":
                self.stats.bad_checksum += 1
            elif item.kind == "version":
                self._fail(
                    ProtocolVersionError,
                    f"{self.device}: the board speaks an unknown protocol ({item.detail}): "
                    f"{line[:60].decode('ascii', 'replace')!r}. Flash the sketch from this kit's firmware/ "
                    f"folder, or update kfkit",
                )
            elif item.kind == "malformed":
                self.stats.malformed += 1
        elif isinstance(item, Header):
            self._header(item)
        elif isinstance(item, Message):
            self.stats.messages += 1
            self.messages.setdefault(item.tag, []).append((self.stats.samples, item.values))
        elif isinstance(item, Note):
            self.stats.notes.append(item.text)

    def _header(self, header: Header):
        if self.header is None:
            self.header = header
            self.timeline = Timeline(header.rate_hz, self.seconds, self.stats)
            describe = getattr(self._serial, "header_metadata", None)  # a phone port describes its own sensors
            self.meta = describe(header) if describe is not None else header_metadata(header)
            self.columns = _columns(header)
            self._nfields = len(header.fields)
            self._mag_index = header.fields.index(MAG_FLAG) if MAG_FLAG in header.fields else None
            self._keep = [i for i, f in enumerate(header.fields[2:], start=2) if f != MAG_FLAG]
            self._mag_cols = [self.columns.index(f) for f in ("mx", "my", "mz") if f in self.columns]
            if self.out is not None:
                self.out.parent.mkdir(parents=True, exist_ok=True)
                self._file = open(self.out, "w", encoding="utf-8", newline="\n")  # noqa: SIM115  (open for the capture; _finish_file closes it)
                self._file.write(format_header(self._file_meta(), self.columns))
        elif header.fields != self.header.fields or header.board != self.header.board:
            self._fail(
                CaptureError,
                f"{self.device}: the board header changed mid-capture, from "
                f"{self.header.text!r} to {header.text!r}; start a new capture",
            )
        else:  # the same header again: an answer to 'h', or a board that restarted (setup() sends it)
            self.timeline.header_again()

    def _sample(self, values):
        s = self.stats
        if self.header is None:
            s.before_header += 1
            return
        if len(values) != self._nfields:
            s.malformed += 1
            return
        t = self.timeline.place(values[0], values[1])
        if t is None:  # the same instant twice (counted malformed), or past ``seconds``
            return
        row = [t, values[1], *(values[i] for i in self._keep)]
        if self._mag_index is not None and not values[self._mag_index]:
            for j in self._mag_cols:  # no new magnetometer reading: empty cells (NaN)
                row[j] = math.nan
        row = tuple(row)
        with self._lock:
            self._rows.append(row)
            s.samples += 1
            s.duration_s = t
        if self._file is not None:
            self._file.write(format_row(self.columns, row))

    # -- results ------------------------------------------------------------------------------------------
    def clock_rate_hz(self) -> float:
        """The sample rate of the board's own clock over the whole capture so far, Hz (NaN before two samples):
        :meth:`Timeline.clock_rate_hz`. A board's header states a nominal rate; a phone's is a guess from its first
        rows."""
        return self.timeline.clock_rate_hz() if self.timeline is not None else float("nan")

    def _file_meta(self, final=False) -> dict:
        meta = dict(self.meta or {"rate_hz": 0.0, "source": "capture"})
        meta["capture"] = {"port": str(self.device), "baud": self.baud}
        if self.board is not None:
            meta["source"] = self.board.source
        if final:
            rate = self.clock_rate_hz()
            if rate > 0:  # the whole capture's clock, not the header's (nominal or estimated) rate
                meta["capture"]["header_rate_hz"] = meta["rate_hz"]
                meta["rate_hz"] = rate
            meta["capture"]["stats"] = self.stats.as_dict()
            end = self.stats.duration_s + (1.0 / self.header.rate_hz if self.header else 0.0)
            phases = [{**p, "end": min(p["end"], end)} for p in self.phases or () if p["start"] < end]
            if phases:  # windows clipped to what was recorded (a capture stopped early)
                meta["phases"] = phases
        return meta

    def recording(self, last_seconds=None) -> Recording:
        """A snapshot of what has arrived (thread-safe): counts + metadata from the board header.

        ``last_seconds``: only the samples within that many seconds of the newest (times keep
        their origin, so phases still line up). Empty (0 rows) until the header has arrived.
        """
        with self._lock:
            if last_seconds is None:
                rows = list(self._rows)
            else:
                rate = self.header.rate_hz if self.header else 1.0
                rows = self._rows[-int(last_seconds * rate * 1.5 + 16) :]
        cols = self.columns or ["t", "seq"]
        # column by column from the parsed values: counts go to int64 directly (never through float), so the
        # final file holds exactly what was streamed
        columns = list(zip(*rows)) if rows else [()] * len(cols)
        data = {c: np.array(v, dtype=np.int64 if c in INT_COLUMNS else float) for c, v in zip(cols, columns)}
        if last_seconds is not None and len(rows):
            keep = data["t"] >= data["t"][-1] - last_seconds
            data = {c: v[keep] for c, v in data.items()}
        return Recording(self._file_meta(final=True), data, self.out)

    def _finish_file(self):
        if self._file is None:
            return
        self._file.close()
        self._file = None
        if not self.stats.samples:  # a header and nothing else: not a recording (it would not load)
            self.out.unlink(missing_ok=True)
        else:  # rewrite with the statistics and phases (atomically)
            tmp = self.out.with_name(self.out.name + ".tmp")
            save_recording(self.recording(), tmp)
            os.replace(tmp, self.out)
        if self.error is not None and self.stats.samples:  # a capture cut short: say where its data is
            self.error = type(self.error)(
                f"{self.error}; every sample received ({self.stats.samples} samples, "
                f"{self.stats.duration_s:.2f} s) is saved in {self.out}"
            )


def capture(port="auto", seconds=10.0, out=None, baud=DEFAULT_BAUD, progress=None, **options) -> Recording:
    """Record ``seconds`` of board time from ``port`` into ``out`` and return the Recording.

    ``progress(fraction, recorder)`` is called about ten times a second. Other keyword
    arguments go to :class:`Recorder` (``virtual=dict(motion=…)``, ``phases=…``, timeouts).
    Raises :class:`CaptureError` subclasses with what to do; on a disconnect the file keeps
    every sample received. (:meth:`Recorder.run` does the same with the recorder in your hands.)
    """
    return Recorder(port, baud, out, seconds=seconds, **options).run(progress)
