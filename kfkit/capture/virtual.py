"""A virtual board: the IMU simulator streaming protocol v1 to a pseudo-terminal.

``VirtualBoard`` opens a pty (``os.openpty``): the slave end is a real tty (``.port``, e.g.
``/dev/pts/5``) that pyserial, ``screen`` or ``kfkit capture --port`` open by path; a thread
writes lines to the master end at the board's real rate. Like an Arduino that resets when
its port opens, it starts (header, then ``seq`` 0) when the host sends its first byte;
afterwards ``h`` re-sends the header and ``s`` stops/starts streaming.

By default each board is the very unit the bundled recordings come from (:data:`VIRTUAL_UNITS`, from
:mod:`kfkit.unit_errors`): the Nucleo of labs 02–04 with its biases, accelerometer scale errors and hard and
soft iron, the MPU6050 of lab 05 with its biases and scale errors. So the bundled calibration
(``data/calibration_<board>.json``, what :func:`kfkit.calibration.load_calibration` gives before a student
saves one) is the virtual board's too, and labs 02/03 on its recordings find the unit's parameters.
``unit=None`` gives an ideal sensor instead: white noise and quantisation, nothing to calibrate.

The sensors' biases wander as one continuous random walk b(t) = b₀ + ∫ w dt (density K, one path
carried from chunk to chunk of the simulation), so a long recording's Allan deviation turns up as
K·√(τ/3) beyond its minimum, as a real sensor's does. Datasheets give no K for these chips; the
values (:data:`kfkit.unit_errors.BIAS_RANDOM_WALK`) put the Allan minimum where MEMS sensors of their class have it.

Faults (``faults=`` dict; positions count every sample the board makes, from 0, across resets;
a list of positions or a probability per sample, drawn from ``seed``):

| key         | what the board does at that sample                                      |
| ----------- | ----------------------------------------------------------------------- |
| corrupt     | changes one digit of the line (bad checksum)                              |
| drop        | does not send the line (a ``seq`` gap)                                    |
| truncate    | sends half the line (malformed)                                           |
| reset       | reboots before it: header again, ``seq`` and ``t_us`` restart             |
| disconnect  | (a position) closes the pty, as if unplugged                              |
| stall       | (a position) stops sending, the port left open, as a crashed sketch       |
| garbage     | (True) sends random bytes at the line rate, as a wrong baud rate looks    |
| silent      | (True) sends nothing at all, as a board without the sketch                |
"""

from __future__ import annotations

import contextlib
import fcntl
import inspect
import os
import select
import sys
import termios
import threading
import time
import tty

import numpy as np

from .. import motions, sim
from ..filters.tilt import TiltAttitude
from ..frames import G
from ..sensors import BOARDS
from ..sensors import board as get_board
from ..unit_errors import BOARD_UNITS, resolve_unit
from .protocol import MICROS_MODULO, SEQ_MODULO, encode_header, encode_message, encode_sample

FAULT_KINDS = ("corrupt", "drop", "truncate", "reset", "disconnect", "stall", "garbage", "silent")
#: The fastest rate a virtual board samples at, Hz: beyond every output data rate of the kit's sensors
#: (ISM330DHCX 6.67 kHz, MPU6050 gyro 8 kHz), and a second of it is a chunk the simulator holds easily.
MAX_RATE_HZ = 10_000.0
BOOT_US = 1500  # micros() when a sketch sends its first sample after a reset
# what firmware/mpu6050_tilt_kf prints (Serial.println: CR LF) when it starts measuring the gyro bias
ATTITUDE_NOTE = b"#NOTE,measuring gyro bias: keep the board still for 2 s\r\n"

#: The units the virtual board plays (``unit="bundled"``): the serial boards' simulated units
#: (:data:`kfkit.unit_errors.BOARD_UNITS`; a phone is the virtual phone's, :mod:`.virtual_phone`).
VIRTUAL_UNITS = {name: BOARD_UNITS[name] for name in BOARDS}


def board_fields(b) -> tuple:
    """The sample fields a kfkit sketch sends for board ``b`` (see firmware/*/README.md)."""
    fields = ("t_us", "seq", "ax", "ay", "az", "gx", "gy", "gz")
    return fields + ("mx", "my", "mz", "mag_new") if b.mag is not None else fields


def board_header(b, rate_hz: float, version: int = 1) -> bytes:
    """The ``#KFKIT`` header the sketch for board ``b`` sends."""
    params = {"accel_fs_g": round(b.accel.full_scale / G), "gyro_fs_dps": round(np.degrees(b.gyro.full_scale))}
    if b.mag is not None:
        params["mag_rate_hz"] = f"{b.mag_rate_hz or rate_hz:g}"
    return encode_header(b.name, rate_hz, board_fields(b), version=version, **params)


def _positions(spec):
    """A fault spec → a set of positions (list) or a probability (float)."""
    if spec is None or spec is False:
        return set()
    if isinstance(spec, float):
        if not 0.0 <= spec <= 1.0:
            raise ValueError(f"a fault probability must be in [0, 1], got {spec}")
        return spec
    return {int(p) for p in ([spec] if isinstance(spec, (int, np.integer)) else spec)}


class VirtualBoard:
    """A simulated board on a pty. Use as a context manager; ``.port`` is the tty path.

    rate_hz      sample rate, Hz, 0 < rate_hz ≤ :data:`MAX_RATE_HZ` (default: the motion's, else the board's: 104
                 Nucleo, 100 MPU6050)
    board        "nucleo-iks02a1" or "mpu6050" (kfkit.sensors.BOARDS)
    motion       a motions.Motion to play (looped when ``loop``), or None: at rest, level, forever
    unit         the sensor errors: "bundled" (default) the board's unit in :data:`VIRTUAL_UNITS`, the one its bundled
                 recordings and calibration come from; None an ideal sensor (no bias, walk, scale error or
                 iron: white noise and quantisation only); or a dict of ``sim.simulate_imu`` keywords
                 (``gyro_bias``, ``accel_bias`` (3,), ``accel_scale``, ``gyro_scale``, ``mag_hard_iron``,
                 ``mag_soft_iron``, ``gyro_bias_rw``, ``accel_bias_rw``; left out: none)
    faults       dict, see the module docstring
    seed         seeds the sensor noise, the bias walks and random faults
    realtime     False: send as fast as the host reads (tests, benchmarks)
    start_us     micros() of the first sample (set near 2³² to exercise the wrap)
    start_seq    ``seq`` of the first sample: a board that was already streaming (a Nucleo does not
                 reset when its port opens); set near 2¹⁶ to exercise the wrap. Resets restart at 0.
    protocol_version  the version its header announces (≠ 1: a board kfkit cannot read)
    sim_options  extra keyword arguments for ``sim.simulate_imu`` (e.g. ``field_n``), over the unit's errors
                 (``gyro_bias_rw=…`` replaces the unit's walk); the walks run on across chunks, loops and resets
    extra_lines  callables ``f(board, n, truth_euler) → bytes | None`` adding lines of other
                 kinds after sample ``n`` (e.g. ``$ATT,…`` from the tilt firmware)
    attitude     True: behave like ``firmware/mpu6050_tilt_kf``, adding ``$ATT,roll_deg,pitch_deg*HH``
                 after each sample, computed from the sample's counts by the Python reference
                 ``kfkit.filters.TiltAttitude``, and ``messages=ATT,filter=tilt_kf`` in the header. Like
                 the sketch it measures the gyro bias for 2 s (no ``$ATT``; :data:`ATTITUDE_NOTE` first)
                 at start, after a reset, and each time ``s`` starts streaming again
    """

    def __init__(
        self,
        rate_hz=None,
        board="nucleo-iks02a1",
        motion=None,
        faults=None,
        seed=0,
        *,
        unit="bundled",
        realtime=True,
        loop=True,
        start_us=0,
        start_seq=0,
        chunk_s=1.0,
        sim_options=None,
        extra_lines=(),
        attitude=False,
        protocol_version=1,
    ):
        self.board = get_board(board) if isinstance(board, str) else board
        if motion is not None and rate_hz is not None and abs(float(rate_hz) - motion.rate_hz) > 1e-9:
            raise ValueError(f"rate_hz={rate_hz} differs from the motion's rate {motion.rate_hz} Hz")
        if rate_hz is None:
            rate_hz = motion.rate_hz if motion is not None else self.board.rate_hz
        if (
            isinstance(rate_hz, bool)
            or not isinstance(rate_hz, (int, float, np.integer, np.floating))
            or not (0.0 < rate_hz <= MAX_RATE_HZ)
        ):
            raise ValueError(f"VirtualBoard: rate_hz must be a number > 0 and ≤ {MAX_RATE_HZ:g} Hz, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.motion, self.loop, self.realtime = motion, loop, realtime
        self.seed, self.start_us, self.start_seq, self.chunk_s = seed, int(start_us), int(start_seq), chunk_s
        self.unit = resolve_unit(self.board.name, unit, VIRTUAL_UNITS)  # the sensor errors it simulates
        self.sim_options = {**self.unit, **(sim_options or {})}  # less the biases and walks: to sim.simulate_imu
        reserved = {"motion", "board", "seed", "mag_rate_hz"}  # the board sets these itself
        unknown = sorted(set(self.sim_options) - (set(inspect.signature(sim.simulate_imu).parameters) - reserved))
        if unknown:
            raise ValueError(
                f"sim_options: {', '.join(unknown)} cannot be set; give sim.simulate_imu keywords "
                f"other than {', '.join(sorted(reserved))}"
            )
        self.bias_rw = {key: float(self.sim_options.pop(f"{key}_rw", 0.0)) for key in ("gyro_bias", "accel_bias")}
        self._bias0 = {key: np.asarray(self.sim_options.pop(key, np.zeros(3)), float) for key in self.bias_rw}
        self.extra_lines = list(extra_lines)
        faults = dict(faults or {})
        unknown = set(faults) - set(FAULT_KINDS)
        if unknown:
            raise ValueError(f"unknown fault kind(s) {', '.join(sorted(unknown))}; known: {', '.join(FAULT_KINDS)}")
        self._rng = np.random.default_rng(seed)
        self.faults = {k: _positions(faults.get(k)) for k in ("corrupt", "drop", "truncate", "reset")}
        self.disconnect_at, self.stall_at = faults.get("disconnect"), faults.get("stall")
        self.garbage, self.silent = bool(faults.get("garbage")), bool(faults.get("silent"))
        self.header = board_header(self.board, self.rate_hz, protocol_version)
        self.attitude = bool(attitude)
        self._tilt = None  # the sketch's filters (attitude=True), new at each (re)start
        if self.attitude:
            self.header = self.header.rstrip(b"\n") + b",messages=ATT,filter=tilt_kf\n"  # as mpu6050_tilt_kf's
        self.fields = board_fields(self.board)
        self.samples_made = 0  # every sample generated, sent or not
        self._paused_us = 0  # time spent stopped by 's' (micros() runs on)
        self.lines_sent = 0
        self.connected = False
        self.error = None  # the exception that stopped the board's thread (it then closes its port, as unplugged)
        self._master = self._slave = None
        self._thread = None
        self._stop = threading.Event()
        self.port = None

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> VirtualBoard:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing: bytes pass unchanged
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name=f"kfkit-virtual-board {self.port}", daemon=True)
        self._thread.start()
        return self

    def close(self):
        """Stop the thread and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._close_fds()

    def _close_fds(self):
        for name in ("_master", "_slave"):
            fd = getattr(self, name)
            if fd is not None:
                setattr(self, name, None)
                with contextlib.suppress(OSError):
                    os.close(fd)

    def __enter__(self):
        return self.start() if self._thread is None else self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return f"VirtualBoard({self.board.name}, {self.rate_hz:g} Hz, port={self.port})"

    # -- what a recorder asks of a board object that serves a port (kfkit.capture.recorder) ---------------
    source = "capture (virtual board)"  # the recording's metadata "source"

    @property
    def description(self) -> str:
        return f"virtual board ({self.board.name}, {self.rate_hz:g} Hz) on {self.port}"

    @property
    def phases(self) -> list:
        """The labelled windows of the motion it plays, [{"label", "start", "end"}] (s); [] without."""
        windows = self.motion.phases if self.motion is not None else None
        return [{"label": label, "start": float(a), "end": float(b)} for a, b, label in windows or ()]

    # -- samples -----------------------------------------------------------------------------------
    def _chunks(self):
        """Yield (counts (n, k) int, truth euler (n, 3)) chunks of the sample rows, forever or once.

        Each chunk is simulated on its own (white noise seeded by [seed, chunk]); the bias path
        b₀ + walk is carried over, so the noise process is one, whatever the chunk length.
        """
        b, rate, bias0 = self.board, self.rate_hz, self._bias0
        walk_rng, walk = np.random.default_rng([self.seed, 1]), {k: np.zeros(3) for k in bias0}
        mag_rate = b.mag_rate_hz or rate
        last_mag, chunk_index = np.zeros(3), 0
        while True:
            total = len(self.motion.t) if self.motion is not None else None
            start = 0
            while total is None or start < total:
                n = (
                    int(round(self.chunk_s * rate))
                    if total is None
                    else min(int(round(self.chunk_s * rate)), total - start)
                )
                if self.motion is None:
                    m = motions.stationary(n / rate, rate)
                    m.t = (start + np.arange(n)) / rate
                else:
                    s = slice(start, start + n)
                    m = motions.Motion(
                        self.motion.t[s], rate, self.motion.euler[s], self.motion.omega_b[s], self.motion.acc_n[s]
                    )
                biases = {}
                for key, density in self.bias_rw.items():  # b_k = b₀ + Σ_{j≤k} w_j, w ~ N(0, K²/rate)
                    path = walk[key] + np.cumsum(walk_rng.normal(0.0, density / np.sqrt(rate), (n, 3)), axis=0)
                    walk[key], biases[key] = path[-1], bias0[key] + path
                rec = sim.simulate_imu(
                    m,
                    board=b,
                    seed=[self.seed, chunk_index],
                    mag_rate_hz=mag_rate,
                    **biases,
                    gyro_bias_rw=0.0,
                    accel_bias_rw=0.0,
                    **self.sim_options,
                )
                cols = [rec[c].astype(np.int64) for c in ("ax", "ay", "az", "gx", "gy", "gz")]
                if b.mag is not None:
                    k = start + np.arange(n)
                    tick = np.floor(k * mag_rate / rate + 1e-9)
                    fresh = tick != np.floor((k - 1) * mag_rate / rate + 1e-9)
                    mag = rec.counts("mag")
                    for i in range(n):  # the sketch repeats the last reading, flagged mag_new = 0
                        if fresh[i]:
                            last_mag = mag[i] if np.all(np.isfinite(mag[i])) else last_mag
                        mag[i] = last_mag
                    cols += [mag[:, j].astype(np.int64) for j in range(3)] + [fresh.astype(np.int64)]
                yield np.column_stack(cols), rec.truth()
                start += n
                chunk_index += 1
            if not self.loop:
                return

    def _is_fault(self, kind, n) -> bool:
        spec = self.faults[kind]
        return self._rng.random() < spec if isinstance(spec, float) else n in spec

    def _corrupt(self, line: bytes) -> bytes:
        star = line.rindex(b"*")
        digits = [i for i in range(1, star) if 48 <= line[i] <= 57]
        i = digits[int(self._rng.integers(len(digits)))]
        new = 48 + (line[i] - 48 + 1 + int(self._rng.integers(9))) % 10  # a different digit
        return line[:i] + bytes([new]) + line[i + 1 :]

    def _start_attitude(self) -> bytes:
        """(attitude=True) What the sketch does at each start: new filters, and the note to keep still."""
        if not self.attitude:
            return b""
        self._tilt = TiltAttitude(self.board, self.rate_hz)
        return ATTITUDE_NOTE

    def _lines(self):
        """Yield (n, bytes to send) per sample made, applying the faults."""
        since_reset, boot_us, seq0 = 0, self.start_us, self.start_seq
        for counts, truth in self._chunks():
            for row, euler in zip(counts, truth):
                n = self.samples_made
                if any(at is not None and n >= at for at in (self.disconnect_at, self.stall_at)):
                    return
                out = b""
                if self._is_fault("reset", n):
                    since_reset, boot_us, seq0 = 0, BOOT_US, 0
                    out += self.header + self._start_attitude()
                t_us = (boot_us + round(since_reset * 1e6 / self.rate_hz) + self._paused_us) % MICROS_MODULO
                line = encode_sample((t_us, (seq0 + since_reset) % SEQ_MODULO, *row.tolist()))
                since_reset += 1
                self.samples_made += 1
                if self._is_fault("drop", n):
                    line = b""
                elif self._is_fault("corrupt", n):
                    line = self._corrupt(line)
                elif self._is_fault("truncate", n):
                    line = line[: len(line) // 2] + b"\n"
                out += line
                angles = self._tilt.step(row[:3], row[3:6]) if self._tilt is not None else None
                if angles is not None:
                    out += encode_message("ATT", np.degrees(angles))
                for extra in self.extra_lines:
                    out += extra(self.board, n, euler) or b""
                yield n, out

    # -- the thread ----------------------------------------------------------------------------------
    def _run(self):
        streaming, lines = False, None
        pending = bytearray()
        t0 = 0.0
        paused_at = None
        try:
            while not self._stop.is_set():
                for c in self._read_commands():
                    if not self.connected:  # first contact: the board (re)starts, as on a DTR reset
                        self.connected, streaming = True, True
                        lines, t0 = self._lines(), time.monotonic()
                        pending += b"" if self.silent else self.header + self._start_attitude()
                    elif c == ord("h") and not self.silent:
                        pending += self.header
                    elif c == ord("s"):
                        streaming = not streaming
                        if streaming and paused_at is not None:
                            gap = time.monotonic() - paused_at
                            t0 += gap
                            self._paused_us += int(gap * 1e6)
                            if not self.silent:  # the board may have moved meanwhile: measure the bias again
                                pending += self._start_attitude()
                        paused_at = None if streaming else time.monotonic()
                if streaming and lines is not None and not self.silent:
                    due = int((time.monotonic() - t0) * self.rate_hz) + 1 if self.realtime else self.samples_made + 64
                    while self.samples_made < due and len(pending) < 65536:
                        try:
                            n, out = next(lines)
                        except StopIteration:
                            if self.disconnect_at is not None and self.samples_made >= self.disconnect_at:
                                self._unplug(pending)
                                return
                            lines = None
                            break
                        if self.garbage:
                            out = self._rng.integers(0, 256, len(out), dtype=np.uint8).tobytes()
                        pending += out
                        self.lines_sent += bool(out)
                if pending:
                    self._flush(pending, wait=0.0 if self.realtime else 0.01)
                self._stop.wait(min(0.5 / self.rate_hz, 0.005) if streaming else 0.01)
        except OSError:  # the pty went away under us (closed from outside)
            pass
        except Exception as e:  # noqa: BLE001 — a failing simulation (or extra_lines): no traceback on a thread
            self.error = e  # what was made before it reaches the host, then the port closes (a recorder says why)
            self._unplug(pending)

    def _unplug(self, pending: bytearray):
        """Send what is pending, wait until the host has read it, close the pty: as a board unplugged."""
        try:
            self._flush(pending, wait=0.01)
            self._drain()
        except OSError:
            pass
        self._close_fds()

    def _drain(self, timeout=30.0):
        """Wait until the host has read what was sent (a pty drops unread bytes when it closes)."""
        deadline = time.monotonic() + timeout
        empty_since = None
        while time.monotonic() < deadline and not self._stop.is_set():
            waiting = int.from_bytes(fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder)
            now = time.monotonic()
            if waiting:
                empty_since = None
            elif empty_since is None:
                empty_since = now
            elif now - empty_since > 0.05:  # empty for 50 ms: the kernel's pty buffers were pushed and read
                return
            time.sleep(0.002)

    def _read_commands(self) -> bytes:
        if self._master is None:
            return b""
        try:
            return os.read(self._master, 256)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO: nobody has the port open
            return b""

    def _flush(self, pending: bytearray, wait=0.0):
        """Write as much of ``pending`` as the pty takes (keeps the rest: no line is lost)."""
        while pending and self._master is not None and not self._stop.is_set():
            try:
                n = os.write(self._master, pending)
            except BlockingIOError:
                if not select.select([], [self._master], [], wait or 0.001)[1] and not wait:
                    return
                continue
            del pending[:n]
